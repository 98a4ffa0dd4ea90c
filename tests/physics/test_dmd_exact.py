"""DMD PWM exactness: the time integral of every grey level against its closed form."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.camera.dmd import DMD, Schedule, on_time_table, transmission_table
from poevp_optics.camera.dmd import DMDSpec
from poevp_optics.core.timing import TimingSpec
def _closed_form(v, bits, t_s, t_i, t_d0, t_d, outside_on, msb_first):
    """On-time inside [t_s, t_s + t_I]: each set bit b contributes the overlap of its plane
    [start_b, start_b + t_D 2^b / (2^B - 1)] with the exposure; plus the white time outside the
    window that overlaps the exposure."""
    n = (1 << bits) - 1
    order = range(bits - 1, -1, -1) if msb_first else range(bits)
    t = t_d0
    on = 0.0
    lo, hi = t_s, t_s + t_i
    for b in order:
        d = t_d * (1 << b) / n
        if (v >> b) & 1:
            on += max(0.0, min(hi, t + d) - max(lo, t))
        t += d
    if outside_on:
        inside = max(0.0, min(hi, t_d0 + t_d) - max(lo, t_d0))
        on += t_i - inside
    return on


@pytest.mark.parametrize("bits", [8, 4])
@pytest.mark.parametrize("order", ["lsb_first", "msb_first"])
@pytest.mark.parametrize("outside", ["white", "dark"])
@pytest.mark.parametrize("exp_off,win_off,t_i,t_d", [
    (0.0, 0.0, 0.03333, 0.020),          # the paper's timing: window at the exposure start
    (0.0, 0.005, 0.020, 0.020),          # window's last 5 ms miss the exposure
    (0.010, 0.0, 0.020, 0.015),          # window's first 10 ms precede the exposure
    (0.0, 0.0, 0.010, 0.030),            # exposure inside the window
])
def test_static_pwm_integral_is_exact(bits, order, outside, exp_off, win_off, t_i, t_d):
    timing = TimingSpec(fps=25.0, exposure_s=t_i, exposure_offset_s=exp_off, dmd_window_s=t_d,
                        dmd_window_offset_s=win_off, outside_window=outside)
    spec = DMDSpec(bits=bits, bit_order=order)
    sched = Schedule.for_frame(spec, timing, 0.0)
    levels = np.arange(1 << bits)
    table = on_time_table(levels, sched, 1)[:, 0]
    expected = np.array([_closed_form(v, bits, exp_off, t_i, win_off, t_d, outside == "white",
                                      order == "msb_first") for v in levels])
    np.testing.assert_allclose(table, expected, rtol=0, atol=1e-15)
    # the full-overlap case is duty x t_D + white fill, exactly
    if win_off >= exp_off and win_off + t_d <= exp_off + t_i:
        fill = (t_i - t_d) if outside == "white" else 0.0
        np.testing.assert_allclose(table, levels / levels[-1] * t_d + fill, rtol=0, atol=1e-15)
    # and the per-mirror DrJit weights (float32) match to float32 precision
    dmd = DMD(spec)
    mask = np.tile(levels, 3).reshape(3, -1)
    w, _ = dmd.exposure_weights(mask, sched, 1)
    thr = spec.fill_factor * spec.reflectance
    ref = thr * (expected + (t_i - expected) / spec.contrast_ratio)
    np.testing.assert_allclose(np.array(w[0]).reshape(3, -1)[0], ref, rtol=2e-7, atol=0)


def test_subintervals_sum_to_the_whole_exposure():
    timing = TimingSpec(fps=30.0, exposure_s=0.03333, dmd_window_s=0.02)
    sched = Schedule.for_frame(DMDSpec(settle_s=8e-6), timing, 1.0)
    levels = np.arange(256)
    whole = on_time_table(levels, sched, 1)[:, 0]
    for k in (2, 7, 64, 1000):
        np.testing.assert_allclose(on_time_table(levels, sched, k).sum(axis=1), whole, atol=1e-15)


def test_settling_conserves_on_time_of_long_pulses_and_eats_short_ones():
    """A linear ramp of length s at each switch delays an on-interval by s/2 at both ends: the
    on-time of an isolated pulse longer than s is unchanged; a pulse shorter than s loses
    the part of the ramp it cannot finish."""
    timing = TimingSpec(fps=30.0, exposure_s=0.03, dmd_window_s=0.02, dmd_window_offset_s=0.005,
                        outside_window="dark")
    base = on_time_table(np.arange(256), Schedule.for_frame(DMDSpec(), timing, 0.0), 1)[:, 0]
    settle = 1e-5                          # 10 us; LSB plane is 20 ms / 255 = 78 us
    slow = on_time_table(np.arange(256), Schedule.for_frame(DMDSpec(settle_s=settle), timing, 0.0), 1)[:, 0]
    # single-bit levels: one isolated pulse each, fully inside the exposure -> unchanged
    for b in range(8):
        assert slow[1 << b] == pytest.approx(base[1 << b], abs=1e-15)
    settle_long = 2e-4                     # longer than the LSB plane
    s2 = on_time_table(np.array([1]), Schedule.for_frame(DMDSpec(settle_s=settle_long), timing, 0.0), 1)[0, 0]
    d = 0.02 / 255
    # ramp up for d (reaching d / s), then ramp down from there: area = d^2 / (2 s) * 2
    assert s2 == pytest.approx(d * d / settle_long, rel=1e-9)


def test_transmission_includes_leakage_and_throughput():
    timing = TimingSpec(fps=30.0, exposure_s=0.03, dmd_window_s=0.03, outside_window="dark")
    spec = DMDSpec(contrast_ratio=500.0, fill_factor=0.9, reflectance=0.8)
    t = transmission_table(np.array([0, 255]), spec, Schedule.for_frame(spec, timing, 0.0), 1)[:, 0]
    assert t[1] == pytest.approx(0.72 * 0.03)
    assert t[0] == pytest.approx(0.72 * 0.03 / 500.0)
