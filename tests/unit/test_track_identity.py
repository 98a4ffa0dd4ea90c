"""Region identity through merges and splits (track.py `inherited_chain`): a region with no
match of alike area continues the motion of the earlier regions it was formed from; a light
with nothing before it at its place stays where it is."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.control.predictors import make_predictor
from poevp_optics.control.predictors.flow import SATURATED
from poevp_optics.control.predictors.track import region_tracks

SHAPE = (96, 160)
SIGMA_PX = 3.0
#: A lamp 15x over saturation: its saturated disc has radius sqrt(2 ln 15.2) sigma = 7 px.
PEAK = 255.0 * np.exp(49.0 / (2 * SIGMA_PX ** 2))


def frame(centres) -> np.ndarray:
    """8-bit frame of Gaussian lamps (sigma SIGMA_PX, peak PEAK) at `centres` (x, y px): their
    light adds, so two lamps closer than ~15.7 px join in one saturated blob."""
    yy, xx = np.mgrid[:SHAPE[0], :SHAPE[1]].astype(np.float64)
    f = np.zeros(SHAPE)
    for cx, cy in centres:
        f += PEAK * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * SIGMA_PX ** 2))
    return np.minimum(f, 255.0).astype(np.float32)


def blobs(f: np.ndarray):
    """(labels, areas px, centroids (x, y) px) of the saturated regions, by SciPy's labelling."""
    from scipy import ndimage

    lab, n = ndimage.label(f >= SATURATED, structure=np.ones((3, 3)))
    idx = range(1, n + 1)
    areas = np.array(ndimage.sum_labels(np.ones_like(f), lab, idx))
    cents = np.array(ndimage.center_of_mass(np.ones_like(f), lab, idx))[:, ::-1]
    return lab, areas, cents


def track_at(tracks, labels, xy):
    k = labels[int(round(xy[1])), int(round(xy[0]))]
    return next(t for t in tracks if t.label == k)


@pytest.fixture(scope="module")
def merge_case():
    """Lamp A (12, 1) px/frame overtakes lamp B (4, 0) px/frame; they join on the newest frame
    (3), where a third lamp appears far from both."""
    va, vb = np.array([12.0, 1.0]), np.array([4.0, 0.0])
    a0, b0, new = np.array([22.0, 38.0]), np.array([60.0, 44.0]), (135.0, 80.0)
    hist = [frame([a0 + f * va, b0 + f * vb] + ([new] if f == 3 else [])) for f in range(4)]
    return hist, va, vb, new


def test_merged_lamps_move_by_their_area_weighted_displacement(merge_case):
    hist, va, vb, new = merge_case
    _, areas2, cents2 = blobs(hist[2])
    lab3, areas3, cents3 = blobs(hist[3])
    assert len(areas2) == 2 and len(areas3) == 2                      # two lamps, then one blob (+ the new lamp)
    ia = int(np.argmin(cents2[:, 0]))                                   # lamp A is the left one on frame 2
    w = np.array([areas2[ia], areas2[1 - ia]])
    expected = (w[0] * va + w[1] * vb) / w.sum()
    blob = int(np.argmin(cents3[:, 0]))
    assert areas3[blob] > 2 * w.max()                                   # not alike either lamp: no match
    tracks, labels = region_tracks(hist)
    tr = track_at(tracks, labels, cents3[blob])
    assert len(tr.displacements) == 3
    for name, tol in (("track", 0.3), ("track_net", 1.0)):
        p = make_predictor(name)
        d = p.next_displacement(tracks)[tracks.index(tr)]
        np.testing.assert_allclose(d, expected, atol=tol, err_msg=name)
    # the predicted frame: the blob's pixels moved by that displacement (rounded to whole px)
    pred = make_predictor("track")(hist)
    _, _, cents_p = blobs(pred)
    moved = cents_p[np.argmin(np.hypot(*(cents_p - cents3[blob] - expected).T))]
    np.testing.assert_allclose(moved - cents3[blob], expected, atol=0.6)


def test_a_new_lamp_away_from_others_stands(merge_case):
    hist, _, _, new = merge_case
    tracks, labels = region_tracks(hist)
    tr = track_at(tracks, labels, new)
    assert tr.displacements == ()
    for name in ("track", "track_net"):
        np.testing.assert_allclose(make_predictor(name).next_displacement(tracks)[tracks.index(tr)], 0.0, atol=1e-9)


def test_split_lamps_continue_their_blob_s_motion():
    """Two lamps of one car, 10-14 px apart, read as one blob moving (10, 2) px/frame (their
    centroid's motion: they part symmetrically by 2 px/frame), are apart on the newest frame:
    each piece keeps the blob's motion."""
    v = np.array([10.0, 2.0])
    c0 = np.array([40.0, 40.0])
    hist = [frame([c0 + f * v - (5 + f, 0), c0 + f * v + (5 + f, 0)]) for f in range(4)]
    _, areas2, _ = blobs(hist[2])
    _, areas3, cents3 = blobs(hist[3])
    assert len(areas2) == 1 and len(areas3) == 2 and areas2[0] > 2 * areas3.max()   # one blob, then two halves
    tracks, labels = region_tracks(hist)
    for name, tol in (("track", 0.3), ("track_net", 1.0)):
        p = make_predictor(name)
        ds = p.next_displacement(tracks)
        for c in cents3:
            tr = track_at(tracks, labels, c)
            assert len(tr.displacements) == 3
            np.testing.assert_allclose(ds[tracks.index(tr)], v, atol=tol, err_msg=name)
