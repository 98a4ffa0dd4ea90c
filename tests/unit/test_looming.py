"""A light closing on the camera at a steady speed is continued by the pinhole projection's law
(control/predictors/track.py `closed_form_looming`), and chains that do not loom are left to
the other models.

The truth here is the projection itself, x_t = f X / (Z_0 - V t) + c, evaluated at the next
frame: not the ratio law the code uses."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.analysis.motion_paths import saturated_centroid
from poevp_optics.control.predictors import make_predictor
from poevp_optics.control.predictors.track import closed_form_displacement, closed_form_looming

F_PX = 900.0                     # focal length (px)
CENTRE = np.array([320.0, 180.0])


def projected(x_m: float, y_m: float, z0_m: float, v_m: float, frames: int) -> np.ndarray:
    """(frames, 2) image positions (px) of a point at (x, y) m off the axis, z0 - v t m ahead."""
    z = z0_m - v_m * np.arange(frames)
    return CENTRE + F_PX * np.stack([x_m / z, y_m / z], 1)


def chain_and_next(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d_t, d_{t-1}, d_{t-2} newest first, d_{t+1}) of positions p_0 .. p_4."""
    d = np.diff(pos, axis=0)
    return d[:3][::-1], d[3]


@pytest.mark.parametrize("x_m, y_m, z0_m, v_m", [
    (-1.8, 0.6, 40.0, 3.0),          # an oncoming car's lamp, 30 m/s closing at 10 fps
    (3.5, -4.0, 25.0, 2.5),          # a street lamp above the road as we drive at it
    (1.2, 0.8, 18.0, 1.5),           # a car ahead we close on fast
    (-2.0, 0.5, 20.0, -2.0),         # a car pulling away (receding)
])
def test_a_steadily_closing_light_is_continued_exactly(x_m, y_m, z0_m, v_m):
    pos = projected(x_m, y_m, z0_m, v_m, 5)
    chain, nxt = chain_and_next(pos)
    got = closed_form_looming(chain)
    assert got is not None
    np.testing.assert_allclose(got, nxt, rtol=1e-9)
    # the constant-acceleration fit lags it wherever the light closes fast (ratios >= 1.2)
    ratios = np.hypot(*chain.T)[:2] / np.hypot(*chain.T)[1:]
    if ratios.min() > 1.2:
        assert np.hypot(*(closed_form_displacement(chain) - nxt)) > 0.05 * np.hypot(*nxt)


@pytest.mark.parametrize("name, chain", [
    ("constant velocity", [[12.0, 5.0], [12.0, 5.0], [12.0, 5.0]]),
    ("start from standing", [[24.0, 0.0], [16.0, 0.0], [8.0, 0.0]]),
    ("braking", [[3.0, 0.0], [6.0, 0.0], [9.0, 0.0]]),
    ("stopped", [[0.0, 0.0], [16.0, 0.0], [16.0, 0.0]]),
    ("turning", [[14.0, 14.0], [18.0, 8.0], [19.0, 0.0]]),
    ("reversal", [[-10.0, 0.0], [10.0, 0.0], [20.0, 0.0]]),
    ("sub-pixel", [[1.5, 0.0], [1.2, 0.0], [1.0, 0.0]]),
    ("two displacements", [[20.0, 0.0], [15.0, 0.0]]),
    ("looming too slowly", [[10.6, 0.0], [10.0, 0.0], [9.5, 0.0]]),
    ("speeding up at a steady rate", [[14.0, 7.0], [12.0, 6.0], [10.0, 5.0]]),
    ("braking at a steady rate", [[20.0, 0.0], [24.0, 0.0], [28.0, 0.0]]),
])
def test_chains_that_do_not_loom_are_left_to_the_other_models(name, chain):
    assert closed_form_looming(chain) is None, name


def test_a_noisy_looming_chain_is_still_read_as_looming():
    """With the outline correlation's noise (0.3 px per axis and displacement) on a lamp closing
    fast (displacements 15-33 px, next 58 px), the chain still looms in at least 85 % of 400
    draws, and there its next step's RMS error is under a quarter of the constant-acceleration
    fit's on the same draws (that fit lags by 17 px)."""
    pos = projected(-1.8, 0.6, 20.0, 3.0, 5)
    chain, nxt = chain_and_next(pos)
    rng = np.random.default_rng(5)
    loom_err, ca_err = [], []
    for _ in range(400):
        noisy = chain + rng.normal(0.0, 0.3, chain.shape)
        got = closed_form_looming(noisy)
        if got is not None:
            loom_err.append(np.hypot(*(got - nxt)))
            ca_err.append(np.hypot(*(closed_form_displacement(noisy) - nxt)))
    assert len(loom_err) >= 0.85 * 400
    assert np.sqrt(np.mean(np.square(loom_err))) < 0.25 * np.sqrt(np.mean(np.square(ca_err)))


def _frames(pos: np.ndarray, sigma0_px: float, z_scale: np.ndarray, shape=(360, 640), over: float = 40.0):
    """8-bit frames of one Gaussian light `over` x saturation at `pos`, its width growing as 1/Z."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    out = []
    for (cx, cy), s in zip(pos, z_scale):
        sig = sigma0_px * s
        img = over * 255.0 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * sig * sig))
        out.append(np.clip(np.rint(img), 0, 255).astype(np.float32))
    return out


@pytest.mark.parametrize("name", ["track", "track_net"])
def test_both_trackers_put_an_approaching_lamp_where_the_projection_puts_it(name):
    """Rendered: a lamp closing at 30 m/s from 24 m at 10 fps (displacements 10, 14 and 19 px, the
    next 28.5 px); the predicted clipped region's centroid within 1 px of the true one's, where
    the constant-acceleration fit of the chain lands more than 4 px short."""
    z0, v = 24.0, 3.0
    pos = projected(-1.8, 0.6, z0, v, 5)
    scale = z0 / (z0 - v * np.arange(5))
    frames = _frames(pos, 3.0, scale)
    pred = make_predictor(name)(frames[:4])
    truth = frames[4]
    assert np.hypot(*(saturated_centroid(pred) - saturated_centroid(truth))) < 1.0
    chain, _ = chain_and_next(pos)
    lag = pos[3] + closed_form_displacement(chain)
    assert np.hypot(*(lag - pos[4])) > 4.0
