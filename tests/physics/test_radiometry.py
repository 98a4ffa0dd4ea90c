"""Absolute radiometry of the render against closed forms (issue 2).

A Lambertian plane of reflectance rho, facing a point source of intensity I at distance d on
the camera axis, has radiance L = rho I cos^3(theta) / (pi d^2) at off-axis angle theta
(irradiance I cos(theta) / r^2 with r = d / cos(theta), times rho / pi). In the sensor-weighted
unit, I is replaced by I_S = integral S(lambda) I_e(lambda) d lambda and rho by its
S-and-SPD-weighted mean.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from poevp_optics import spectra
from poevp_optics.render import Renderer, absolute_spectrum
from poevp_optics.scene import load_scene
from poevp_optics.sensor import IMX253

from tests.helpers import PLANE_XML

D_M = 4.0
FOV_DEG = 6.0
RES = 33


def _scene(write_scene, rho_source: str, mode: str, spp: int):
    toml = f"""
    [render]
    spp = {spp}
    resolution = [{RES}, {RES}]
    seed = 11
    spectral_mode = "{mode}"
    mc_splits = 4
    [timing]
    frames = 1
    [spectra.lamp]
    kind = "intensity"
    source = "cie:A"
    intensity_cd = 1000.0
    [spectra.rho]
    kind = "reflectance"
    source = "{rho_source}"
    """
    folder = write_scene(toml, PLANE_XML.format(fov=FOV_DEG, d=D_M), name=f"plane_{mode}_{spp}")
    return load_scene(folder)


def _closed_form(spec) -> np.ndarray:
    """Expected per-pixel photon radiance (e- s-1 m-2 sr-1), pixel-centre cos^3 law."""
    response = spectra.sensor_response_e_per_J(spectra.load_spectrum(IMX253.qe, emissive=True))
    lamp = absolute_spectrum(spec.spectra["lamp"])
    rho = absolute_spectrum(spec.spectra["rho"])
    weighted = spectra.integrate(response * lamp * rho)          # = rho_eff * I_S
    half = math.tan(math.radians(FOV_DEG) / 2)
    c = (np.arange(RES) + 0.5) / RES * 2 - 1
    x, y = np.meshgrid(c * half, c * half)
    cos_t = 1 / np.sqrt(1 + x**2 + y**2)
    return weighted * cos_t**3 / (math.pi * D_M**2)


@pytest.mark.parametrize("mode,rho_source", [
    ("mono", "neutral:0.5"),
    ("spectral", "neutral:0.5"),
    ("spectral", "colorchecker:orange"),
])
def test_lambertian_plane_matches_closed_form(write_scene, mode, rho_source):
    spec = _scene(write_scene, rho_source, mode, spp=64)
    r = Renderer(spec)
    assert r.plan.mode == mode
    seeds = [101, 202, 303, 404]
    mean, var = r.render_with_error(seeds, spec.render.spp)
    expected = _closed_form(spec)
    # Compare the frame sums: the MC standard error of the sum is sqrt(sum var). Tolerance:
    # 4 sigma (two-sided p ~ 6e-5) plus 2e-4 for the cos^3 evaluation at pixel centres
    # instead of over the pixel area (second-order term ~ (pixel angle)^2 ~ 3e-5).
    total, total_exp = float(mean.sum(dtype=np.float64)), float(expected.sum())
    sigma = math.sqrt(float(var.sum()))
    tol = 4 * sigma + 2e-4 * total_exp
    assert abs(total - total_exp) <= tol, (total / total_exp - 1, sigma / total_exp)
    assert abs(total / total_exp - 1) < 0.02
    # per pixel too: the normalised residual is standard normal-ish (4 splits: t with 3 dof,
    # so use a loose 10 sigma bound only against gross per-pixel errors)
    z = (mean - expected) / np.sqrt(np.maximum(var, 1e-30 * expected.max() ** 2))
    assert np.median(np.abs(z)) < 2.0


def test_mono_and_spectral_paths_agree_on_spectral_plate(write_scene):
    """Pre-integrated mono equals spectral when one emitter lights a spectral reflectance once."""
    mono = Renderer(_scene(write_scene, "colorchecker:orange", "mono", 16))
    m, vm = mono.render_with_error([1, 2, 3, 4], 16)
    spec = Renderer(_scene(write_scene, "colorchecker:orange", "spectral", 256))
    s, vs = spec.render_with_error([5, 6, 7, 8], 256)
    diff = float(m.sum(dtype=np.float64) - s.sum(dtype=np.float64))
    sigma = math.sqrt(float(vm.sum() + vs.sum()))
    assert abs(diff) <= 4 * sigma + 1e-4 * float(s.sum()), (diff / float(s.sum()), sigma / float(s.sum()))
    # mono has no wavelength noise: its error is far smaller at 16x fewer samples
    assert vm.sum() < vs.sum()
