"""Mirror grid -> sensor grid registration (issue 13, bug 1): radiance and flux are conserved,
and masks computed from sensor-grid predictions land on the mirrors that image the highlight."""

from __future__ import annotations

import math

import numpy as np
import pytest

from poevp_optics.camera.camera import Camera
from poevp_optics.camera.registration import apply_taps, apply_taps_numpy, forward_taps, mirror_coords
from poevp_optics.camera.registration import RegistrationSpec
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES

H, W = 48, 64
MAPS = {
    "offset 1 px": RegistrationSpec(offset_px=(1.0, 0.0)),
    "rotation 45 deg": RegistrationSpec(rotation_deg=45.0),
    "scale 2": RegistrationSpec(scale=2.0),
    "scale 0.8, rotation 10, offset": RegistrationSpec(scale=0.8, rotation_deg=10.0, offset_px=(2.5, -3.25)),
    "rotation -30, sub-pixel offset": RegistrationSpec(rotation_deg=-30.0, offset_px=(0.3, 0.7)),
}


def _interior(reg, mirror_shape, sensor_shape):
    """Sensor pixels whose whole footprint (all four corners) maps inside the mirror array."""
    hs, ws = sensor_shape
    sy, sx = np.mgrid[0:hs, 0:ws].astype(np.float64)
    ok = np.ones((hs, ws), bool)
    for dy in (0.0, 1.0):
        for dx in (0.0, 1.0):
            mx, my = mirror_coords(reg, sx + dx, sy + dy, mirror_shape, sensor_shape)
            ok &= (mx > 0) & (mx < mirror_shape[1]) & (my > 0) & (my < mirror_shape[0])
    return ok


@pytest.mark.parametrize("name", list(MAPS))
def test_uniform_mirror_image_reads_one_in_the_interior(name):
    """Radiance is conserved through the relay: a uniform DMD plane gives a uniform sensor image.
    The weights of each sensor pixel are oversample^2 sub-areas of 1/oversample^2 each, all
    inside the array in the interior: their sum is 1 exactly (1/16 is exact in binary), so the
    float32 DrJit path reads 1 to float32 rounding."""
    from drjit.auto import Float

    reg = MAPS[name]
    taps = forward_taps(reg, (H, W), (H, W))
    inside = _interior(reg, (H, W), (H, W))
    assert inside.sum() > 0.2 * H * W
    ones64 = apply_taps_numpy(np.ones((H, W)), taps, (H, W))
    ones32 = np.array(apply_taps(Float(np.ones(H * W, np.float32)), taps)).reshape(H, W)
    np.testing.assert_allclose(ones64[inside], 1.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ones32[inside], 1.0, rtol=0, atol=1e-6)


@pytest.mark.parametrize("name", list(MAPS))
def test_total_flux_is_conserved(name):
    """sum over sensor pixels = scale^2 x sum over mirrors (a sensor pixel sees the area average
    of its footprint; the image of one mirror covers scale^2 sensor pixels), for a smooth blob
    inside both grids. Point sampling of the piecewise-constant mirror image at 16^2 points per
    pixel errs by O(1/16^2) of the boundary pixels' share: 1e-3 relative allowed."""
    reg = MAPS[name]
    hm, wm = 96, 128
    y, x = np.mgrid[0:hm, 0:wm] + 0.5
    blob = np.exp(-((x - wm / 2) ** 2 + (y - hm / 2) ** 2) / (2 * 5.0 ** 2))
    taps = forward_taps(reg, (hm, wm), (hm, wm), oversample=16)
    img = apply_taps_numpy(blob, taps, (hm, wm))
    assert img.sum() == pytest.approx(reg.scale ** 2 * blob.sum(), rel=1e-3)


def test_predicted_mask_lands_on_the_highlight_after_a_registration_round_trip():
    """A highlight predicted on the sensor grid (clipped 8-bit) is dimmed by mirrors that the
    relay images onto that highlight: the exposure seen by the sensor there is low, and far
    away it is white. Without the inverse map the dark patch would sit 20 px off."""
    from poevp_optics.control.loop_step import predicted_mask

    spec = load_scene(SCENES / "smoke", [f"render.resolution=[{H},{W}]", "mask.smooth_px=1.0",
                                         "dmd.registration.offset_px=[20.0, -6.0]",
                                         "dmd.registration.rotation_deg=12.0", "dmd.registration.scale=1.1"])
    cam = Camera.from_params(spec.resolved.camera)
    pred = np.full((H, W), 20.0)
    cy, cx = 30, 14
    yy, xx = np.mgrid[0:H, 0:W]
    pred[(yy - cy) ** 2 + (xx - cx) ** 2 <= 9] = 255.0               # clipped highlight, r = 3 px
    mask = predicted_mask(cam, spec.mask, pred, 0)
    assert mask.shape == cam.mirror_shape
    rel = cam.level_exposure_s(0)[mask.astype(int)] / cam.white_exposure_s(0)
    seen = cam.to_sensor(rel)
    assert seen[cy, cx] < 0.1
    far = (yy - cy) ** 2 + (xx - cx) ** 2 > 15 ** 2
    inside = _interior(spec.dmd.registration, cam.mirror_shape, cam.shape)
    assert np.all(seen[far & inside] > 0.99)


def test_reconstruction_is_compared_on_the_sensor_grid(tmp_path):
    """With a non-identity map the run's reconstruction error is measured against the truth
    registered onto the sensor grid, not the mirror-grid truth: with the noise off (12-bit, so
    ADC rounding stays ~1 %) it equals the identity map's error; comparing with the mirror-grid
    truth would add the 3 px shift of a textured plate (tens of %)."""
    from poevp_optics.apps.run.render_run import run_render

    errs = []
    for reg in (["dmd.registration.offset_px=[3.0, 2.0]"], []):
        spec = load_scene(SCENES / "smoke", ["render.resolution=[24,32]", "render.spp=4", "timing.frames=1",
                                             "sensor.noise=false", "sensor.bits=12",
                                             "spectra.lamp.intensity_cd=200.0", "outputs.previews=false",
                                             "outputs.contact_sheet=false", *reg])
        errs.append(run_render(spec, tmp_path / str(len(errs)), progress=False)["metrics"]["recon_rel_error"])
    assert errs[0] < 0.05 and errs[0] == pytest.approx(errs[1], rel=0.1)
