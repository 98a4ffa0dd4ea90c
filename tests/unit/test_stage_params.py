"""Stages built from their params alone, no scene file (issue 30): the camera from its stages'
specs, the loop from its mask, loop and predictor specs; the loop's DMD command drives the
camera. The physics asserted: a mirror at level L exposes its pixel for the PWM share of L
(binary-weighted bit-planes: electrons at level L over electrons at the top level = L / top,
within the off-state leakage), and the oracle dims a spot brighter than saturation only there."""

from __future__ import annotations

import numpy as np

from poevp_optics.camera.camera import Camera
from poevp_optics.camera.dmd import DMDSpec
from poevp_optics.camera.objective import ObjectiveSpec
from poevp_optics.camera.relay import RelaySpec
from poevp_optics.camera.sensor import SensorSpec
from poevp_optics.control.loop_step import DMDCommand, LoopSpec, LoopStep
from poevp_optics.control.masks import MaskSpec
from poevp_optics.control.predictors import PredictorSpec
from poevp_optics.core.timing import TimingSpec

SHAPE = (12, 16)


def _camera() -> Camera:
    return Camera(SensorSpec(), DMDSpec(enabled=True, bits=8), RelaySpec(), ObjectiveSpec(), TimingSpec(), SHAPE)


def test_camera_from_params_exposes_by_the_pwm_share():
    cam = _camera()
    assert cam.mirror_shape[0] >= SHAPE[0] and cam.shape == SHAPE
    top = cam.top_level
    half = top // 2
    levels = np.full(cam.mirror_shape, float(top))
    levels[:, : cam.mirror_shape[1] // 2] = half
    exp = np.asarray(cam.capture([np.ones(cam.mirror_shape, np.float32)], levels, 0, seed=1).exposure_s)
    left, right = exp[:, :2].mean(), exp[:, -2:].mean()
    leak = 1.0 / cam.dmd.spec.contrast_ratio
    want = half / top * (1 - leak) + leak
    assert abs(left / right - want) < 2 * leak


def test_loop_from_params_commands_white_then_dims_the_highlight_only():
    cam = _camera()
    step = LoopStep(cam, MaskSpec(law="target", target=0.5, smooth_px=0.0), LoopSpec(), PredictorSpec(name="oracle"))
    truth = np.full(cam.mirror_shape, 1.0, np.float32)
    white_e = cam.electrons_per_radiance() * cam.white_exposure_s(2)
    truth *= 0.05 * cam.params.saturation_capacity_e / white_e            # background at 5 % of saturation
    cy, cx = cam.mirror_shape[0] // 2, cam.mirror_shape[1] // 2
    truth[cy - 1:cy + 2, cx - 1:cx + 2] *= 400.0                            # a spot 20x over saturation
    first = step.command(0, truth)
    assert isinstance(first, DMDCommand) and first.record.get("init") and np.all(first.levels.array == cam.top_level)
    cmd = step.command(2, truth)
    assert not cmd.record.get("init") and cmd.switch is None
    assert cmd.levels.grid == cam.mirror_grid
    assert cmd.levels.array[cy, cx] < cam.top_level / 20                     # <= target / 20x of white
    far = cmd.levels.array.copy()
    far[cy - 2:cy + 3, cx - 2:cx + 3] = cam.top_level
    assert np.all(far == cam.top_level)


def test_the_command_drives_the_capture_and_unclips_the_spot():
    """The loop's command into `Camera.capture_command`: the spot 20x over saturation clips
    behind white mirrors and does not behind the commanded ones (noise off: the sensor's full
    well is the clip); the background, left at white, gets the same exposure either way."""
    from poevp_optics.camera.sensor import NoiseSwitches

    cam = Camera(SensorSpec(), DMDSpec(enabled=True, bits=8), RelaySpec(), ObjectiveSpec(), TimingSpec(), SHAPE,
                 switches=NoiseSwitches.off())
    step = LoopStep(cam, MaskSpec(law="target", target=0.5, smooth_px=0.0), LoopSpec(), PredictorSpec(name="oracle"))
    truth = np.full(cam.mirror_shape, 1.0, np.float32)
    white_e = cam.electrons_per_radiance() * cam.white_exposure_s(2)
    truth *= 0.05 * cam.params.saturation_capacity_e / white_e
    cy, cx = cam.mirror_shape[0] // 2, cam.mirror_shape[1] // 2
    truth[cy - 1:cy + 2, cx - 1:cx + 2] *= 400.0
    cmd = step.command(2, truth)
    enc = cam.capture_command([truth], cmd, 2, seed=3)
    ldr = cam.capture([truth], cam.white_mask(), 2, seed=3)
    sy, sx = cy - cam.guard_px, cx - cam.guard_px                         # the spot on the sensor grid
    top = cam.params.max_dn
    assert ldr.dn[sy, sx] >= top and enc.dn[sy, sx] < top
    np.testing.assert_array_equal(np.asarray(enc.exposure_s)[0, 0], np.asarray(ldr.exposure_s)[0, 0])
