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

from poevp_optics.sources import spectra
from poevp_optics.render.renderer import Renderer, absolute_spectrum
from poevp_optics.scene.load import load_scene
from poevp_optics.camera.sensor import IMX253

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
    # the box-filtered pixel: cos^3 averaged over the pixel's square on the film (tan plane),
    # 16 x 16 points per pixel (midpoint rule, error ~1e-7: below a QMC sampler's noise too)
    sub = 16
    c = (np.arange(RES * sub) + 0.5) / (RES * sub) * 2 - 1
    x, y = np.meshgrid(c * half, c * half)
    cos3 = (1 / np.sqrt(1 + x**2 + y**2)) ** 3
    cos3 = cos3.reshape(RES, sub, RES, sub).mean(axis=(1, 3))
    return weighted * cos3 / (math.pi * D_M**2)


@pytest.mark.parametrize("mode,rho_source", [
    ("mono", "neutral:0.5"),
    ("spectral", "neutral:0.5"),
    ("spectral", "colorchecker:orange"),
])
def test_lambertian_plane_matches_closed_form(write_scene, mode, rho_source):
    spec = _scene(write_scene, rho_source, mode, spp=64)
    r = Renderer(spec.resolved.render)
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
    mono = Renderer(_scene(write_scene, "colorchecker:orange", "mono", 16).resolved.render)
    m, vm = mono.render_with_error([1, 2, 3, 4], 16)
    spec = Renderer(_scene(write_scene, "colorchecker:orange", "spectral", 256).resolved.render)
    s, vs = spec.render_with_error([5, 6, 7, 8], 256)
    diff = float(m.sum(dtype=np.float64) - s.sum(dtype=np.float64))
    sigma = math.sqrt(float(vm.sum() + vs.sum()))
    assert abs(diff) <= 4 * sigma + 1e-4 * float(s.sum()), (diff / float(s.sum()), sigma / float(s.sum()))
    # mono has no wavelength noise: its error is far smaller at 16x fewer samples
    assert vm.sum() < vs.sum()


def test_cie_a_lamp_matches_planck_closed_form_over_the_whole_band(write_scene):
    """Issue 13, bug 4: a CIE A lamp's sensor-weighted radiance within 1 % of a closed form
    built from an independent spectrum: Planck's law at 2856 K (c2 = 1.4388e-2 m K, CIE 015)
    on a 1 nm grid over 360-830 nm, scaled to the lamp's candela with CIE 1924 V(lambda) and
    K_m = 683.002 lm/W, weighted by the IMX253 QE read straight from its CSV. The project's
    old spectrum (zero beyond colour-science's 780 nm table) was 11 % low here. Mono path:
    no wavelength noise, and the plane's pixel values are exact up to float32."""
    import colour

    spec = _scene(write_scene, "neutral:0.5", "mono", spp=16)
    img = Renderer(spec.resolved.render).render_with_error([1, 2, 3, 4], spec.render.spp)[0].astype(np.float64)
    wl = np.arange(360.0, 830.5, 1.0)
    wl_m = wl * 1e-9
    planck = wl_m ** -5 / np.expm1(1.4388e-2 / (wl_m * 2856.0))              # relative SPD
    v = colour.colorimetry.SDS_LEFS_PHOTOPIC["CIE 1924 Photopic Standard Observer"]
    v_l = np.interp(wl, np.asarray(v.wavelengths, float), np.asarray(v.values, float), left=0, right=0)
    spd = planck * 1000.0 / (683.002 * np.trapezoid(v_l * planck, wl))      # W sr-1 nm-1 at 1000 cd
    lines = (spectra.ASSETS_DIR / "spectra" / "imx253_mono_qe.csv").read_text().splitlines()
    qe_tab = np.array([[float(v) for v in ln.split(",")] for ln in lines
                       if ln.strip() and not ln.startswith("#") and not ln.startswith("wavelength")])
    qe = np.interp(wl, qe_tab[:, 0], qe_tab[:, 1], left=0, right=0)
    h, c = 6.62607015e-34, 299792458.0
    i_s = np.trapezoid(qe * wl_m / (h * c) * spd, wl)                       # e- s-1 sr-1
    half = math.tan(math.radians(FOV_DEG) / 2)
    cc = (np.arange(RES) + 0.5) / RES * 2 - 1
    x, y = np.meshgrid(cc * half, cc * half)
    cos_t = 1 / np.sqrt(1 + x ** 2 + y ** 2)
    expected = 0.5 * i_s * cos_t ** 3 / (math.pi * D_M ** 2)
    # pixel-centre cos^3 vs the pixel's area average: < 1e-5 at this 6 deg field
    np.testing.assert_allclose(img, expected, rtol=0.01)
