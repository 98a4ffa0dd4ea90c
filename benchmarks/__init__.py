"""Benchmarks: scripts that print tables and write plots under benchmarks/results/."""
