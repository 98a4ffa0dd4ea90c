"""`poevp train-data` / `train-predictor`: training data, the per-sequence renderer and the predictor
trainers (issue 29: one job per subpackage; no re-exports, import the modules)."""
