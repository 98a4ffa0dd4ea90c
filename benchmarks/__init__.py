"""Benchmarks: scripts that print tables and write plots, into out/benchmarks/ by default and into
the committed benchmarks/results/ with `--results` (`make bench`)."""
