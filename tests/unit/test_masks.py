"""Mask laws: the paper's Eq. 2 readings, the target law, smoothing, bounds (issue 3)."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.control.masks import mask_levels, smooth_envelope, target_levels, threshold_exp, threshold_ratio
from poevp_optics.control.masks import MaskSpec
X = np.arange(256, dtype=np.float64)


@pytest.mark.parametrize("a,b", [(0.9, 0.0), (0.7, 0.2), (1.0, 0.0), (0.0, 0.0), (0.5, 1.0)])
def test_threshold_laws_are_bounded_finite_and_white_below_vs(a, b):
    for law in (threshold_exp, threshold_ratio):
        m = law(X, 200.0, a, b)
        assert np.all(np.isfinite(m)) and m.min() >= 0 and m.max() <= 255
        assert np.all(m[:200] == 255)


def test_threshold_exp_formula_and_limit():
    m = threshold_exp(np.array([210.0, 254.0, 255.0]), 200.0, 0.9, 0.0)
    np.testing.assert_allclose(m[:2], 255 * 0.9 ** (np.array([210.0, 254.0]) / (255 - np.array([210.0, 254.0]))))
    assert m[2] == 0.0                                   # limit x -> 255 for a < 1
    m = threshold_exp(np.array([230.0]), 200.0, 0.7, 0.2)
    np.testing.assert_allclose(m, 255 * 0.7 ** ((230 - 0.2 * 200) / 25))


def test_threshold_ratio_formula():
    m = threshold_ratio(np.array([200.0, 255.0]), 200.0, 0.7, 0.2)
    np.testing.assert_allclose(m, 255 * (0.7 * 200 / np.array([200.0, 255.0]) + 0.2))


def test_target_law_brings_signal_to_target():
    table = np.linspace(0.1, 1.0, 256)            # exposure per level, white = 1
    e = np.array([100.0, 5000.0, 20000.0, 1e7])
    lv = target_levels(e, full_well_e=10000.0, target=0.5, level_exposure=table).astype(int)
    got = e * table[lv]
    assert lv[0] == 255 and lv[1] == 255          # already below target: white
    assert got[2] <= 5000.0 and e[2] * table[min(lv[2] + 1, 255)] > 5000.0  # largest level that fits
    assert lv[3] == 0                               # beyond the floor: darkest level


def test_target_law_handles_non_monotone_tables():
    rng = np.random.default_rng(0)
    table = rng.uniform(0.2, 1.0, 256)
    table[-1] = 1.0
    e = np.full(50, 15000.0)
    lv = target_levels(e, 10000.0, 0.5, table).astype(int)
    got = e * table[lv]
    ok = table * 15000.0 <= 5000.0
    assert np.all(got <= 5000.0 + 1e-9) and np.allclose(got, 15000.0 * table[ok].max())


def test_smooth_envelope_never_under_attenuates_and_is_smooth():
    img = np.zeros((64, 64))
    img[30:34, 20:44] = 255.0
    img[31, 25] = 250.0
    env = smooth_envelope(img, 4.0)
    assert np.all(env[30:34, 20:44] >= 255.0 - 1e-9)   # the whole bright bar keeps full value
    assert np.abs(np.diff(env, axis=1)).max() < 60       # no hard edges


def test_mask_levels_scale_to_bits():
    spec = MaskSpec(law="threshold_ratio", vs=200.0, a=0.9, b=0.0, smooth_px=0.0)
    lv = mask_levels(spec, 4, pred_8bit=np.array([[10.0, 255.0]]))
    assert lv[0, 0] == 15 and 0 <= lv[0, 1] <= 15 and float(lv[0, 1]).is_integer()


# ---------------------------------------------------------------- issue 13: law edge cases
def test_target_law_edges_are_consistent():
    """A prediction of 0, -0.0 or below needs no dimming (white); NaN is taken as infinitely
    bright (the darkest usable level). -0.0 used to fall to the darkest level (1 / -0.0 = -inf)."""
    table = np.linspace(0.001, 1.0, 256)
    e = np.array([0.0, -0.0, -5.0, 1e9, np.nan], dtype=np.float32)
    lv = target_levels(e, 1000.0, 0.5, table, min_level=1)
    assert lv[0] == lv[1] == lv[2] == 255
    assert lv[3] == lv[4] == 1


def test_paper_laws_treat_nan_alike():
    """Both readings of Eq. 2 take a NaN prediction as clipped (255): finite, equal to 255's."""
    for law in (threshold_exp, threshold_ratio):
        out = law(np.array([np.nan, 255.0]), 200.0, 0.9, 0.0)
        assert np.all(np.isfinite(out)) and out[0] == out[1]


def test_predicted_electrons_remove_the_black_level():
    """x on the 8-bit scale is offset + gain e (rescaled): the black level reads 0 e-, a value
    halfway to the top code (clipped_gain aside) the matching electrons. The old conversion
    read 3 DN of black as 123 e-."""
    from poevp_optics.control.masks import predicted_electrons
    from poevp_optics.camera.sensor import SensorSpec
    from poevp_optics.camera.sensor import resolve_sensor

    p = resolve_sensor(SensorSpec())
    black_8 = p.offset_dn * 255.0 / p.max_dn
    x = np.array([black_8, 0.0, 128.0, 255.0])
    e = predicted_electrons(x, p, clipped_gain=32.0)
    assert e[0] == pytest.approx(0.0, abs=1e-9) and e[1] == 0.0
    assert e[2] == pytest.approx((128.0 * p.max_dn / 255.0 - p.offset_dn) / p.gain_dn_per_e)
    assert e[3] == pytest.approx(32.0 * p.saturation_capacity_e)
