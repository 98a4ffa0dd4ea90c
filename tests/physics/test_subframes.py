"""Time quadrature of the encoded capture (issue 13, bug 2): every mask level converges at second
order on a smooth L(t), the DMD's switching times resolve the low-bit planes, and the run's
temporal-error estimate tracks the true error of the encoded plate."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.camera.dmd import (Schedule, interval_on_time_table, node_times_s, on_time_table,
                              switch_times_s)
from poevp_optics.camera.dmd import DMDSpec
from poevp_optics.core.timing import TimingSpec
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES

H, W = 12, 96
LEVELS = np.array([1, 14, 128, 255])
T = 0.03
SCHED = Schedule.for_frame(DMDSpec(), TimingSpec(fps=30.0, exposure_s=T, dmd_window_s=T), 0.0)


def _highlight(t_s):
    """Gaussian highlight crossing the frame at 1500 px/s (45 px per 30 ms exposure): smooth in t."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    return 1.0 + 300.0 * np.exp(-((x - 25 - 1500.0 * t_s) ** 2 + (y - H / 2) ** 2) / (2 * 4.0 ** 2))


def _plane(weights, times):
    return np.einsum("vk,khw->vhw", weights, np.stack([_highlight(t) for t in times]))


def _err(a, ref):
    return np.sqrt(np.mean((a - ref) ** 2, axis=(1, 2))) / np.mean(ref, axis=(1, 2))


def test_every_mask_level_converges_at_second_order_on_a_smooth_motion():
    """Hat weights (exact on-time against the piecewise-linear L) converge as h^2 once the node
    spacing h resolves the window in which a level is lit: levels 14, 128 and 255 fit slopes
    below -1.8 over 16 ... 128 intervals (-2 expected). Level 1 (one 118 us plane at the window's
    start) is inside one interval until h ~ 118 us: linear interpolation then errs by
    ~ tau h L'' / 4 (first order, but scaled by the plane's length tau), at least 20x below the
    old midpoint rule, whose error ~ h L' / 2 at equal K; joining the DMD's switching times
    (PWM nodes) resolves the plane at any K (error ~ tau^2 L'' / 8, here < 1e-3)."""
    ref = _plane(on_time_table(LEVELS, SCHED, 2049), node_times_s(0.0, T, 2049))
    n_int = np.array([16, 32, 64, 128])
    new = np.array([_err(_plane(on_time_table(LEVELS, SCHED, n + 1), node_times_s(0.0, T, n + 1)), ref)
                    for n in n_int])
    old = np.array([_err(_plane(interval_on_time_table(LEVELS, SCHED, n), (np.arange(n) + 0.5) * T / n), ref)
                    for n in n_int])
    pwm = np.array([_err(_plane(on_time_table(LEVELS, SCHED, nd), nd), ref)
                    for nd in (node_times_s(0.0, T, n + 1, switch_times_s(SCHED)) for n in n_int)])
    slope = lambda e: np.polyfit(np.log(n_int), np.log(e), 1)[0]          # noqa: E731
    for j, v in enumerate(LEVELS[1:], 1):
        assert slope(new[:, j]) < -1.8, (v, new[:, j])
    assert np.all(new[:, 0] < old[:, 0] / 20)
    assert np.all(pwm[:, 0] < 1e-3)


def test_hat_weights_conserve_each_levels_on_time():
    """sum_j W_j(v) is the level's exact total on-time, for uniform and PWM-joined nodes."""
    whole = on_time_table(np.arange(256), SCHED, 1)[:, 0]
    for nodes in (node_times_s(0.0, T, 7), node_times_s(0.0, T, 5, switch_times_s(SCHED))):
        w = on_time_table(np.arange(256), SCHED, nodes)
        assert np.all(w >= 0)
        np.testing.assert_allclose(w.sum(axis=1), whole, rtol=1e-12, atol=1e-18)


def test_pwm_nodes_resolve_the_low_bit_planes():
    """Level 14 is lit only by its bit-planes 1-3, within the window's first 1.8 ms: with K = 9
    uniform nodes (3.75 ms apart) the fast highlight is interpolated across that whole stretch;
    joining the DMD's switching times samples it at the planes' ends. Error at least 5x lower."""
    ref = _plane(on_time_table(LEVELS, SCHED, 2041), node_times_s(0.0, T, 2041))
    uni = node_times_s(0.0, T, 9)
    pwm = node_times_s(0.0, T, 9, switch_times_s(SCHED))
    assert len(pwm) == 9 + 7                      # 7 inner plane boundaries (B - 1)
    e_uni = _err(_plane(on_time_table(LEVELS, SCHED, uni), uni), ref)
    e_pwm = _err(_plane(on_time_table(LEVELS, SCHED, pwm), pwm), ref)
    assert e_pwm[1] < e_uni[1] / 5
    assert np.all(e_pwm <= e_uni * 1.01)           # extra nodes never make a level notably worse


@pytest.mark.slow
def test_temporal_error_estimate_tracks_the_true_error_of_the_encoded_plate():
    """apps.run.temporal_check.temporal_error (the frame's nodes vs nodes + midpoints, independent seeds at the
    scene's spp, the frame's oracle mask) within a factor 1.5 of the true error of the encoded
    plate: the rule on the same nodes against 161 samples rendered with one seed (common random
    numbers, so the difference is the quadrature's, not noise) on fast_pass, where the plate
    sweeps ~50 px across this small frame within the exposure."""
    from poevp_optics.camera.camera import Camera
    from poevp_optics.apps.run.temporal_check import temporal_error
    from poevp_optics.control.loop_step import oracle_mask
    from poevp_optics.render.exposures import render_exposures
    from poevp_optics.render.renderer import Renderer

    spec = load_scene(SCENES / "fast_pass", ["render.resolution=[92,160]", "render.spp=32",
                                             "render.subframes=5", "timing.frames=2"])
    cam = Camera.from_params(spec.resolved.camera)
    r = Renderer(spec.resolved.render, guard_px=cam.guard_px)
    ex = list(render_exposures(spec.resolved.render, r, progress=False))[1]
    mask = oracle_mask(cam, spec.mask, ex.radiance.data, 1)
    est = temporal_error(spec, r, cam, ex, mask)
    t0, t1 = spec.exposure_window_s(1)
    dense = node_times_s(t0, t1, 161)
    imgs = []
    for t in dense:
        r.set_time(float(t))
        imgs.append(r.render_once(777, 32).astype(np.float64))
    imgs = np.stack(imgs)

    def L(t):                    # linear interpolation between the dense samples
        j = min(int(np.searchsorted(dense, t, side="right")) - 1, len(dense) - 2)
        a = (t - dense[j]) / (dense[j + 1] - dense[j])
        return (1 - a) * imgs[j] + a * imgs[j + 1]

    lv = np.rint(mask).astype(int)
    uq, inv = np.unique(lv, return_inverse=True)
    sched = cam.schedule(1)

    def encoded(times):
        wt = on_time_table(uq, sched, times - t0)[inv.reshape(lv.shape)]
        return np.einsum("hwk,khw->hw", wt, np.stack([L(t) for t in times]))

    y0, x0, y1, x1 = ex.roi
    diff = (encoded(ex.subframe_times_s) - encoded(dense))[y0:y1, x0:x1]
    true = np.sqrt(np.mean(diff ** 2)) / np.mean(encoded(dense)[y0:y1, x0:x1])
    print("temporal error: estimate", est["rel"], "true", true)
    assert est["resolved"] and 1 / 1.5 < est["rel"] / true < 1.5, (est["rel"], true)
