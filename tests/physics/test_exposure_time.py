"""The exposure controller's exposure time T_e and DMD bit depth B per frame (control/exposure_time.py):
a plate 1e4x over saturation reaches the band on the third loop frame, the PWM integral over a
shortened exposure is the closed form q / (2^B - 1), B is the largest that fits the controller's
shortest plane, and an impossible fixed T_e is one line."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from poevp_optics.camera.dmd import DMDSpec, displayed_levels, frame_schedule, throughput_on, transmission_table
from poevp_optics.control import exposure_time as et
from poevp_optics.core.timing import TimingSpec, node_times_s
from tests.conftest import SCENES

T = 0.030                    # 30 ms exposure at 30 fps, the DMD window equal to it
TIMING = TimingSpec(fps=30.0, exposure_s=T, dmd_window_s=T)
PLANE_S = 105e-6             # DLPC900 shortest bit-plane (camera/dmd.py DMD_CONTROLLERS)


def _camera(controller="ideal"):
    from poevp_optics.camera.camera import Camera
    from poevp_optics.camera.objective import ObjectiveSpec
    from poevp_optics.camera.relay import RelaySpec
    from poevp_optics.camera.sensor import NoiseSwitches, SensorSpec

    return Camera(SensorSpec(bits=12), DMDSpec(controller=controller), RelaySpec(psf="delta"), ObjectiveSpec(),
                  TIMING, (20, 32), switches=NoiseSwitches.off())


@pytest.mark.parametrize("mode", ["open", "demodulated"])
def test_a_plate_1e4x_over_saturation_is_in_the_band_on_the_third_loop_frame(mode):
    """Two white frames, then the loop (hold predictor): the first loop frame assumes the
    controller's bracket after the white frames' clip, the second is unclipped, the third exact.
    The band is read off the capture's DN (fraction of the top code), independently of the law."""
    from poevp_optics.control.loop_step import LoopSpec, LoopStep
    from poevp_optics.control.masks import MaskSpec
    from poevp_optics.control.predictors import PredictorSpec

    cam = _camera()
    mask = MaskSpec(law="exposure_controller", exposure_time_auto=True, target=0.6, band_low=0.4, band_high=0.9, smooth_px=1.0)
    step = LoopStep(cam, mask, LoopSpec(mode=mode, init_frames=2), PredictorSpec(name="hold"))
    per_sat = cam.electrons_per_radiance() * cam.white_exposure_s(0) / cam.params.saturation_capacity_e
    g = cam.guard_px
    rad = np.full(cam.mirror_shape, 0.05 / per_sat, np.float32)       # background 0.05x saturation
    rad[g + 6:g + 14, g + 8:g + 24] = 1e4 / per_sat                    # the plate: 1e4x
    plate = np.s_[6:14, 8:24]
    fractions, choices = [], []
    for i in range(5):
        cmd = step.command(i, rad)
        ldr = cam.capture([rad], cam.white_mask(), i, seed=1)
        enc = cam.capture_command([rad], cmd, i, seed=2)
        est, flags, _ = cam.reconstruct(enc, i)
        step.observe(i, ldr, enc, est, flags)
        fractions.append(float(np.median(enc.dn[plate])) / cam.params.max_dn)
        choices.append(cmd.exposure)
    assert fractions[1] == 1.0                                        # white frames clip
    assert mask.band_low <= fractions[4] <= mask.band_high, fractions
    fx = choices[4]
    # at 1e4x the plate needs 0.6 / 1e4 of the white 30 ms: T_e x (fine level 20/255) ~ 30 ms x 6e-5
    want = 0.6 / 1e4 * T / (20 / 255)
    assert not fx.nominal and abs(fx.exposure_s / want - 1) < 0.1, (fx, want)
    assert et.SENSOR_MIN_EXPOSURE_S <= fx.exposure_s <= T and fx.window_s == fx.exposure_s


@pytest.mark.parametrize("bits", [1, 3, 6, 8])
def test_pwm_integral_over_a_shortened_exposure_is_the_closed_form(bits):
    """Mask levels v (8-bit) shown with B planes in a window equal to the shortened exposure: a
    mirror shows q = v >> (8 - B) and passes exactly q / (2^B - 1) of the exposure, plus the
    off-state leakage (1 - q / (2^B - 1)) / CR, through the scene's radiance nodes (which reach
    beyond the shortened exposure on both sides) as through one node."""
    dmd = DMDSpec(contrast_ratio=1000.0)
    te = 1.7e-3
    fx = et.FrameExposure(te, bits, te, False)
    sched = frame_schedule(dmd, TIMING, 0.0, fx)
    assert abs(sched.exposure_start_s - (T - te) / 2) < 1e-15 and sched.window_start_s == sched.exposure_start_s
    v = np.arange(256)
    q = v >> (8 - bits)
    top = (1 << bits) - 1
    closed = throughput_on(dmd) * te * (q / top + (1 - q / top) / dmd.contrast_ratio)
    shown = displayed_levels(v, 8, bits)
    one = transmission_table(shown, dmd, sched, 1)[:, 0]
    nodes = node_times_s(0.0, T, 7) - sched.exposure_start_s          # the scene's nodes, around it
    many = transmission_table(shown, dmd, sched, nodes)
    assert np.max(np.abs(one / closed - 1)) < 1e-7
    assert np.max(np.abs(many.sum(1) / closed - 1)) < 1e-7
    # a radiance linear in time, L(t) = a + b t, is integrated exactly over the exposure alone
    a, b = 2.0, 300.0
    lin = (a + b * (nodes + sched.exposure_start_s))
    e0, e1 = sched.exposure_start_s, sched.exposure_start_s + te
    exact_white = throughput_on(dmd) * (a * te + b * (e1 ** 2 - e0 ** 2) / 2)
    assert abs(many[-1] @ lin / exact_white - 1) < 1e-7


def test_chosen_bits_are_the_largest_whose_planes_fit_the_exposure():
    """(2^B - 1) x 105 us <= T_e < (2^(B+1) - 1) x 105 us (B < 8); a binary mask (B = 1) below
    the shortest 2-bit window, its pattern shown for at least one plane; T_e >= 26.775 ms: 8 bits."""
    cam = SimpleNamespace(timing=TIMING, dmd_spec=DMDSpec(controller="dlpc900_dlp6500"))
    for te in np.geomspace(et.SENSOR_MIN_EXPOSURE_S, T, 60):
        fx = et.at_exposure(cam, float(te))
        b = fx.bits
        if fx.nominal:
            assert b == 8 and te >= T * (1 - 1e-12)
            continue
        plane = fx.window_s / ((1 << b) - 1)
        assert plane >= PLANE_S * (1 - 1e-12), (te, b)
        if b > 1:
            assert ((1 << b) - 1) * PLANE_S <= te * (1 + 1e-12) and fx.window_s == te
        else:
            assert fx.window_s == max(te, PLANE_S)
        if b < 8:
            assert ((1 << (b + 1)) - 1) * PLANE_S > te, (te, b)
    assert et.at_exposure(cam, 0.0268).bits == 8 and et.at_exposure(cam, 0.0267).bits == 7


def test_the_controller_keeps_the_reference_demand_at_its_fine_level_or_the_full_depth_window():
    """The brightest served highlight sits at the fine level (20 of 255) at the aim:
    D T_e / T x rel(20) = aim, with an ideal controller down to the sensor's minimum; on the
    DLPC900 T_e stops at the 8-bit window 255 x 105 us = 26.775 ms (shorter would only drop bits:
    its smallest step passes 105 us of light whatever T_e). A highlight the fine level serves at
    30 ms (up to 7.6x) and a lamp core smaller than serve_min_mirrors (24) keep the scene's
    exposure."""
    from poevp_optics.control.exposure_control import full_scale_electrons
    from poevp_optics.control.masks import MaskSpec

    mask = MaskSpec(law="exposure_controller", exposure_time_auto=True, target=0.6, band_low=0.4, band_high=0.9)
    for controller, floor in (("ideal", et.SENSOR_MIN_EXPOSURE_S), ("dlpc900_dlp6500", 255 * PLANE_S)):
        cam = _camera(controller)
        assert abs(et.shortest_exposure_s(cam.dmd_spec) / floor - 1) < 1e-12
        sat = cam.params.saturation_capacity_e
        aim = float(full_scale_electrons(cam.params, mask.target))
        demand = np.full((16, 16), 0.1 * sat)
        assert et.choose(cam, mask, demand, 0).nominal
        demand[2:12, 2:12] = 5.0 * sat                                  # at 30 ms already at level >= 20
        assert et.choose(cam, mask, demand, 0).nominal
        lamp = demand.copy()
        lamp[13:15, 13:16] = 1e5 * sat                                  # a 6-mirror lamp core
        assert et.choose(cam, mask, lamp, 0).nominal
        for over in (8.0, 30.0, 300.0, 1000.0, 1e4, 1e5):
            d = lamp.copy()
            d[2:12, 2:12] = over * sat                                  # a 100-mirror plate
            fx = et.choose(cam, mask, d, 0)
            assert fx.bits == 8 and fx.window_s == fx.exposure_s and floor * (1 - 1e-12) <= fx.exposure_s < T
            got = over * sat * fx.exposure_s / T * (20 / 255 + (235 / 255) / 1000.0)
            assert abs(got / aim - 1) < 1e-6 or abs(fx.exposure_s / floor - 1) < 1e-12, (controller, over, fx)


@pytest.mark.parametrize("value, says", [
    ("0.5", "longer than the scene's exposure timing.exposure_s"),
    ("1e-6", "shorter than the sensor's minimum exposure"),
    ("-0.001", "negative times are not allowed"),
])
def test_an_impossible_fixed_exposure_time_is_one_line(capsys, value, says):
    from poevp_optics.cli import main

    rc = main(["validate", str(SCENES / "smoke"), "--set", 'mask.law="exposure_controller"',
               "--set", f"mask.exposure_time_s={value}"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert "mask.exposure_time_s" in err and says in err, err


def test_the_timing_budget_follows_each_frames_shortened_exposure_and_window():
    """A frame shortened to 1 ms: its DMD window is that millisecond centred on the scene's 30 ms
    exposure, and the next mask's budget runs from its end (not from the scene's exposure end)."""
    from poevp_optics.control.timing_budget import BudgetSpec, MaskClock

    clock = MaskClock(BudgetSpec(compute="given", compute_s=1e-3), TIMING, (8, 8), 12, (8, 8), 8)
    levels = np.full((8, 8), 255.0)
    clock.show(0, levels, True, None)
    fx = et.FrameExposure(1e-3, 4, 1e-3, False)
    mid1 = 1 / 30 + T / 2
    r1 = clock.show(1, levels, False, None, fx).record
    assert abs(r1["window_start_s"] - (mid1 - 0.5e-3)) < 1e-12 and abs(r1["window_s"] - 1e-3) < 1e-12
    assert abs(r1["exposure_end_s"] - T) < 1e-12                      # frame 0 kept the scene's exposure
    r2 = clock.show(2, levels, False, None).record
    assert abs(r2["exposure_end_s"] - (mid1 + 0.5e-3)) < 1e-12
    assert abs(r2["window_start_s"] - 2 / 30) < 1e-12 and "window_s" not in r2


def test_with_a_variable_nd_the_exposure_time_serves_only_what_the_nd_leaves_beyond_reach():
    """A plate 300x over saturation that the ND dims to the mask's reach keeps the scene's
    exposure; at the ND's darkest setting (1/128) a plate 1e5x over is still beyond reach and T_e
    takes the rest (the plate at the fine level at the aim)."""
    from poevp_optics.control.exposure_control import full_scale_electrons
    from poevp_optics.control.masks import MaskSpec, reach_electrons

    cam = _camera()
    mask = MaskSpec(law="exposure_controller", exposure_time_auto=True, target=0.6, band_low=0.4, band_high=0.9)
    sat = cam.params.saturation_capacity_e
    table = cam.level_exposure_s(0)
    reach = reach_electrons(mask, 255, table, cam.params)
    demand = np.full((16, 16), 0.1 * sat)
    demand[2:12, 2:12] = 300.0 * sat
    assert et.choose(cam, mask, demand, 0, nd=reach / (300.0 * sat), with_nd=True).nominal
    assert not et.choose(cam, mask, demand, 0, nd=1.0, with_nd=False).nominal
    demand[2:12, 2:12] = 1e5 * sat
    fx = et.choose(cam, mask, demand, 0, nd=1 / 128, with_nd=True)
    aim = float(full_scale_electrons(cam.params, mask.target))
    got = 1e5 * sat / 128 * fx.exposure_s / T * (20 / 255 + (235 / 255) / 1000.0)
    assert not fx.nominal and fx.nd_transmission == 1 / 128 and abs(got / aim - 1) < 1e-6
