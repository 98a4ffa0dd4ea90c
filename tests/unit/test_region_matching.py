"""A light is the same light one frame on only when the match is mutual and the areas are alike
(region_motion.py `match_regions`): a new light appearing beside a standing one is new (predicted
where it is), not the standing one moved; lights moving together keep their own motion.

Frames are synthesised here (dim textured road, clipped elliptical lamps: tests/unit/
test_predictor_stop.py's `frame` drawn with several lamps)."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.control.predictors import make_predictor
from poevp_optics.control.region_motion import MAX_AREA_RATIO, components, extrapolate, match_regions

SHAPE = (184, 320)


def lamps(centres, seed: int = 5, axes=(14.0, 8.0)) -> np.ndarray:
    """8-bit frame: textured road (15-45 DN) and a clipped Gaussian lamp (semi-axes `axes` px at
    1/e, peak 20x saturation) at each (x, y) of `centres`."""
    rng = np.random.default_rng(seed)
    h, w = SHAPE
    img = 15.0 + 30.0 * rng.uniform(0, 1, (h, w))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    for cx, cy in centres:
        img += 20.0 * 255.0 * np.exp(-(((xx - cx) / axes[0]) ** 2 + ((yy - cy) / axes[1]) ** 2))
    return np.clip(np.rint(img), 0, 255).astype(np.float32)


def lamp_centroids(img: np.ndarray, near) -> list[np.ndarray]:
    """Saturated centroid (x, y) within 25 px of each point of `near` (NaN where none)."""
    ys, xs = np.nonzero(img >= 254.5)
    out = []
    for cx, cy in near:
        k = (xs - cx) ** 2 + (ys - cy) ** 2 <= 25.0 ** 2
        out.append(np.array([xs[k].mean(), ys[k].mean()]) if k.any() else np.array([np.nan, np.nan]))
    return out


STANDING, NEW = (130.0, 92.0), (190.0, 92.0)          # 60 px apart, same row


@pytest.mark.parametrize("name", ["flow", "track", "track_net"])
@pytest.mark.parametrize("appeared", [1, 2])
def test_new_light_beside_a_standing_one_is_predicted_in_place(name, appeared):
    """A lamp stands for four frames; another appears 60 px beside it in the last frame
    (appeared = 1) or the one before (2). Both stand in the next frame: each predicted centroid
    within 2 px of its lamp (the unmatched prediction moved the new lamp 60-80 px, onto or past
    its neighbour)."""
    hist = [lamps([STANDING] + ([NEW] if t >= 4 - appeared else [])) for t in range(4)]
    truth = lamps([STANDING, NEW])
    pred = make_predictor(name)(hist)
    got, want = lamp_centroids(pred, [STANDING, NEW]), lamp_centroids(truth, [STANDING, NEW])
    for g, w, which in zip(got, want, ("standing", "new")):
        assert np.hypot(*(g - w)) <= 2.0, f"{name}: the {which} lamp predicted at {g}, truly at {w}"


@pytest.mark.parametrize("name", ["flow", "track", "track_net"])
def test_lights_moving_together_keep_their_motion(name):
    """Two lamps 100 px apart moving 24 px/frame right together (a car's pair): each is
    predicted 24 px on, within 2 px (each region's own match, not its neighbour's)."""
    v = 24.0
    pos = lambda t: [(40.0 + v * t, 92.0), (140.0 + v * t, 92.0)]
    hist = [lamps(pos(t)) for t in range(4)]
    truth = lamps(pos(4))
    got, want = lamp_centroids(make_predictor(name)(hist), pos(4)), lamp_centroids(truth, pos(4))
    for g, w in zip(got, want):
        assert np.hypot(*(g - w)) <= 2.0, (name, g, w)


def _boxes(*boxes, shape=(40, 120)):
    m = np.zeros(shape, bool)
    for y0, x0, h, w in boxes:
        m[y0:y0 + h, x0:x0 + w] = True
    return m


def test_match_regions_is_mutual_and_needs_alike_areas():
    """Closed cases on boxes: (1) two regions of frame t claim one frame t-1 region with equal
    IoU: the smaller shift keeps it, the other is new; (2) a region 3x the area of the one it
    lands on is new (MAX_AREA_RATIO 2) unless one of them touches the frame's edge."""
    prev = _boxes((10, 20, 8, 8))
    cur = _boxes((10, 20, 8, 8), (10, 60, 8, 8))         # the standing box and a new one 40 px right
    lp, sp = components(prev)
    lc, sc = components(cur)
    k_stand, k_new = lc[12, 22], lc[12, 62]
    m = match_regions(lp, sp, lc, sc, {k_stand: (0.0, 0.0, 1.0), k_new: (40.0, 0.0, 1.0)})
    assert m[k_stand].prev_label == lp[12, 22] and m[k_new].prev_label == 0
    # the same two claims with the new box truly coming from there (no standing box): matched
    lc2, sc2 = components(_boxes((10, 60, 8, 8)))
    assert match_regions(lp, sp, lc2, sc2, {1: (40.0, 0.0, 1.0)})[1].prev_label == 1
    assert MAX_AREA_RATIO == 2.0
    big = _boxes((10, 20, 8, 24))                        # 3x the area, same place
    lb, sb = components(big)
    assert match_regions(lp, sp, lb, sb, {1: (0.0, 0.0, 1.0)})[1].prev_label == 0
    edge_prev, edge_cur = _boxes((10, 0, 8, 8)), _boxes((10, 0, 8, 24))   # entering from the left
    lpe, spe = components(edge_prev)
    lce, sce = components(edge_cur)
    assert match_regions(lpe, spe, lce, sce, {1: (0.0, 0.0, 1.0)})[1].prev_label == 1
    # a weak correlation response is no match
    assert match_regions(lp, sp, lc2, sc2, {1: (40.0, 0.0, 0.01)}, min_response=0.05)[1].prev_label == 0


def test_extrapolate_leaves_a_split_off_region_in_place():
    """Demand maps: one box in frame t-1 splits into two in frame t; the piece overlapping it
    most keeps the match (moved on by its box map), the other, with no mutual match, is not moved
    (and not carried: extrapolate returns only moved regions; matched by overlap alone it was
    moved on, shrunk, to columns 51-55)."""
    prev = _boxes((10, 20, 8, 30)).astype(np.float32)
    cur = _boxes((10, 20, 8, 20), (10, 44, 8, 6)).astype(np.float32)
    out = extrapolate(prev, cur, 0.5)
    assert out[:, 40:].sum() == 0                        # the small split-off piece: no match
    assert out[:, :40].any()


def test_a_lamp_whose_correlation_landed_on_its_twin_takes_its_neighbours_shift():
    """A pair of like boxes moving 10 px right; the second box's own shift (40 px) moves it back
    onto the first box's old place (what the outline correlation can do with twin lamps): both
    claim that box, the smaller shift keeps it, and the second box, trying its neighbour's shift,
    lands on its own old place (unclaimed, IoU 1): matched with (10, 0)."""
    prev = _boxes((10, 10, 8, 8), (10, 40, 8, 8))
    cur = _boxes((10, 20, 8, 8), (10, 50, 8, 8))
    lp, sp = components(prev)
    lc, sc = components(cur)
    a, b = lc[12, 22], lc[12, 52]
    m = match_regions(lp, sp, lc, sc, {a: (10.0, 0.0, 1.0), b: (40.0, 0.0, 1.0)})
    assert m[a].prev_label == lp[12, 12] and m[b].prev_label == lp[12, 42]
    assert m[b].shift == (10.0, 0.0)


@pytest.mark.parametrize("name", ["flow", "track", "track_net"])
def test_two_lamps_crossing_keep_their_identities(name):
    """Two like lamps 40 px apart in height pass each other at 16 px/frame in opposite
    directions (level in frame 2): each is predicted 16 px on its own way, within 2 px. Both
    lie in each other's correlation window, where the outline correlation of one lands as well
    on the other's old place; taken as they came (a mutual match of the two swapped) the lower
    lamp was predicted 8 px off."""
    v = 16.0
    pos = lambda t: [(100.0 + v * t, 80.0), (100.0 + 4 * v - v * t, 120.0)]
    hist = [lamps(pos(t)) for t in range(4)]
    got, want = lamp_centroids(make_predictor(name)(hist), pos(4)), lamp_centroids(lamps(pos(4)), pos(4))
    for g, w in zip(got, want):
        assert np.hypot(*(g - w)) <= 2.0, (name, g, w)


def test_unswap_exchanges_a_swapped_pair_only_where_it_moves_less():
    """Boxes: A moves 10 px right, B 10 px left, 20 px lower. Matched swapped (A <- B's old
    place, B <- A's), the exchange moves them 10 + 10 px against 2 x 22.4: undone, with shifts
    (+-10, 0). Two boxes moving 10 px right together and read swapped (shifts -20 and +40)
    are undone too; a right pair (shifts 10, 10) is left as it is (the exchange moves them
    30 + 10 px)."""
    from poevp_optics.control.region_motion import RegionMatch, unswap

    prev = _boxes((2, 20, 8, 8), (22, 40, 8, 8))
    cur = _boxes((2, 30, 8, 8), (22, 30, 8, 8))
    lp, sp = components(prev)
    lc, sc = components(cur)
    a, b, pa, pb = lc[4, 32], lc[24, 32], lp[4, 22], lp[24, 42]
    swapped = {a: RegionMatch(a, pb, (-10.0, -20.0), 1.0), b: RegionMatch(b, pa, (10.0, 20.0), 1.0)}
    m = unswap(swapped, lp, sp, lc, sc)
    assert (m[a].prev_label, m[b].prev_label) == (pa, pb)
    assert m[a].shift == (10.0, 0.0) and m[b].shift == (-10.0, 0.0)
    prev = _boxes((10, 20, 8, 8), (10, 50, 8, 8))
    cur = _boxes((10, 30, 8, 8), (10, 60, 8, 8))
    lp, sp = components(prev)
    lc, sc = components(cur)
    a, b, pa, pb = lc[12, 32], lc[12, 62], lp[12, 22], lp[12, 52]
    m = unswap({a: RegionMatch(a, pb, (-20.0, 0.0), 1.0), b: RegionMatch(b, pa, (40.0, 0.0), 1.0)}, lp, sp, lc, sc)
    assert (m[a].prev_label, m[b].prev_label, m[a].shift, m[b].shift) == (pa, pb, (10.0, 0.0), (10.0, 0.0))
    right = {a: RegionMatch(a, pa, (10.0, 0.0), 1.0), b: RegionMatch(b, pb, (10.0, 0.0), 1.0)}
    assert unswap(right, lp, sp, lc, sc) == right


def test_reclaim_gives_a_lamp_back_the_old_place_its_twin_took():
    """Boxes A, B (a lamp pair) and C (the plate) all move 10 px right. A's correlation read
    -20 px (onto B's old place) and B's -50 px (onto nothing): `match_regions` gives A B's old
    place and leaves B new. B, moved back by its neighbour C's shift (10 px, under 0.8 of A's
    20), lands on its own old place and takes it over; A then finds its own by B's shift."""
    from poevp_optics.control.region_motion import reclaim

    prev = _boxes((6, 10, 8, 8), (6, 40, 8, 8), (26, 70, 6, 10))
    cur = _boxes((6, 20, 8, 8), (6, 50, 8, 8), (26, 80, 6, 10))
    lp, sp = components(prev)
    lc, sc = components(cur)
    a, b, c = lc[8, 22], lc[8, 52], lc[28, 82]
    pa, pb, pc = lp[8, 12], lp[8, 42], lp[28, 72]
    m = match_regions(lp, sp, lc, sc, {a: (-20.0, 0.0, 1.0), b: (-50.0, 0.0, 1.0), c: (10.0, 0.0, 1.0)})
    assert (m[a].prev_label, m[b].prev_label, m[c].prev_label) == (pb, 0, pc)
    r = reclaim(lp, sp, lc, sc, m)
    assert (r[a].prev_label, r[b].prev_label, r[c].prev_label) == (pa, pb, pc)
    assert r[a].shift == r[b].shift == (10.0, 0.0)


def test_unswap_keeps_a_match_that_continues_its_motion():
    """Boxes A and B, 12 px apart in height, pass each other at 30 px/frame. Their true matches
    (+-30 px) move them more than the exchanged ones (0, -+12 px): with no earlier motion known
    the exchange is taken; given each earlier box's shift from the frame before (+-30 px), the
    true matches continue it exactly and stand."""
    from poevp_optics.control.region_motion import RegionMatch, unswap

    lp, sp = components(_boxes((2, 20, 8, 8), (14, 50, 8, 8)))
    lc, sc = components(_boxes((2, 50, 8, 8), (14, 20, 8, 8)))
    a, b, pa, pb = lc[4, 52], lc[16, 22], lp[4, 22], lp[16, 52]
    true = {a: RegionMatch(a, pa, (30.0, 0.0), 1.0), b: RegionMatch(b, pb, (-30.0, 0.0), 1.0)}
    assert unswap(true, lp, sp, lc, sc, prior={pa: (30.0, 0.0), pb: (-30.0, 0.0)}) == true
    m = unswap(true, lp, sp, lc, sc)
    assert (m[a].prev_label, m[b].prev_label, m[a].shift, m[b].shift) == (pb, pa, (0.0, -12.0), (0.0, 12.0))
