"""Global variable attenuator before the DMD (issue 18, 10x beams): its choice against closed
forms, its timing, its exactness in the camera, and a closed loop that brings a highlight
beyond the 8-bit DMD's reach into the target band."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.camera.attenuator import AttenuatorSpec, AttenuatorState, choose_transmission
from poevp_optics.camera.camera import Camera
from poevp_optics.camera.sensor import NoiseSwitches
from poevp_optics.control.exposure_control import ExposureController
from poevp_optics.control.masks import MaskSpec, mask_levels, reach_electrons
from poevp_optics.core.exceptions import SceneError
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES
from tests.unit.test_exposure_controller import SAT_E, SENSOR, H, W, level_table, scene

ND = AttenuatorSpec(kind="variable_nd", serve_min_mirrors=32)


def test_transmission_is_the_reach_over_the_brightest_large_highlight():
    """g = D_reach / (highest D in a highlight of >= N mirrors): two 5x5 lamps at 1000x the
    reach (25 < N = 32 mirrors each, apart) do not set it, a 4x10 plate (40 mirrors) whose
    brightest mirror is 4x the reach does; clamped at min_transmission; 1 when nothing large is
    beyond reach; NaN demand counts as brightest."""
    d = np.full((40, 60), 0.5)
    d[2:7, 2:7] = d[2:7, 50:55] = 1000.0
    d[20:24, 20:30] = 3.0
    d[21, 25] = 4.0
    assert choose_transmission(d * 7.0, 7.0, ND) == pytest.approx(0.25, rel=1e-12)
    assert choose_transmission(d * 7.0, 7.0, AttenuatorSpec()) == 1.0          # kind none
    d[20:24, 20:30] = 1e6
    assert choose_transmission(d, 1.0, ND) == ND.min_transmission
    d[20:24, 20:30] = 0.9
    assert choose_transmission(d, 1.0, ND) == 1.0                               # lamps alone
    d[20:24, 20:30] = np.nan
    assert choose_transmission(d, 1.0, ND) == ND.min_transmission


def test_late_command_keeps_the_previous_setting():
    st = AttenuatorState(AttenuatorSpec(kind="variable_nd", settle_s=0.02))
    assert st.apply(0.5, 0.000, 0.020)["transmission"] == 0.5          # settles exactly at the start
    rec = st.apply(0.1, 0.050, 0.060)                                   # settles at 70 ms > 60 ms
    assert rec["late"] and rec["transmission"] == 0.5 and rec["commanded"] == 0.1
    assert st.apply(0.1, None, 0.1)["transmission"] == 0.1             # preset (no command time)


def test_capture_through_the_attenuator_is_the_capture_of_dimmed_radiance():
    """The camera with transmission g exposes exactly what it exposes for radiance x g, and the
    reconstruction divides g out (its exposure carries g)."""
    spec = load_scene(SCENES / "smoke", [f"render.resolution=[{H},{W}]"])
    cam = Camera.from_params(spec.resolved.camera, NoiseSwitches(False, False, True, False, False, False))
    fw_rad = cam.params.full_well_e / (cam.electrons_per_radiance() * cam.white_exposure_s(0))
    rad = (np.logspace(-1, 1.3, H * W).reshape(H, W) * fw_rad).astype(np.float32)   # 0.1-20x full well
    mask = np.where(np.arange(W)[None, :] < W // 2, cam.top_level, 100.0) * np.ones((H, 1))
    g = 0.0371
    a = cam.capture([rad], mask, 0, seed=1, transmission=g)
    b = cam.capture([rad * np.float32(g)], mask, 0, seed=1)
    np.testing.assert_allclose(a.signal_e, b.signal_e, rtol=2e-6)
    np.testing.assert_allclose(a.exposure_s, np.asarray(b.exposure_s) * g, rtol=2e-6)
    est_a, flags_a, _ = cam.reconstruct(a, 0)
    est_b, _, _ = cam.reconstruct(b, 0)
    ok = flags_a == 0
    assert ok.mean() > 0.3
    np.testing.assert_allclose(est_a[ok], est_b[ok] / g, rtol=1e-5)
    with pytest.raises(ValueError, match="transmission"):
        cam.capture([rad], mask, 0, seed=1, transmission=0.0)


def _loop(over, attenuator, frames=10, init=2):
    """tests/unit/test_exposure_controller's ideal loop (exact next LDR frame, noise-free
    sensor), 8-bit DMD at 1000:1 with min_level 1, plus the attenuator's transmission."""
    spec = MaskSpec(law="exposure_controller", target=0.6, band_low=0.4, band_high=0.9, smooth_px=2.0, min_level=1)
    table = level_table(1000.0)
    rel = table / table[-1]
    ctl = ExposureController(spec.first_guess, spec.clip_step, int(np.ceil(3 * spec.smooth_px)), SAT_E)
    mask, g = np.full((H, W), 255.0), 1.0
    whites, gs = [], []
    for t in range(frames):
        truth, inside = scene(t, over)
        if t >= init:
            pred8 = np.clip(truth / SAT_E * 255, 0, 255)
            pred_e = np.where(pred8 >= 254.5, spec.clipped_gain * SAT_E, pred8 / 255 * SAT_E)
            g = choose_transmission(ctl.demand_e, reach_electrons(spec, 255, table, SENSOR), attenuator)
            mask = mask_levels(spec, 8, pred_8bit=pred8, pred_electrons=pred_e, full_well_e=SAT_E,
                               level_exposure=table, sensor=SENSOR, controller=ctl, transmission=g)
        r = rel[mask.astype(int)] * g
        e = np.minimum(truth * r, SAT_E)
        ctl.observe(e / r, truth * r >= SAT_E, r)
        core = inside & (np.hypot(*np.gradient(inside.astype(float))) == 0)
        whites.append(float(np.median(e[core] / SAT_E)))
        gs.append(g)
    return whites, gs, rel


@pytest.mark.parametrize("over", [300.0, 640.0, 5000.0])
def test_attenuator_brings_a_highlight_beyond_the_dmd_into_band(over):
    """Beyond the DMD's reach (0.6 / rel(1) = 122x here) the mask alone leaves the highlight
    clipped at its darkest level; with the attenuator the loop settles at g = reach / X and the
    darkest level, i.e. white = target exactly (noise-free), once the bracket after the clipped
    first guesses has found it (2 clipped loop frames at 300-640x, 4 at 5000x)."""
    whites0, _, rel = _loop(over, AttenuatorSpec())
    assert over * rel[1] > 1.0 and whites0[-1] == pytest.approx(1.0)         # clipped without
    whites, gs, _ = _loop(over, ND)
    reach = 0.6 / rel[1]
    np.testing.assert_allclose(gs[-1], reach / over, rtol=1e-5)
    np.testing.assert_allclose(whites[-3:], 0.6, rtol=1e-4)
    assert sum(w >= 1.0 for w in whites[2:]) <= (2 if over < 1000 else 4)


def test_attenuator_stays_clear_within_the_dmd_reach():
    whites, gs, _ = _loop(40.0, ND)
    assert gs == [1.0] * len(gs)
    assert 0.4 <= whites[-1] <= 0.9


@pytest.mark.parametrize("override, key", [
    (['attenuator.kind="variable_nd"', 'mask.law="threshold_exp"'], "attenuator.kind"),
    (['attenuator.kind="variable_nd"', 'mask.law="exposure_controller"', "attenuator.settle_s=0.5"],
     "attenuator.settle_s"),
    (['attenuator.kind="grey_glass"'], "attenuator.kind"),
])
def test_bad_attenuator_settings_name_the_key(override, key):
    with pytest.raises(SceneError, match=key.replace(".", r"\.")):
        load_scene(SCENES / "highbeam_plate", override)
