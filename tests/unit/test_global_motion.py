"""The frame's global motion (the camera's own pitch and yaw): the consensus shift of the matched
regions (region_motion.py `global_shift`), its extrapolation (track.py `closed_form_global`), and
the trackers' use of it (a region's own motion relative to it; a new region moves with it).
Expectations are closed forms: medians of the given shifts, a sinusoid's next sample, a
constant shift continued."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.control.predictors import make_predictor
from poevp_optics.control.predictors.flow import SATURATED
from poevp_optics.control.predictors.track import closed_form_displacement, closed_form_global, region_tracks
from poevp_optics.control.region_motion import MIN_GLOBAL_REGIONS, global_shift

SHAPE = (120, 200)
#: Blob centres (px, x and y) at frame 0: spread over the frame as street lights and cars are.
CENTRES = np.array([[30.0, 25.0], [100.0, 20.0], [165.0, 30.0], [40.0, 90.0], [150.0, 95.0]])


def frame(centres) -> np.ndarray:
    """An 8-bit frame: a Gaussian highlight (sigma 4 px, 8x over saturation: clipped to a disc of
    ~5.8 px radius) at each centre on a dark road of 10 DN."""
    yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]].astype(np.float64)
    img = np.full(SHAPE, 10.0)
    for cx, cy in np.asarray(centres).reshape(-1, 2):
        img += 2000.0 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * 4.0 ** 2))
    return np.clip(np.rint(img), 0, 255).astype(np.float32)


def saturated_centroids(img) -> np.ndarray:
    from scipy import ndimage

    lab, n = ndimage.label(np.asarray(img) >= SATURATED, structure=np.ones((3, 3)))
    return np.array([c[::-1] for c in ndimage.center_of_mass(np.ones_like(lab), lab, range(1, n + 1))])


def assert_lands_on(pred, truth_centres, tol_px=1.0):
    got = saturated_centroids(pred)
    want = np.asarray(truth_centres).reshape(-1, 2)
    assert len(got) == len(want)
    dist = np.hypot(*(got[:, None, :] - want[None, :, :]).transpose(2, 0, 1)).min(0)
    assert dist.max() <= tol_px, dist


def test_global_shift_is_the_median_of_the_largest_agreeing_set():
    rng = np.random.default_rng(3)
    common = np.array([3.0, -2.0]) + rng.uniform(-0.4, 0.4, (5, 2))
    movers = np.array([[20.0, 0.0], [21.0, 0.5], [-9.0, 4.0]])       # a car's two lamps and another light
    g = global_shift(np.concatenate([movers, common]), responses=np.arange(8) / 10.0)
    np.testing.assert_allclose(g.shift, np.median(common, axis=0), atol=1e-12)
    assert g.support == 5 and g.response == pytest.approx(np.median(np.arange(3, 8) / 10.0))
    # fewer agreeing regions than MIN_GLOBAL_REGIONS: no global motion
    none = global_shift(np.array([[5.0, 5.0], [5.2, 5.0], [-8.0, 1.0], [14.0, 3.0]]))
    assert MIN_GLOBAL_REGIONS == 3 and none.support == 0 and none.shift == (0.0, 0.0)
    # one car's three lights (2 px apart in height) are not the camera's motion; spread over the
    # frame's height (a street lamp high, a parked car low) they are
    car = np.array([[9.0, 1.0], [9.2, 1.1], [8.9, 0.9]])
    assert global_shift(car, centres_y=[100.0, 100.0, 102.0], height=200).support == 0
    assert global_shift(car, centres_y=[20.0, 150.0, 152.0], height=200).support == 3
    # two equal sets: the standing one (smaller shift) is the global motion
    tie = global_shift(np.array([[0.0, 0.1], [0.1, 0.0], [0.0, 0.0], [12.0, 3.0], [12.1, 3.0], [12.0, 3.1]]))
    np.testing.assert_allclose(tie.shift, (0.0, 0.0))


@pytest.mark.parametrize("period, phase", [(4.0, 0.3), (6.5, 2.0), (9.0, 4.0)])
def test_an_oscillating_global_motion_is_continued_as_a_sinusoid(period, phase):
    """A pitch bounce y(k) = A sin(2 pi k / P + phi) moves the image by y(k+1) - y(k), itself a
    sinusoid of period P: its next value is 2 cos(2 pi / P) g_t - g_{t-1}. A steady chain takes
    `closed_form_displacement`'s row (a stop: the gate keeps the last displacement)."""
    k = np.arange(5, dtype=np.float64)
    y = 10.0 * np.sin(2 * np.pi * k / period + phase)
    x = 2.0 * k                                                       # a steady yaw: 2 px a frame
    d = np.diff(np.stack([x, y], 1), axis=0)                          # g_0 .. g_3
    chain = d[2::-1]                                                  # g_2, g_1, g_0: newest first
    if abs(chain[1, 1]) < 2.0:
        pytest.skip("middle sample near a zero crossing")
    # the ridge (0.05 px^2 against a middle sample of >= 2 px) moves c by <= 1.3 %
    np.testing.assert_allclose(closed_form_global(chain), d[3], atol=0.1 * abs(chain[0, 1]) + 0.05)
    np.testing.assert_allclose(closed_form_global([[0.0, 0.5], [0.0, 4.0], [0.0, 8.0]]),
                               closed_form_displacement([[0.0, 0.5], [0.0, 4.0], [0.0, 8.0]]))
    np.testing.assert_allclose(closed_form_global([[3.0, -1.0], [3.0, -1.0], [3.0, -1.0]]), [3.0, -1.0])
    np.testing.assert_allclose(closed_form_global([[3.0, -1.0]]), [3.0, -1.0])


@pytest.mark.parametrize("drift, sigma", [(0.0, 1.5), (0.0, 0.5), (3.0, 0.3)])
def test_the_yaw_is_continued_by_its_drift_not_by_its_corrections(drift, sigma):
    """The heading a random walk: yaw shifts g_k = drift + e_k with e_k independent N(0, sigma^2).
    Nothing forecasts g_{t+1} from the past better than the drift itself (mean square error
    sigma^2); the mean of the three past shifts errs by sigma^2 (1 + 1/3); the rule (the mean, or
    0 where it does not stand out) lies between the two, within four Monte Carlo standard errors
    (the squared error of a normal variate of variance v has standard deviation v sqrt 2), and
    below half the least-squares extrapolation's sigma^2 (1 + 21/9) (track.py's table)."""
    rng = np.random.default_rng(11)
    n = 4000
    g = drift + sigma * rng.normal(size=(n, 4))                  # column 0 next; 1..3 newest first
    pitch = np.zeros(3)
    pred = np.array([closed_form_global(np.c_[row[1:], pitch])[0] for row in g])
    mse = float(np.mean((pred - g[:, 0]) ** 2))
    se = 4.0 / 3.0 * sigma ** 2 * np.sqrt(2.0 / n)
    assert sigma ** 2 - 4 * se <= mse <= 4.0 / 3.0 * sigma ** 2 + 4 * se
    assert mse < (1.0 + 21.0 / 9.0) * sigma ** 2 / 2.0
    if drift:                                                    # a bend: its drift is always seen
        np.testing.assert_allclose(mse, 4.0 / 3.0 * sigma ** 2, atol=4 * se)


@pytest.mark.parametrize("name", ["track", "track_net"])
def test_a_pure_global_shift_is_predicted_within_a_pixel(name):
    """Every light moved by one shift a frame (the camera panning: 5, -3 px), and a light that
    appears in the last frame (no history: new): all land within 1 px of where the shift takes
    them; the new one moves with the global motion."""
    step = np.array([5.0, -3.0])
    newcomer = np.array([95.0, 60.0])
    hist = [frame(CENTRES + k * step) for k in range(3)]
    hist.append(frame(np.concatenate([CENTRES + 3 * step, newcomer[None]])))
    tracks, _ = region_tracks(hist)
    assert len(tracks) == 6 and sum(not t.displacements for t in tracks) == 1
    np.testing.assert_allclose(tracks[0].global_shifts, [step] * 3, atol=0.3)
    pred = make_predictor(name)(hist)
    assert_lands_on(pred, np.concatenate([CENTRES + 4 * step, (newcomer + step)[None]]))


def test_an_independent_mover_among_shifted_lights_keeps_its_own_motion():
    """Four lights shift with the camera (2, 1.5 px a frame); one car's lamp moves on its own (12
    px a frame to the right, besides the camera's shift): the global shift is the four's, and the
    lamp is continued at 14, 1.5 px, the four at 2, 1.5."""
    cam = np.array([2.0, 1.5])
    own = np.array([12.0, 0.0])
    still, mover = CENTRES[1:], CENTRES[0]
    hist = [frame(np.concatenate([still + k * cam, (mover + k * (cam + own))[None]])) for k in range(4)]
    tracks, _ = region_tracks(hist)
    np.testing.assert_allclose(tracks[0].global_shifts, [cam] * 3, atol=0.3)
    pred = make_predictor("track")(hist)
    assert_lands_on(pred, np.concatenate([still + 4 * cam, (mover + 4 * (cam + own))[None]]))
