"""`poevp search`: an optimiser (Optuna) over scene keys for an objective from the runs' reports, on
the sweep's Dask machinery (no re-exports, import the modules)."""
