"""Two lights whose outlines run into one (control/predictors/region_merges.py): the merged region
moves with the lights it came from, each part with its own light's extrapolated motion.

Closed forms: two clipped discs at x = 60 + 10 k and x = 140 - 10 k (y = 60), frames k = 0..3 in
the history (their outlines merge in frame 3, centres 20 px apart, clipped radius 12.4 px each),
the truth of frame 4 the two lights on one another at x = 100."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.analysis.prediction_metrics import saturated_iou
from poevp_optics.control.predictors import make_predictor
from poevp_optics.control.predictors.flow import SATURATED
from poevp_optics.control.predictors.region_merges import lost_parts
from poevp_optics.control.predictors.track import RegionTracker, region_tracks

SHAPE = (120, 200)
SIGMA_PX, OVER = 6.0, 8.0          # clipped radius 12.4 px on the 10 DN road


def frame(xs, y=60.0) -> np.ndarray:
    yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]].astype(np.float64)
    img = np.full(SHAPE, 10.0)
    for x in xs:
        img += OVER * 255.0 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * SIGMA_PX ** 2))
    return np.clip(np.rint(img), 0, 255).astype(np.float32)


def positions(k: int) -> tuple[float, float]:
    return 60.0 + 10.0 * k, 140.0 - 10.0 * k


HISTORY = [frame(positions(k)) for k in range(4)]


def steps(tracks):
    """`track`'s predicted step of each frame t-1 track to frame t (region_merges.py `lost_parts`)."""
    return lambda followed: RegionTracker().step_to_last(followed, tracks[0].global_shifts)
TRUTH = frame(positions(4))


def test_the_merged_region_holds_both_lights_at_their_predicted_places():
    assert (HISTORY[3] >= SATURATED).sum() > 0
    tracks, labels = region_tracks(HISTORY)
    before, before_labels = region_tracks(HISTORY[:-1])
    assert len(before) == 2 and len(tracks) == 1                  # two lights in frame 2, one outline in 3
    parts = lost_parts(tracks, labels, before, before_labels, steps(tracks))
    (k, got), = parts.items()
    assert k == tracks[0].label and len(got) == 2
    centres = sorted(p.centre[0] for p in got)
    np.testing.assert_allclose(centres, positions(3), atol=1.0)  # constant velocity: 90 and 110
    np.testing.assert_allclose([p.centre[1] for p in got], [60.0, 60.0], atol=0.5)


@pytest.mark.parametrize("name", ["track", "track_net"])
def test_a_merged_pair_moves_on_with_each_light(name):
    """Each half of the merged outline moves 10 px towards the other, so the prediction is the
    clipped disc of one light at x = 100: centred there within 0.5 px, its edges within 1 px of
    100 -+ r (r: where 8 x 255 exp(-r^2 / 2 sigma^2) + 10 DN reaches the clip, 12.4 px). The truth
    is brighter (the two lights add: radius 14.2 px), so the IoU is that of the two radii's discs,
    (12.4 / 14.2)^2 = 0.75 less the pixel grid's edges; the merged outline held where it is, or
    moved with its one measured shift (as when it counted as one of the two lights), scores
    under 0.6."""
    r = SIGMA_PX * np.sqrt(2.0 * np.log(OVER * 255.0 / (SATURATED - 10.0)))
    pred = make_predictor(name)(HISTORY)
    ys, xs = np.nonzero(pred >= SATURATED)
    assert abs(xs.mean() - 100.0) <= 0.5 and abs(ys.mean() - 60.0) <= 0.5
    assert abs(xs.min() - (100.0 - r)) <= 1.0 and abs(xs.max() - (100.0 + r)) <= 1.0
    assert saturated_iou(pred, TRUTH) >= 0.7
    assert saturated_iou(HISTORY[3], TRUTH) < 0.6
    assert saturated_iou(make_predictor("flow")(HISTORY), TRUTH) < 0.6


def test_a_small_light_touching_a_standing_one_does_not_move_it():
    """A standing lamp (clipped radius 12.4 px) and a small light (sigma 2.5 px: radius 5.1 px)
    closing in on it at 3 px a frame, touching it in frame 3: the joined outline keeps the lamp's
    match (its area 1.19 times the lamp's, under `MERGE_AREA_GAIN`), so it does not hold the small
    light, and its pixels are not moved with the small light's motion (a wet road's glints
    touching a lamp's reflection)."""
    from poevp_optics.control.predictors.region_merges import MERGE_AREA_GAIN

    yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]].astype(np.float64)

    def scene(k):
        img = 10.0 + OVER * 255.0 * np.exp(-((xx - 100.0) ** 2 + (yy - 60.0) ** 2) / (2 * SIGMA_PX ** 2))
        img += OVER * 255.0 * np.exp(-((xx - 126.0 + 3.0 * k) ** 2 + (yy - 60.0) ** 2) / (2 * 2.5 ** 2))
        return np.clip(np.rint(img), 0, 255).astype(np.float32)

    hist = [scene(k) for k in range(4)]
    tracks, labels = region_tracks(hist)
    before, before_labels = region_tracks(hist[:-1])
    assert len(before) == 2 and len(tracks) == 1 and tracks[0].prev_label
    assert tracks[0].growths[0] ** 2 < MERGE_AREA_GAIN
    assert lost_parts(tracks, labels, before, before_labels, steps(tracks)) == {}


def test_one_light_that_lost_its_match_alone_is_not_carried_on():
    """A light moving 10 px a frame whose clipped outline more than doubles in the last frame (its
    sigma 4 -> 6.5 px) loses its match: the new region holds that one light only, and is left
    as a new region (its failed chain is not carried on: region_merges.py)."""
    def light(k, sigma):
        yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]].astype(np.float64)
        img = 10.0 + OVER * 255.0 * np.exp(-((xx - 60.0 - 10.0 * k) ** 2 + (yy - 60.0) ** 2) / (2 * sigma ** 2))
        return np.clip(np.rint(img), 0, 255).astype(np.float32)

    hist = [light(k, 4.0) for k in range(3)] + [light(3, 6.5)]
    tracks, labels = region_tracks(hist)
    before, before_labels = region_tracks(hist[:-1])
    assert len(tracks) == 1 and not tracks[0].displacements and len(before) == 1 and before[0].displacements
    assert lost_parts(tracks, labels, before, before_labels, steps(tracks)) == {}
