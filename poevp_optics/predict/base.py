"""Predictor interface and the registry factory."""

from __future__ import annotations

from pathlib import Path

import numpy as np


class Predictor:
    """Callable: list of past frames (H, W) float32 on the 8-bit scale -> next frame."""

    name = "base"
    needs_frames = 2

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


def make_predictor(name: str, weights: str = "", resolution=(368, 640)) -> Predictor:
    """Build a predictor by name (oracle is the loop's business: it needs the ground truth)."""
    if name == "hold":
        return Hold()
    if name == "flow":
        from .flow import FlowExtrapolation

        return FlowExtrapolation()
    if name in ("dmvfn", "dmvfn_lite"):
        from .dmvfn import load_predictor

        return load_predictor(name, Path(weights) if weights else None)
    raise ValueError(f"unknown predictor {name!r}")
