"""A standing glow whose outline wavers is predicted where it stands (moving lights: test_track.py,
test_predictor_stop.py, test_global_motion.py).

A fog halo or a street lamp's reflection on a wet road is a large clipped region that does not
travel, but whose clipped edge moves with the noise and the Monte Carlo samples from frame to
frame, so the tracker reads a few pixels of motion back and forth. Frames are synthesised here: a
dim textured road and a clipped round glow (a Gaussian 6x over saturation, radius ~21 px clipped)
whose clipped outline sits 3 px left of the lamp in even frames and 3 px right in odd ones: a
measured chain of +-6 px swings with nothing travelling. The region trackers must read that
chain as wavering and keep the glow in place (its clipped pixels where the last frame has them),
not carry the last swing on.
"""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.control.predictors import make_predictor
from poevp_optics.control.predictors.track import region_tracks, wavering

SHAPE = (184, 320)
CENTRE = (160.0, 92.0)


def glow_frame(side: float, seed: int) -> np.ndarray:
    """8-bit frame: road 15-45 DN and a glow 6x over saturation (1/e radius 16 px) centred 3 px
    to the `side` (+1 right, -1 left) of CENTRE."""
    rng = np.random.default_rng(seed)
    h, w = SHAPE
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    cx, cy = CENTRE[0] + 3.0 * side, CENTRE[1]
    glow = 6.0 * 255.0 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / 16.0 ** 2)
    return np.clip(np.rint(15.0 + 30.0 * rng.uniform(0, 1, (h, w)) + glow), 0, 255).astype(np.float32)


def test_the_wavering_gate_in_closed_form():
    """Twice running a change of displacement above the acceleration gate (1 x max(|d|, 1 px)):
    wavering; one change (a reversal), a steady or accelerating chain, or a short chain: not."""
    assert wavering([(4.0, 0.0), (-4.0, 0.0), (4.0, 0.0)])          # |8| > 4 and |8| > 4
    assert wavering([(0.0, 3.0), (0.0, -2.5), (0.0, 3.5)])          # |5.5| > 3 and |6| > 2.5
    assert not wavering([(9.0, 0.0), (7.0, 0.0), (5.0, 0.0)])       # accelerating: changes of 2 <= 9, 7
    assert not wavering([(-10.0, 0.0), (10.0, 0.0), (10.0, 0.0)])   # one reversal: |20| > 10, then 0
    assert not wavering([(0.0, 0.0), (16.0, 0.0), (16.0, 0.0)])     # a stop: |16| > 1, then 0
    assert not wavering([(4.0, 0.0), (-4.0, 0.0)])                  # two displacements: no second change
    # sub-pixel jitter of a standing light: the gate's floor is 1 px, |0.6 - -0.5| = 1.1 > 1 twice
    assert wavering([(0.6, 0.0), (-0.5, 0.0), (0.6, 0.0)])
    assert not wavering([(0.4, 0.0), (-0.3, 0.0), (0.4, 0.0)])      # changes of 0.7 px: under the floor


def test_the_synthetic_glow_reads_as_a_wavering_chain():
    """The tracker follows the glow back three frames and measures its swings: 6 px each way,
    alternating (0.5 px: the rounded, clipped outline)."""
    frames = [glow_frame((-1.0) ** k, seed=k) for k in range(4)]
    tracks, labels = region_tracks(frames)
    glow = next(t for t in tracks if labels[int(CENTRE[1]), int(CENTRE[0])] == t.label)
    d = np.asarray(glow.displacements)
    assert len(d) == 3
    # newest first: frame 3 is on the left (-3 px), frame 2 on the right (+3 px)
    np.testing.assert_allclose(d, [(-6.0, 0.0), (6.0, 0.0), (-6.0, 0.0)], atol=0.5)
    assert wavering(glow.relative())


@pytest.mark.parametrize("name", ["track", "track_net"])
def test_a_wavering_glow_is_predicted_in_place(name):
    """The prediction's clipped pixels are the last frame's (the glow stands), so against the next
    frame (the outline swung back) it scores what `hold` scores, and better than carrying the
    glow on by its last measured swing (a constant-velocity reading of the chain)."""
    from poevp_optics.analysis.prediction_metrics import saturated_iou

    frames = [glow_frame((-1.0) ** k, seed=k) for k in range(5)]
    pred = make_predictor(name)(frames[:4])
    last = frames[3] >= 254.5
    got = pred >= 254.5
    assert np.logical_and(got, last).sum() / np.logical_or(got, last).sum() > 0.99
    # the last swing carried on: the last frame's clipped pixels shifted by its newest displacement
    tracks, _ = region_tracks(frames[:4])
    dx = int(round(next(t for t in tracks if t.area_px > 500).displacements[0][0]))
    carried = np.where(np.roll(last, dx, axis=1), 255.0, 0.0)
    assert saturated_iou(pred, frames[4]) == pytest.approx(saturated_iou(frames[3], frames[4]), abs=0.01)
    assert saturated_iou(pred, frames[4]) > saturated_iou(carried, frames[4]) + 0.05
