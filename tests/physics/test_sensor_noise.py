"""Sensor noise statistics and numerical stability over extreme ranges (issue 3)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from drjit.auto import Float

from poevp_optics.camera.sensor import SensorSpec
from poevp_optics.camera.sensor import NoiseSwitches, Sensor, resolve_sensor

N = 200_000


@pytest.mark.parametrize("signal_e", [0.3, 1.0, 10.0, 100.0, 1e3, 1e4, 1e5, 1e6, 1e7])
def test_noise_mean_and_variance_match_theory_at_every_decade(signal_e):
    """DN = offset + g (Poisson(s + dark) + N(0, r^2)) rounded: mean offset + g (s + dark),
    variance g^2 (s + dark + r^2) + 1/12 (rounding of a smooth distribution, Sheppard)."""
    p = resolve_sensor(SensorSpec(preset="generic", bits=24, full_well_e=1e8, gain_dn_per_e=1.0,
                                  offset_dn=1000.0, read_noise_e=2.0, dark_current_e_per_s=5.0))
    s = Sensor(p, (1, N), NoiseSwitches(prnu=False, dsnu=False))
    t = 0.1
    dn, _ = s.capture(Float(np.full(N, signal_e, np.float32)), t, seed=int(signal_e * 10) + 3)
    x = np.array(dn, dtype=np.float64)
    lam = signal_e + p.dark_current_e_per_s * t
    mean_th = p.offset_dn + lam
    var_th = lam + p.read_noise_e ** 2 + 1 / 12
    # sigma of the sample mean: sqrt(var / N); of the sample variance: sqrt((mu4 - var^2) / N),
    # mu4 of Poisson + Gaussian: 3 var^2 + lam (Poisson excess kurtosis 1 / lam times lam^2)
    mu4 = 3 * var_th ** 2 + lam
    assert abs(x.mean() - mean_th) < 3 * math.sqrt(var_th / N), (x.mean(), mean_th)
    assert abs(x.var() - var_th) < 3 * math.sqrt((mu4 - var_th ** 2) / N), (x.var(), var_th)


def test_full_well_and_adc_clip():
    p = resolve_sensor(SensorSpec(preset="IMX253", bits=8))
    s = Sensor(p, (1, 1000))
    dn, e = s.capture(Float(np.full(1000, 1e9, np.float32)), 0.01, seed=1)
    assert np.all(np.array(dn) == 255) and np.all(np.array(e) <= p.full_well_e)
    dn0, _ = s.capture(Float(np.zeros(1000, np.float32)), 0.01, seed=2)
    assert np.array(dn0).min() >= 0 and abs(np.array(dn0).mean() - p.offset_dn) < 0.5


def test_fixed_pattern_is_fixed_per_sensor_instance():
    p = resolve_sensor(SensorSpec(preset="IMX253", prnu=0.02, dsnu_e=3.0, seed=5))
    a, b = Sensor(p, (8, 8)), Sensor(p, (8, 8))
    np.testing.assert_array_equal(np.array(a.gain_map), np.array(b.gain_map))
    c = Sensor(resolve_sensor(SensorSpec(preset="IMX253", prnu=0.02, seed=6)), (8, 8))
    assert np.any(np.array(a.gain_map) != np.array(c.gain_map))


def test_noise_off_draws_no_random_numbers():
    p = resolve_sensor(SensorSpec(preset="IMX253", noise=False))
    s = Sensor(p, (4, 4))
    dn1, _ = s.capture(Float(np.full(16, 5000.0, np.float32)), 0.01, seed=1)
    dn2, _ = s.capture(Float(np.full(16, 5000.0, np.float32)), 0.01, seed=2)
    assert s.random_draws == 0
    np.testing.assert_array_equal(np.array(dn1), np.array(dn2))


@pytest.mark.parametrize("full_well_e", [1e3, 1e4, 1e5, 1e6])
@pytest.mark.parametrize("exposure_s", [1e-6, 1e-3, 1.0, 10.0])
def test_extreme_ranges_stay_finite_and_bounded(full_well_e, exposure_s):
    """Electron means from 1e-9 to 1e12 (radiance 1e-3..1e8 times any exposure): no NaN/Inf,
    DN within [0, 2^bits - 1], shot noise never negative."""
    p = resolve_sensor(SensorSpec(preset="IMX253", bits=12, full_well_e=full_well_e))
    s = Sensor(p, (1, 64))
    sig = np.logspace(-3, 8, 64).astype(np.float32) * 1e4 * exposure_s
    dn, e = s.capture(Float(sig), exposure_s, seed=9)
    dn, e = np.array(dn), np.array(e)
    assert np.all(np.isfinite(dn)) and np.all(np.isfinite(e))
    assert dn.min() >= 0 and dn.max() <= p.max_dn and e.min() >= 0
