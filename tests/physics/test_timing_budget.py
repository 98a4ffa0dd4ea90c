"""Real-time budget and late masks (issue 18): the paper's App. D numbers, slack and late flags in
closed form, and a late mask's exposure against the closed-form PWM duty integral."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.camera.dmd import DMD, DMDSpec, Schedule, throughput_on
from poevp_optics.control.timing_budget import BudgetSpec, MaskClock, bus_seconds
from poevp_optics.core.timing import TimingSpec


def test_paper_appendix_d_numbers():
    """T_AHB = 1280 x 720 x 8 / (200 MHz x 32) = 1.152 ms; 2 T_AHB + 3.96 ms + 3.333 ms = 9.597 ms."""
    spec = BudgetSpec()
    assert bus_seconds(1280, 720, 8, spec) == pytest.approx(1.152e-3, rel=1e-12)
    timing = TimingSpec(fps=30.0, exposure_s=0.02, dmd_window_s=1 / 300)
    clock = MaskClock(spec, timing, (1280, 720), 8, (1280, 720), 8)
    s = clock.summary()
    assert s["budget_s"] == pytest.approx(2 * 1.152e-3 + 3.96e-3, rel=1e-12)
    assert 1 / s["paper_serial_fps"] == pytest.approx(9.597e-3, abs=1e-6)     # paper: 9.597 ms, 104 fps
    assert int(s["paper_serial_fps"]) == 104


def _clock(mode, compute="fpga_zynq", fps=30.0):
    timing = TimingSpec(fps=fps, frames=6, exposure_s=0.030, dmd_window_s=0.030)
    return MaskClock(BudgetSpec(compute=compute, late_mask=mode), timing, (368, 640), 8, (368, 640), 8), timing


@pytest.mark.parametrize("mode", ["partial", "next", "ideal"])
def test_slack_late_flag_and_what_is_shown(mode):
    clock, timing = _clock(mode)
    readout = 368 * 640 * 8 / (200e6 * 32)
    budget = 2 * readout + 3.96e-3
    white = np.full((2, 2), 255.0)
    clock.show(0, white, True, None)
    clock.show(1, white, True, None)
    new = np.full((2, 2), 7.0)
    shown = clock.show(2, new, False, None)
    rec = shown.record
    # exposure of frame 1 ends at 1/30 + 30 ms; frame 2's window starts at 2/30
    expect_slack = 2 / 30 - (1 / 30 + 0.030 + budget)
    assert rec["slack_s"] == pytest.approx(expect_slack, abs=1e-12)
    assert rec["late"] and expect_slack < 0                 # 4.55 ms of budget, 3.33 ms of gap
    if mode == "partial":
        np.testing.assert_array_equal(shown.levels, white)
        np.testing.assert_array_equal(shown.late, new)
        assert shown.switch_s == pytest.approx(2 / 30 - expect_slack, abs=1e-12)
    elif mode == "next":
        np.testing.assert_array_equal(shown.levels, white) and shown.late is None
        assert shown.late is None
    else:
        np.testing.assert_array_equal(shown.levels, new)
    nxt = clock.show(3, np.full((2, 2), 9.0), False, None)
    if mode == "next":                                     # mask 2 (ready in frame 2's window) now shown
        np.testing.assert_array_equal(nxt.levels, new)
    s = clock.summary()
    assert s["late_frames"] == [2, 3]
    assert s["on_time_fps"] == pytest.approx(1 / (0.030 + budget), rel=1e-12)


def test_on_time_at_lower_rate_and_rtx3090_late():
    clock, _ = _clock("partial", fps=25.0)                  # gap 10 ms > 4.55 ms
    w = np.full((2, 2), 255.0)
    clock.show(0, w, True, None)
    assert not clock.show(1, np.full((2, 2), 3.0), False, None).record["late"]
    clock, _ = _clock("partial", "rtx3090", fps=25.0)       # 16.9 ms + transfers > 10 ms
    clock.show(0, w, True, None)
    assert clock.show(1, np.full((2, 2), 3.0), False, None).record["late"]


def _closed_form_on_time(v_old, v_new, sched, switch_s):
    """Exposure-window on-time of a mirror (s): the white fill outside the window, plus each
    bit-plane's duration t_D 2^b / 255 where the bit of the mask latched at the plane's start
    (old before the switch, new after) is set; planes in LSB-first order."""
    e0, e1 = sched.exposure_start_s, sched.exposure_start_s + sched.exposure_s
    w0, w1 = sched.window_start_s, sched.window_start_s + sched.window_s
    on = (max(0.0, min(e1, w0) - e0) + max(0.0, e1 - max(e0, w1))) if sched.outside_on else 0.0
    t = w0
    for b in range(sched.bits):
        d = sched.window_s * (1 << b) / 255
        v = v_old if t < switch_s else v_new
        if (v >> b) & 1:
            on += max(0.0, min(t + d, e1) - max(t, e0))
        t += d
    return on


@pytest.mark.parametrize("switch_ms", [2.0, 6.5, 11.0, 20.0, 40.0])
def test_late_mask_exposure_is_the_duty_integral(switch_ms):
    dmd = DMDSpec(contrast_ratio=1000.0)
    sched = Schedule(0.0, 0.030, 0.002, 0.025, True, 8, False, 0.0)
    old = np.array([[181.0, 0.0, 255.0, 17.0]])
    new = np.array([[78.0, 255.0, 0.0, 200.0]])
    w, _ = DMD(dmd).late_exposure_weights(old, new, sched, 1, switch_ms * 1e-3)
    got = np.array(w[0])
    thr, cr = throughput_on(dmd), dmd.contrast_ratio
    expect = [thr * (_closed_form_on_time(int(a), int(b), sched, switch_ms * 1e-3) * (1 - 1 / cr) + 0.030 / cr)
              for a, b in zip(old.ravel(), new.ravel())]
    # float32 tables: relative rounding 6e-8 per entry
    np.testing.assert_allclose(got, expect, rtol=1e-6)
    # with radiance nodes the per-node weights still sum to the same total
    w3, _ = DMD(dmd).late_exposure_weights(old, new, sched, 5, switch_ms * 1e-3)
    np.testing.assert_allclose(sum(np.array(x, dtype=np.float64) for x in w3), expect, rtol=1e-6)


def _scene_error(*overrides):
    from poevp_optics.core.exceptions import SceneError
    from poevp_optics.scene.load import load_scene
    from tests.conftest import SCENES

    with pytest.raises(SceneError) as e:
        load_scene(SCENES / "smoke", list(overrides))
    return str(e.value)


def test_dlpc900_limits_are_one_line_errors_naming_the_keys():
    """Paper Fig. 7's 20 ms 8-bit window: shortest plane 20 ms / 255 = 78.4 us < 105 us."""
    msg = _scene_error('dmd.controller="dlpc900_dlp6500"', "dmd.bits=8", "timing.dmd_window_s=0.020")
    assert "timing.dmd_window_s" in msg and "78.4 us" in msg and "26.775 ms" in msg and "dmd.bits" in msg
    assert "\n" not in msg
    msg = _scene_error('dmd.controller="dlpc900_dlp6500"', "dmd.bits=16", "timing.dmd_window_s=0.030",
                       "timing.fps=0.1", "timing.exposure_s=0.03")
    assert "timing.dmd_window_s" in msg          # 16 bits: 0.46 us planes
    # 255 x 105 us = 26.775 ms: the shortest window an 8-bit camera mask can use on a DLPC900
    from poevp_optics.camera.dmd import DMDSpec, timing_problem
    ok = TimingSpec(fps=30.0, exposure_s=0.03, dmd_window_s=0.026775)
    assert timing_problem(DMDSpec(controller="dlpc900_dlp6500"), ok) is None
    short = TimingSpec(fps=30.0, exposure_s=0.03, dmd_window_s=0.0267)
    assert timing_problem(DMDSpec(controller="dlpc900_dlp6500"), short)[0] == "timing.dmd_window_s"
    assert timing_problem(DMDSpec(controller="ideal"), short) is None


def test_given_and_measured_compute_are_valid_choices():
    """`given` takes budget.compute_s and `measured` the run's time (the registry once dropped
    both: registering None returned a decorator instead of an entry)."""
    timing = TimingSpec(fps=30.0, exposure_s=0.028, dmd_window_s=0.028)
    given = MaskClock(BudgetSpec(compute="given", compute_s=0.012), timing, (368, 640), 8, (368, 640), 8)
    assert given.compute_seconds(0.5) == 0.012
    measured = MaskClock(BudgetSpec(compute="measured", compute_s=0.012), timing, (368, 640), 8, (368, 640), 8)
    assert measured.compute_seconds(0.048) == 0.048
