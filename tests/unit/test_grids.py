"""Arrays that cross the loop carry their grid (issue 30; core/grids.py): predictor, sensor,
mirror. Asserted: an array on the wrong grid is refused with both grids named, also when the
shapes are equal; the identity registration's round trip mirror -> sensor -> mirror is exact
(the guard band is the sensor picture's edge, replicated); the oracle loop's DMD command is on
the mirror grid; a registration of scale 2 maps shapes, coordinates and flux as its closed form
(camera/registration.py: s = scale (m - c_m) + c_s; sum_sensor = scale^2 sum_mirror) says."""

from __future__ import annotations

import math

import numpy as np
import pytest

from poevp_optics.camera.camera import Camera
from poevp_optics.camera.dmd import DMDSpec
from poevp_optics.camera.objective import ObjectiveSpec
from poevp_optics.camera.registration import RegistrationSpec
from poevp_optics.camera.relay import RelaySpec
from poevp_optics.camera.sensor import SensorSpec
from poevp_optics.control.loop_step import DMDCommand, LoopSpec, LoopStep, MaskDecision, resize_onto
from poevp_optics.control.masks import MaskSpec
from poevp_optics.control.predictors import PredictorSpec
from poevp_optics.core.grids import Grid, GridError, OnGrid
from poevp_optics.core.timing import TimingSpec

SHAPE = (12, 16)


def _camera(scale: float = 1.0, psf: str = "delta") -> Camera:
    return Camera(SensorSpec(), DMDSpec(enabled=True, bits=8, registration=RegistrationSpec(scale=scale)),
                  RelaySpec(psf=psf, sigma_px=1.0), ObjectiveSpec(), TimingSpec(), SHAPE)


def test_wrong_grid_is_refused_naming_both_grids():
    cam = _camera(psf="gaussian")                       # guard band: mirror grid larger than the sensor's
    assert cam.mirror_shape != cam.shape
    on_sensor = OnGrid(np.full(cam.shape, float(cam.top_level)), cam.sensor_grid)
    rad = [np.ones(cam.mirror_shape, np.float32)]
    with pytest.raises(GridError, match=r"sensor grid \(12x16.*mirror grid \(20x24"):
        cam.capture(rad, on_sensor, 0, seed=1)
    with pytest.raises(GridError, match="sensor grid.*mirror grid"):
        cam.to_sensor(on_sensor)                        # to_sensor needs the mirror grid
    with pytest.raises(GridError, match="mirror grid.*sensor grid"):
        cam.to_mirror(OnGrid(np.zeros(cam.mirror_shape), cam.mirror_grid))
    with pytest.raises(GridError, match="mirror grid.*predictor grid"):
        resize_onto(OnGrid(np.zeros(cam.mirror_shape), cam.mirror_grid), Grid("predictor", (6, 8)))
    with pytest.raises(GridError, match="sensor grid.*mirror grid"):   # skipping the registration
        resize_onto(on_sensor, cam.mirror_grid)
    with pytest.raises(GridError, match="DMDCommand.levels is on the sensor grid"):
        DMDCommand(on_sensor, None, None, 1.0, {}, MaskDecision(on_sensor.array, True, None))
    with pytest.raises(GridError, match=r"shape \(12, 15\) is not on the sensor grid"):
        OnGrid(np.zeros((12, 15)), cam.sensor_grid)


def test_equal_shapes_are_still_refused_when_the_tag_differs():
    cam = _camera()                                     # delta PSF: no guard band
    assert cam.mirror_shape == cam.shape and cam.sensor_grid != cam.mirror_grid
    levels = OnGrid(np.full(cam.shape, float(cam.top_level)), cam.sensor_grid)
    with pytest.raises(GridError, match="sensor grid.*mirror grid"):
        cam.capture([np.ones(cam.mirror_shape, np.float32)], levels, 0, seed=1)
    with pytest.raises(GridError, match="late mask levels is on the sensor grid"):
        cam.capture([np.ones(cam.mirror_shape, np.float32)], levels.array, 0, seed=1, switch=(levels, 1e-3))
    # the same array tagged with the mirror grid is taken, and exposes as the plain array does
    a = cam.capture([np.ones(cam.mirror_shape, np.float32)], OnGrid(levels.array, cam.mirror_grid), 0, seed=1)
    b = cam.capture([np.ones(cam.mirror_shape, np.float32)], levels.array, 0, seed=1)
    assert np.array_equal(a.dn, b.dn) and a.grid == cam.sensor_grid and a.on_grid("dn").grid == cam.sensor_grid


def test_identity_registration_round_trip_is_exact():
    cam = _camera(psf="gaussian")
    g = cam.guard_px
    assert g > 0 and cam.taps is None                   # identity: the sensor is the mirror grid's centre
    rng = np.random.default_rng(3)
    m = OnGrid(rng.uniform(0, 1000, cam.mirror_shape).astype(np.float32), cam.mirror_grid)
    s = cam.to_sensor(m)
    assert s.grid == cam.sensor_grid
    back = cam.to_mirror(s)
    assert back.grid == cam.mirror_grid
    h, w = cam.shape
    assert np.array_equal(back.array[g:g + h, g:g + w], m.array[g:g + h, g:g + w])
    # the guard band: the sensor picture's edge replicated (bilinear, BORDER_REPLICATE)
    assert np.array_equal(back.array, np.pad(s.array.astype(np.float32), g, mode="edge"))
    # and the other way: sensor -> mirror -> sensor is the identity everywhere
    assert np.array_equal(cam.to_sensor(cam.to_mirror(s)).array, s.array)


def test_oracle_command_is_on_the_mirror_grid():
    cam = _camera(psf="gaussian")
    step = LoopStep(cam, MaskSpec(law="target", target=0.5, smooth_px=0.0), LoopSpec(), PredictorSpec(name="oracle"))
    truth = np.full(cam.mirror_shape, 1.0, np.float32)
    truth *= 2.0 * cam.params.saturation_capacity_e / (cam.electrons_per_radiance() * cam.white_exposure_s(2))
    with pytest.raises(GridError, match="oracle's truth is on the sensor grid"):
        step.command(2, OnGrid(np.ones(cam.shape, np.float32), cam.sensor_grid))
    for i in (0, 2):                                    # an init frame and a decided one
        cmd = step.command(i, OnGrid(truth, cam.mirror_grid))
        assert cmd.levels.grid == Grid("mirror", cam.mirror_shape, cam.dmd.spec.pitch_m)
        assert cmd.levels.shape == cam.mirror_shape == (SHAPE[0] + 2 * cam.guard_px, SHAPE[1] + 2 * cam.guard_px)
        assert cmd.late_levels is None or cmd.late_levels.grid == cam.mirror_grid
    # twice saturation everywhere: the target law halves (or more) every mirror's level
    assert np.all(cmd.levels.array <= cam.top_level / 2 + 1)
    # the command drives the camera as it is (tagged), a sensor-grid capture comes back
    cap = cam.capture([truth], cmd.levels, 2, seed=1, transmission=cmd.transmission)
    assert cap.grid == cam.sensor_grid and cap.dn.shape == cam.shape


def test_registration_scale_two_maps_shapes_coordinates_and_flux_in_closed_form():
    scale = 2.0
    cam = _camera(scale=scale, psf="gaussian")
    h, w = SHAPE
    gs = cam.psf.kernel.shape[0] // 2                   # the relay's guard on the sensor
    gm = math.ceil(gs / scale) + 1                      # mirrors covering it through the map, +1 sampling
    assert cam.mirror_grid.shape == (h + 2 * gm, w + 2 * gm)
    hm, wm = cam.mirror_shape
    # sensor -> mirror: a ramp f(x) = x sampled at each mirror's centre x_m + 0.5, mapped by
    # s = scale (m - wm/2) + w/2 (pixel centres at +0.5), edge-replicated off the sensor
    ramp = OnGrid(np.tile(np.arange(w, dtype=np.float32), (h, 1)), cam.sensor_grid)
    placed = cam.to_mirror(ramp)
    assert placed.grid == cam.mirror_grid and placed.shape == (hm, wm)
    mx = np.arange(wm) + 0.5
    want = np.clip(scale * (mx - wm / 2) + w / 2 - 0.5, 0, w - 1)
    assert np.allclose(placed.array, np.tile(want, (hm, 1)), atol=1e-4)
    # mirror -> sensor: radiance conserved, so flux scales by scale^2 for an image inside the field
    m = np.zeros((hm, wm))
    m[hm // 2 - 1:hm // 2 + 1, wm // 2 - 2:wm // 2 + 1] = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]
    seen = cam.to_sensor(OnGrid(m, cam.mirror_grid))
    assert seen.grid == cam.sensor_grid and seen.shape == SHAPE
    assert seen.array.sum() == pytest.approx(scale ** 2 * m.sum(), rel=1e-12)
    assert seen.array.max() == pytest.approx(6.0)       # a sensor pixel inside one mirror reads its radiance


def test_loop_history_and_prediction_are_on_the_predictor_grid():
    cam = _camera(psf="gaussian")
    pspec = PredictorSpec(name="hold", resolution=(8, 12))
    step = LoopStep(cam, MaskSpec(law="target", target=0.5, smooth_px=0.0), LoopSpec(init_frames=1), pspec)
    ldr = cam.capture([np.ones(cam.mirror_shape, np.float32)], cam.white_mask(), 0, seed=1)
    est, flags, _ = cam.reconstruct(ldr, 0)
    step.observe(0, ldr, ldr, est, flags)
    assert [x.grid for x in step.history] == [Grid("predictor", (8, 12))]
    cmd = step.command(1)
    assert not cmd.record.get("init") and cmd.levels.grid == cam.mirror_grid


def test_sampling_maps_are_kept_per_registration():
    """`to_mirror` keeps its sampling maps per registration and shapes: cameras at scale 2 and
    1.5, used in turn (A, B, A, B), each place the ramp f(x) = x at s = scale (m - wm/2) + w/2 - 0.5
    (edge-replicated), their own closed form, every time."""
    h, w = SHAPE
    cams = [_camera(scale=s, psf="gaussian") for s in (2.0, 1.5)]
    ramp = np.tile(np.arange(w, dtype=np.float32), (h, 1))
    for cam in cams + cams:
        scale = cam.registration.scale
        hm, wm = cam.mirror_shape
        placed = cam.to_mirror(OnGrid(ramp, cam.sensor_grid))
        want = np.clip(scale * (np.arange(wm) + 0.5 - wm / 2) + w / 2 - 0.5, 0, w - 1)
        assert np.allclose(placed.array, np.tile(want, (hm, 1)), atol=1e-4), scale
