"""`poevp evaluate`: the ALPR evaluation, its paper protocol, sequences, report and plots (issue 29:
one job per subpackage; no re-exports, import the modules)."""
