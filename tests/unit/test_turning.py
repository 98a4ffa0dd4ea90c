"""A light on an arc at a steady speed is continued on its arc (control/predictors/track.py
`closed_form_turning`), and chains that do not turn are left to the other models.

The truth is the arc itself, p_k = c + R (cos(phi_0 + w k), sin(phi_0 + w k)), evaluated at the
next frame: not the rotation of the last displacement the code uses."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.analysis.motion_paths import saturated_centroid
from poevp_optics.control.predictors import make_predictor
from poevp_optics.control.predictors.track import closed_form_displacement, closed_form_turning


def arc(radius_px: float, w_rad: float, frames: int, phi0: float = 0.3, centre=(320.0, 180.0)) -> np.ndarray:
    """(frames, 2) positions (px) on a circle of `radius_px`, w_rad a frame."""
    phi = phi0 + w_rad * np.arange(frames)
    return np.asarray(centre) + radius_px * np.stack([np.cos(phi), np.sin(phi)], 1)


def chain_and_next(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d_t, d_{t-1}, d_{t-2} newest first, d_{t+1}) of positions p_0 .. p_4."""
    d = np.diff(pos, axis=0)
    return d[:3][::-1], d[3]


@pytest.mark.parametrize("radius_px, w_rad", [(150.0, 0.06), (80.0, 0.2), (60.0, -0.45), (40.0, 0.8)])
def test_a_steady_turn_is_continued_on_its_arc(radius_px, w_rad):
    """Exact for any radius and rate in the gate, where the three-displacement constant-acceleration
    fit misses the arc by more than |d| w^2 (about 5/3 of it for small w)."""
    chain, truth = chain_and_next(arc(radius_px, w_rad, 5))
    np.testing.assert_allclose(closed_form_turning(chain), truth, atol=1e-9)
    assert np.hypot(*(closed_form_displacement(chain) - truth)) > w_rad ** 2 * np.hypot(*truth)


@pytest.mark.parametrize("name, chain", [
    ("constant velocity", [(12.0, 3.0), (12.0, 3.0), (12.0, 3.0)]),
    ("accelerating on a line", [(16.0, 4.0), (12.0, 3.0), (8.0, 2.0)]),
    ("braking hard on an arc", [(6.0, 3.0), (10.0, 2.0), (14.0, 0.0)]),
    ("swerve: turns of opposite signs", [(10.0, 2.0), (10.0, 0.0), (10.0, 2.0)]),
    ("reversal", [(-10.0, 0.5), (10.0, 0.0), (10.0, -0.5)]),
    ("too slow to read a direction", [(1.0, 1.0), (1.2, 0.2), (1.0, -0.5)]),
    ("a new light", [(10.0, 2.0), (10.0, 0.0)]),
])
def test_chains_that_do_not_turn_are_left_to_the_other_models(name, chain):
    assert closed_form_turning(chain) is None, name


def test_a_noisy_turn_is_still_continued_better_than_the_acceleration_fit():
    """0.3 px of noise per axis on each position of a car turning 0.25 rad a frame at 20 px a
    frame: the arc reads as a turn in most draws, and its RMS error is under two thirds of the
    constant-acceleration fit's."""
    rng = np.random.default_rng(11)
    pos = arc(80.0, 0.25, 5)
    arc_err, ca_err, read = [], [], 0
    for _ in range(400):
        chain, truth = chain_and_next(pos + rng.normal(0.0, 0.3, pos.shape))
        turned = closed_form_turning(chain)
        read += turned is not None
        guess = closed_form_displacement(chain) if turned is None else turned
        arc_err.append(np.hypot(*(guess - truth)))
        ca_err.append(np.hypot(*(closed_form_displacement(chain) - truth)))
    assert read >= 0.9 * 400
    assert np.sqrt(np.mean(np.square(arc_err))) < (2 / 3) * np.sqrt(np.mean(np.square(ca_err)))


def _frames(pos: np.ndarray, shape=(360, 640), over: float = 300.0) -> list[np.ndarray]:
    """8-bit frames of one headlamp spot `over` x saturation at each of `pos`."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    return [np.clip(np.rint(10.0 + over * 255.0 * np.exp(-((xx - cx) / 7.0) ** 2 - ((yy - cy) / 4.5) ** 2)), 0, 255)
            .astype(np.float32) for cx, cy in pos]


@pytest.mark.parametrize("name", ["track", "track_net"])
def test_both_trackers_follow_a_lamp_round_a_turn(name):
    """Rendered: a lamp turning 0.35 rad a frame at 28 px a frame; the predicted clipped region's
    centroid within 1.5 px of the true one's, where the constant-acceleration fit of the chain
    lands over 4 px off."""
    pos = arc(80.0, 0.35, 5, phi0=-1.2)
    frames = _frames(pos)
    pred = make_predictor(name)(frames[:4])
    assert np.hypot(*(saturated_centroid(pred) - saturated_centroid(frames[4]))) < 1.5
    chain, _ = chain_and_next(pos)
    assert np.hypot(*(pos[3] + closed_form_displacement(chain) - pos[4])) > 4.0


def test_track_net_leaves_the_turns_it_was_trained_on_to_its_network():
    """`track_net` continues on the arc only turns sharper than its training paths' fastest
    (analysis/motion_paths.py TRAINING_SHAPES), `track` from TURN_MIN_RAD: a 0.2 rad turn is the
    law's in `track` only; a 0.35 rad turn is both's."""
    from poevp_optics.analysis.motion_paths import TRAINING_SHAPES
    from poevp_optics.control.predictors.track import TURN_MIN_RAD

    net, closed = make_predictor("track_net"), make_predictor("track")
    assert net.turn_min_rad == TRAINING_SHAPES["turn_rad"][1]
    assert closed.turn_min_rad == TURN_MIN_RAD
    slow, _ = chain_and_next(arc(80.0, 0.2, 5))
    sharp, _ = chain_and_next(arc(80.0, 0.35, 5))
    assert closed_form_turning(slow, closed.turn_min_rad) is not None
    assert closed_form_turning(slow, net.turn_min_rad) is None
    assert closed_form_turning(sharp, net.turn_min_rad) is not None
