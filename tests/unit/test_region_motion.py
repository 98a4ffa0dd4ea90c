"""Region extrapolation for the exposure controller (region_motion.py; issue 18, night_road's
last frame): a bright box moving at constant velocity lands where the closed form puts it, and a
highlight moving faster than the carry radius behind a lagging predictor stays in the band with
mask.carry = "extrapolate" where the dilated carry clips it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from poevp_optics.control.exposure_control import ExposureController
from poevp_optics.control.masks import mask_levels
from poevp_optics.control.region_motion import extrapolate
from tests.unit.test_exposure_controller import SAT_E, SENSOR, SPEC, closed_form_white, level_table

H, W = 64, 160


def box_map(y0, x0, h, w, value=50.0):
    """Demand map (e-): `value` x saturation on rows y0..y0+h, columns x0..x0+w, 0 elsewhere."""
    d = np.zeros((H, W), np.float32)
    d[y0:y0 + h, x0:x0 + w] = value * SAT_E
    return d


def bbox(img):
    ys, xs = np.nonzero(img)
    return ys.min(), xs.min(), ys.max() + 1, xs.max() + 1


def test_box_moving_and_growing_lands_on_the_closed_form():
    """Per axis the box's size grows by a = 1.25 and its centre maps as c' = a c + b: from
    rows [8, 16) to [14, 24) (centre 12 -> 19, b = 19 - 1.25 x 12 = 4), the next box has height
    12.5 and centre 1.25 x 19 + 4 = 27.75, i.e. rows 21.5..34; columns [20, 40) -> [30, 55)
    (centre 30 -> 42.5, b = 5): width 31.25, centre 58.125, columns 42.5..73.75. Integer pixel
    edges: within 1 px. The demand value is carried unchanged."""
    out = extrapolate(box_map(8, 20, 8, 20), box_map(14, 30, 10, 25), SAT_E)
    y0, x0, y1, x1 = bbox(out)
    np.testing.assert_allclose([y0, x0, y1, x1], [21.5, 42.5, 34.0, 73.75], atol=1.0)
    assert np.all(out[out > 0] == np.float32(50 * SAT_E))


def test_regions_move_independently_and_a_new_region_stays():
    """Two boxes moving apart (+6 and -6 columns per frame) each move on by their own shift; a
    region with no overlap in the previous frame (new) is not moved (and not carried)."""
    prev = box_map(10, 40, 8, 10) + box_map(40, 100, 8, 10)
    cur = box_map(10, 46, 8, 10) + box_map(40, 94, 8, 10) + box_map(25, 5, 6, 6)
    out = extrapolate(prev, cur, SAT_E)
    np.testing.assert_array_equal(bbox(out[:30, :80]), (10, 52, 18, 62))
    np.testing.assert_array_equal(bbox(out[30:, 80:]), (10, 8, 18, 18))   # rows 40..48, columns 88..98
    assert not out[20:32, :20].any()


def test_below_level_is_ignored():
    """Only demand >= level (saturation) is moved: a region under it gives nothing."""
    assert not extrapolate(box_map(8, 20, 8, 20, 0.5), box_map(8, 30, 8, 20, 0.5), SAT_E).any()


SPEED_PX, OVER, BOX = 10, 20.0, (14, 24)            # 10 px per frame > the carry radius R = 6


def hold_loop(carry, speed_px=SPEED_PX, frames=9, init=2):
    """Closed loop on the mirror grid, ideal sensor, a predictor that holds the last encoded
    capture (masked: raw mode), i.e. lags the box by one frame: per loop frame the box's clipped
    fraction and its core white (x saturation)."""
    spec = dataclasses.replace(SPEC, carry=carry)
    table = level_table()
    rel = table / table[-1]
    ctl = ExposureController(spec.first_guess, spec.clip_step, int(np.ceil(3 * spec.smooth_px)), SAT_E,
                             extrapolate=carry == "extrapolate")
    mask, enc8, out = np.full((H, W), 255.0), None, []
    for t in range(frames):
        inside = box_map(20, 10 + speed_px * t, *BOX) > 0
        truth = np.where(inside, OVER, 0.05) * SAT_E
        if t >= init:
            pred_e = np.where(enc8 >= 254.5, spec.clipped_gain * SAT_E, enc8 / 255 * SAT_E)
            mask = mask_levels(spec, 8, pred_8bit=enc8, pred_electrons=pred_e, full_well_e=SAT_E,
                               level_exposure=table, sensor=SENSOR, controller=ctl, pred_masked=True)
        r = rel[mask.astype(int)]
        e = np.minimum(truth * r, SAT_E)
        ctl.observe(e / r, truth * r >= SAT_E, r)
        enc8 = e / SAT_E * 255
        if t >= init:
            out.append((float(np.mean(truth[inside] * r[inside] >= SAT_E)),
                        float(np.median(e[inside] / SAT_E))))
    return out, rel


def test_lagging_predictor_fast_box_in_band_with_extrapolation():
    """With the dilated carry the box's leading edge (10 px ahead of a prediction that lags a
    frame, 4 px beyond R) clips on every loop frame; moved on at its velocity, no pixel clips
    and the white is the closed form of a static box (uniform box, noise-free: exact to float32
    rounding) from the second loop frame on (the first follows the white initialisation)."""
    dilated, _ = hold_loop("dilate")
    assert all(clip > 0 for clip, _ in dilated[1:])
    moved, rel = hold_loop("extrapolate")
    assert all(clip == 0 for clip, _ in moved[1:])
    expect = closed_form_white(OVER, rel)
    np.testing.assert_allclose([w for _, w in moved[2:]], expect, rtol=1e-5)


@pytest.mark.parametrize("carry", ["dilate", "extrapolate"])
def test_static_box_unchanged_by_carry(carry):
    """A box that does not move: extrapolation moves it nowhere, both carries give the same
    settled white (the closed form)."""
    out, rel = hold_loop(carry, speed_px=0)
    np.testing.assert_allclose([w for _, w in out[3:]], closed_form_white(OVER, rel), rtol=1e-5)
    assert all(clip == 0 for clip, _ in out[1:])
