"""`mask.envelope = "predictor_error"`: the mask envelope's radius follows the loop's own miss.

Closed form: a disc moving v mirrors per frame. `hold` predicts the last capture, so the disc
the camera captures reaches v mirrors beyond the one the mask was computed from (its centroid
moved v, its area did not change), and every loop frame gets an envelope of sigma v, radius
3 v >= v (below the cap 3 smooth_px): from the first one on, as the miss of a prediction made
during the white start is already measured. The oracle's mask is computed from the frame itself: it misses by
nothing, and its envelope sits at the floor, 3 mirrors (sigma 1)."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.camera.camera import Camera
from poevp_optics.camera.dmd import DMDSpec
from poevp_optics.camera.objective import ObjectiveSpec
from poevp_optics.camera.relay import RelaySpec
from poevp_optics.camera.sensor import SensorSpec
from poevp_optics.control.loop_step import LoopSpec, LoopStep
from poevp_optics.control.masks import MaskSpec, envelope_sigma, highlight_miss_px
from poevp_optics.control.predictors import PredictorSpec
from poevp_optics.core.timing import TimingSpec

SHAPE = (32, 72)
RADIUS = 5.0          # disc radius, mirrors
OVER = 30.0           # disc brightness, x saturation (background 0.1 x)


def _disc(cx: float, cy: float, shape) -> np.ndarray:
    y, x = np.mgrid[0:shape[0], 0:shape[1]]
    return (x - cx) ** 2 + (y - cy) ** 2 <= RADIUS ** 2


def _run(name: str, v: int, envelope: str, frames: int = 5) -> list[int]:
    cam = Camera(SensorSpec(), DMDSpec(enabled=True, bits=8), RelaySpec(psf="delta"), ObjectiveSpec(), TimingSpec(),
                 SHAPE)
    spec = MaskSpec(law="target", target=0.5, smooth_px=4.0, envelope=envelope)
    step = LoopStep(cam, spec, LoopSpec(init_frames=2), PredictorSpec(name=name, resolution=SHAPE))
    radii = []
    for i in range(frames):
        unit = cam.params.saturation_capacity_e / (cam.electrons_per_radiance() * cam.white_exposure_s(i))
        truth = np.where(_disc(12.0 + v * i, SHAPE[0] / 2, cam.mirror_shape), OVER, 0.1).astype(np.float32) * unit
        radii.append(step.envelope_px())                       # the radius this frame's mask is built with
        dec = step.next_mask(i, truth)
        ldr = cam.capture([truth], cam.white_mask(), i, seed=100 + i)     # the LDR twin: what hold sees
        enc = cam.capture([truth], dec.levels, i, seed=i + 1, transmission=dec.transmission, exposure=dec.exposure)
        est, flags, _ = cam.reconstruct(enc, i)
        step.observe(i, ldr, enc, est, flags)
    return radii


def test_miss_is_the_one_sided_hausdorff_distance():
    shape = (40, 60)
    a, b = _disc(20.0, 20.0, shape), _disc(27.0, 20.0, shape)
    assert highlight_miss_px(a, b) == pytest.approx(7.0, abs=1e-9)            # moved 7
    assert highlight_miss_px(b, a) == pytest.approx(7.0, abs=1e-9)
    big = _disc(20.0, 20.0, shape) | (np.hypot(*np.mgrid[0:40, 0:60] - np.array([20, 20])[:, None, None]) <= 9)
    grow = np.sqrt(big.sum() / np.pi) - np.sqrt(a.sum() / np.pi)               # same centre, grew
    assert highlight_miss_px(a, big) == pytest.approx(grow) and grow > 3.5
    assert highlight_miss_px(big, a) == 0.0                                    # shrank in place: no miss
    assert highlight_miss_px(a, np.zeros(shape, bool)) is None                 # no highlight
    assert highlight_miss_px(np.zeros(shape, bool), a) == pytest.approx(np.hypot(*shape))
    s = MaskSpec(smooth_px=4.0, envelope="predictor_error")
    assert [envelope_sigma(s, m) for m in (None, 0.0, 2.5, 50.0)] == [4.0, 1.0, 2.5, 4.0]
    assert envelope_sigma(MaskSpec(smooth_px=4.0), 0.0) == 4.0                 # fixed
    assert envelope_sigma(MaskSpec(smooth_px=0.5, envelope="predictor_error"), 0.0) == 0.5


@pytest.mark.parametrize("v", [2, 3])
def test_hold_gets_at_least_its_lag_and_the_oracle_the_floor(v):
    hold = _run("hold", v, "predictor_error")
    # frames 0, 1: the white start (hold predicts frame 1 from frame 0: its miss is measured),
    # so the first loop frame, 2, and every later one get 3 v >= v
    assert hold[2:] == [3 * v] * 3, hold
    assert _run("oracle", v, "predictor_error")[2:] == [3] * 3
    assert set(_run("hold", v, "fixed", frames=3)) == {12}


def test_evaluate_sets_scene_keys_after_the_protocols_own():
    from poevp_optics.apps.evaluate.eval_paper import paper_overrides
    from poevp_optics.apps.evaluate.evaluate_cli import _eval_config
    from poevp_optics.cli import build_parser
    from poevp_optics.scene.load import load_scene
    from tests.conftest import SCENES

    args = build_parser().parse_args(["evaluate", "scenes/ldr_highlight_demo", "--set", 'mask.envelope="predictor_error"',
                                      "--set", "mask.exposure_time_auto=true"])
    cfg = _eval_config(args)
    assert cfg.overrides == ('mask.envelope="predictor_error"', "mask.exposure_time_auto=true")
    spec = load_scene(SCENES / "ldr_highlight_demo", [*paper_overrides(9.0, "exposure_controller"), *cfg.overrides])
    assert spec.mask.envelope == "predictor_error" and spec.mask.exposure_time_auto
    assert _eval_config(build_parser().parse_args(["evaluate"])).overrides == ()
