"""`poevp sweep`: the grid, its resumable state, scene bundles for workers and the Dask cluster (issue
29: one job per subpackage; no re-exports, import the modules)."""
