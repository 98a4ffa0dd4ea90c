"""`mask.envelope = "region_body"`: each bright region's body at the fixed envelope, its brighter
parts at the envelope its own last miss asks for (control/envelope.py).

Closed forms computed here, not by the code under test:
- a region's miss is the one-sided Hausdorff distance from its captured mirrors to the mirrors
  the mask aimed at, by brute force over every pair of mirrors; its sigma half of it;
- a plate 40 x 16 mirrors whose left quarter is lit (2.3x its shaded rest, a lamp cut off it),
  measured at sigma 1: its median is the shaded level, so on the shaded mirrors more than
  2 x 3 = 6 mirrors from the lit part (the dilation's radius, then the blur's) the envelope is
  the shaded level itself, where the fixed envelope (sigma 4: 12, then 12) still holds more than
  1.5x the shaded level 12 mirrors into the shade; on the lit part it is the lit level;
- a lamp (core 100x its halo): no mirror of it within 3x of its core lies above the core's
  median, so it keeps the fixed envelope bit for bit; so does every region before any miss was
  measured, or one whose miss reaches smooth_px;
- the envelope is >= the demand on every mirror (random HDR frames);
- in the loop, `hold` on two discs, one standing and one moving v mirrors a frame: the standing
  disc is measured at the floor (radius 3), the moving one at sigma v / 2 (radius ceil(1.5 v))."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.camera.camera import Camera
from poevp_optics.camera.dmd import DMDSpec
from poevp_optics.camera.objective import ObjectiveSpec
from poevp_optics.camera.relay import RelaySpec
from poevp_optics.camera.sensor import SensorSpec
from poevp_optics.control.envelope import body_envelope, region_sigma, smooth_envelope
from poevp_optics.control.loop_step import LoopSpec, LoopStep
from poevp_optics.control.masks import MaskSpec
from poevp_optics.control.predictors import PredictorSpec
from poevp_optics.core.timing import TimingSpec

SMOOTH = 4.0
LIFT = np.float32(1 + 1e-6)      # smooth_envelope's lift above the frame


def _disc(shape, cy: float, cx: float, r: float) -> np.ndarray:
    y, x = np.mgrid[0:shape[0], 0:shape[1]]
    return (y - cy) ** 2 + (x - cx) ** 2 <= r * r


def _hausdorff(captured: np.ndarray, aimed: np.ndarray) -> float:
    """max over captured mirrors of the distance to the nearest aimed mirror (brute force)."""
    c = np.argwhere(captured).astype(float)
    a = np.argwhere(aimed).astype(float)
    return float(np.sqrt(((c[:, None, :] - a[None, :, :]) ** 2).sum(-1)).min(1).max())


def test_each_region_is_measured_by_its_own_miss():
    shape = (40, 90)
    aimed = _disc(shape, 20, 20, 6) | _disc(shape, 20, 60, 6)
    near = _disc(shape, 20, 24.5, 6)          # moved 4.5 mirrors
    far = _disc(shape, 22, 66, 6)              # moved 6.3 mirrors
    sigma = region_sigma(aimed, near | far, SMOOTH, 1.0)
    want_near, want_far = _hausdorff(near, aimed) / 2, _hausdorff(far, aimed) / 2
    assert 2.0 < want_near < want_far < SMOOTH
    assert np.allclose(sigma[near], want_near, atol=1e-3)
    assert np.allclose(sigma[far], want_far, atol=1e-3)
    assert np.isnan(sigma[~(near | far)]).all()
    shrunk = _disc(shape, 20, 20, 3)                                           # inside the aim: the floor
    assert np.all(region_sigma(aimed, shrunk, SMOOTH, 1.0)[shrunk] == 1.0)
    away = _disc(shape, 20, 40, 3)                                             # 14 mirrors off: 7, capped
    assert np.all(region_sigma(aimed, away, SMOOTH, 1.0)[away] == SMOOTH)
    assert np.all(region_sigma(np.zeros(shape, bool), shrunk, SMOOTH, 1.0)[shrunk] == SMOOTH)
    assert np.isnan(region_sigma(aimed, np.zeros(shape, bool), SMOOTH, 1.0)).all()


def _plate(lit: float, shade: float) -> np.ndarray:
    d = np.full((60, 100), 0.2)
    d[22:38, 30:70] = shade
    d[22:38, 30:40] = lit                     # the left quarter still lit
    return d


def test_a_half_shaded_plate_keeps_each_part_its_own_level():
    lit, shade = 230.0, 100.0
    d = _plate(lit, shade)
    bright = d >= 1.0
    env = body_envelope(d, bright, np.where(bright, 1.0, np.nan).astype(np.float32), SMOOTH)
    fixed = smooth_envelope(d, SMOOTH)
    cols = np.arange(100)
    far_shade = (cols >= 40 + 7) & (cols < 70)   # shaded mirrors more than 6 from the lit part
    assert np.allclose(env[22:38][:, far_shade], shade * LIFT, rtol=1e-6)
    assert np.allclose(env[22:38, 30:40], lit * LIFT, rtol=1e-6)
    assert np.all(fixed[22:38, 40:52] > 1.5 * shade)           # the fixed one: the lit level 12 mirrors into the shade
    assert np.all(env >= d.astype(np.float32))


def test_the_fixed_envelope_where_nothing_is_split():
    d = _plate(230.0, 100.0)
    bright = d >= 1.0
    fixed = smooth_envelope(d, SMOOTH)
    assert np.array_equal(body_envelope(d, bright, None, SMOOTH), fixed)                      # not measured
    assert np.array_equal(body_envelope(d, bright, np.full(d.shape, np.nan, np.float32), SMOOTH), fixed)
    assert np.array_equal(body_envelope(d, bright, np.full(d.shape, SMOOTH, np.float32), SMOOTH), fixed)
    lamp = np.full((60, 100), 0.2)
    lamp[20:40, 30:60] = 10.0                                   # the halo, 100x below the core
    lamp[27:33, 42:48] = 1000.0
    sig = np.where(lamp >= 1.0, 1.0, np.nan).astype(np.float32)
    assert np.array_equal(body_envelope(lamp, lamp >= 1.0, sig, SMOOTH), smooth_envelope(lamp, SMOOTH))


@pytest.mark.parametrize("seed", [1, 2])
def test_never_below_the_demand(seed):
    rng = np.random.default_rng(seed)
    d = rng.lognormal(0.0, 2.5, (90, 140))
    sig = np.where(rng.random(d.shape) < 0.5, rng.uniform(0.5, 5.0, d.shape), np.nan).astype(np.float32)
    env = body_envelope(d, d >= 30.0, sig, 3.0)
    assert np.all(env >= d.astype(np.float32))


SHAPE = (32, 96)


def _measured_radii(v: int, frames: int = 6) -> list:
    cam = Camera(SensorSpec(), DMDSpec(enabled=True, bits=8), RelaySpec(psf="delta"), ObjectiveSpec(), TimingSpec(),
                 SHAPE)
    spec = MaskSpec(law="exposure_controller", target=0.6, band_low=0.4, band_high=0.9, smooth_px=SMOOTH,
                    envelope="region_body")
    step = LoopStep(cam, spec, LoopSpec(init_frames=2), PredictorSpec(name="hold", resolution=SHAPE))
    radii = []
    for i in range(frames):
        unit = cam.params.saturation_capacity_e / (cam.electrons_per_radiance() * cam.white_exposure_s(i))
        lit = _disc(cam.mirror_shape, SHAPE[0] / 2, 20.0, 5.0) | _disc(cam.mirror_shape, SHAPE[0] / 2, 50.0 + v * i, 5.0)
        truth = np.where(lit, 30.0, 0.1).astype(np.float32) * unit
        dec = step.next_mask(i, truth)
        ldr = cam.capture([truth], cam.white_mask(), i, seed=100 + i)
        enc = cam.capture([truth], dec.levels, i, seed=i + 1, transmission=dec.transmission, exposure=dec.exposure)
        est, flags, _ = cam.reconstruct(enc, i)
        step.observe(i, ldr, enc, est, flags)
        s = step.controller.region_sigma
        radii.append(None if s is None else sorted({int(np.ceil(3 * x)) for x in np.unique(s[np.isfinite(s)])}))
    return radii


@pytest.mark.parametrize("v", [4, 6])
def test_hold_measures_the_standing_and_the_moving_highlight_apart(v):
    radii = _measured_radii(v)
    # from the first loop frame on (frames 0, 1: the white start), the standing disc at the
    # floor and the moving one at sigma v / 2
    assert all(r == [3, int(np.ceil(1.5 * v))] for r in radii[2:]), radii


def test_only_the_exposure_controller_takes_it():
    from poevp_optics.core.exceptions import SceneError
    from poevp_optics.scene.load import load_scene
    from tests.conftest import SCENES

    with pytest.raises(SceneError, match="mask.envelope"):
        load_scene(SCENES / "toll_or_junction", ['mask.envelope="region_body"', 'mask.law="target"'])
    assert load_scene(SCENES / "toll_or_junction", ['mask.envelope="region_body"']).mask.envelope == "region_body"
