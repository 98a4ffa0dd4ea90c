"""The predictor interface, `hold`, and the per-frame check of a prediction."""

from __future__ import annotations

import numpy as np


class Predictor:
    """Callable: list of past frames (H, W) float32 on the 8-bit scale -> next frame."""

    name = "base"
    needs_frames = 2
    min_input_px = 1              # smallest frame side (px) it takes

    def __call__(self, history: list[np.ndarray]) -> np.ndarray:
        raise NotImplementedError

    def describe(self) -> dict:
        return {"name": self.name}


class Hold(Predictor):
    """The last frame: what an iteratively updated, non-predictive SVE camera does."""

    name = "hold"
    needs_frames = 1

    def __call__(self, history):
        return np.asarray(history[-1], dtype=np.float32)


def checked_prediction(predictor: Predictor, history: list[np.ndarray]) -> tuple[np.ndarray, int]:
    """Run `predictor` on `history` and check its output: pixels that are NaN or Inf fall back
    to the last frame (what `hold` predicts). Returns (prediction, number of pixels that fell
    back); the caller reports a non-zero count (per-frame flag and a report note), so a broken
    prediction is never silent."""
    pred = np.asarray(predictor(history), dtype=np.float32)
    bad = ~np.isfinite(pred)
    n_bad = int(np.count_nonzero(bad))
    if n_bad:
        last = np.nan_to_num(np.asarray(history[-1], dtype=np.float32), nan=255.0, posinf=255.0, neginf=0.0)
        pred = np.where(bad, last, pred)
    return pred, n_bad
