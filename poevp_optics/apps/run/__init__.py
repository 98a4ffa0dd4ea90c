"""`poevp render` and its parts: the render run, its outputs, report, checks, size and memory
estimates, the DR chart and the run comparison (issue 29: one job per subpackage; no re-exports,
import the modules)."""
