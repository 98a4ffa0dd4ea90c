"""A highlight that moves and then stops is predicted where it stands: no overshoot, no reversal.

Frames are synthesised here (not by analysis/motion_paths.py, the training generator): a dim
textured road and a clipped headlamp-like ellipse (a Gaussian highlight 20x over saturation,
clipped at 255) that moves `v` px/frame for three frames and then stands. Each causal
predictor gets the last four frames (two-frame predictors use the last two) and predicts the
next one; the saturated centroid of the prediction must lie within 2 px of the true one (the
highlight is still, so the truth is the last frame's centroid: 2 px is two pixels of rounding of
a sub-pixel centroid, far below the 16-32 px a reversal or a constant-velocity overshoot gives).
"""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.control.predictors import make_predictor

CAUSAL = ("hold", "flow", "track", "track_net", "dmvfn_lite", "dmvfn")
SHAPE = (184, 320)


def frame(cx: float, cy: float, heading_deg: float, seed: int = 11) -> np.ndarray:
    """8-bit frame: a textured road (15-45 DN) and a clipped elliptical highlight (semi-axes 14 x 8
    px at 1/e, peak 20x saturation) centred at (cx, cy) px, its long axis along the heading."""
    rng = np.random.default_rng(seed)
    h, w = SHAPE
    road = 15.0 + 30.0 * rng.uniform(0, 1, (h, w))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    th = np.deg2rad(heading_deg)
    u = (xx - cx) * np.cos(th) + (yy - cy) * np.sin(th)
    q = -(xx - cx) * np.sin(th) + (yy - cy) * np.cos(th)
    lamp = 20.0 * 255.0 * np.exp(-((u / 14.0) ** 2 + (q / 8.0) ** 2))
    return np.clip(np.rint(road + lamp), 0, 255).astype(np.float32)


def centroid(img: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(img >= 254.5)
    return np.array([xs.mean(), ys.mean()]) if xs.size else np.array([np.nan, np.nan])


def stop_sequence(v: float, heading_deg: float, standing: int) -> list[np.ndarray]:
    """Positions 0, v, 2v, 3v along the heading (three moving frames), then `standing` more
    frames at 3v: the frames the predictor sees plus the one it predicts."""
    e = np.array([np.cos(np.deg2rad(heading_deg)), np.sin(np.deg2rad(heading_deg))])
    start = np.array([SHAPE[1] / 2, SHAPE[0] / 2]) - 1.5 * v * e
    steps = [0, 1, 2, 3] + [3] * standing
    return [frame(*(start + s * v * e), heading_deg) for s in steps]


@pytest.mark.parametrize("name", CAUSAL)
@pytest.mark.parametrize("v", [16.0, 32.0])
@pytest.mark.parametrize("heading_deg", [0.0, 135.0])
def test_first_stopped_frame_is_predicted_in_place(name, v, heading_deg):
    """History: moving, moving, moving, stopped (the newest displacement 0, the two before v);
    the prediction of the next frame (still stopped) is within 2 px of where it stands."""
    seq = stop_sequence(v, heading_deg, standing=2)
    hist, truth = seq[-5:-1], seq[-1]
    pred = make_predictor(name)(hist)
    err = float(np.hypot(*(centroid(pred) - centroid(truth))))
    assert err <= 2.0, f"{name} at {v} px/frame: {err:.1f} px off a stopped highlight"


@pytest.mark.parametrize("name", ("track", "track_net"))
@pytest.mark.parametrize("v", [16.0, 32.0])
def test_second_stopped_frame_is_predicted_in_place(name, v):
    """One frame later the chain is (0, 0, v), newest first: still no motion predicted."""
    seq = stop_sequence(v, 0.0, standing=3)
    pred = make_predictor(name)(seq[-5:-1])
    assert np.hypot(*(centroid(pred) - centroid(seq[-1]))) <= 2.0
