"""Vignetting: the relative illumination per pixel (`VIGNETTING` registry: none, cos^4, the
prescription's ray-traced profile, cached on disk)."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Callable

import numpy as np

from poevp_optics.camera.objective.cache import cache_key, resolve_cache_dir
from poevp_optics.camera.objective.params import VIGNETTING, ObjectiveParams, band
from poevp_optics.camera.objective.prescriptions import build_lens, check_field
from poevp_optics.core.cache import cached, save_npz

def field_angle_rad(params: ObjectiveParams, image_shape) -> np.ndarray:
    """Field angle of each pixel centre: tan(theta) = r / f, r its distance from the image centre
    (the pinhole render's projection)."""
    h, w = int(image_shape[0]), int(image_shape[1])
    y = (np.arange(h) - (h - 1) / 2)[:, None]
    x = (np.arange(w) - (w - 1) / 2)[None, :]
    return np.arctan(np.hypot(x, y) * params.pixel_pitch_m / params.focal_length_m)


def _ri_cos4(params, image_shape, cache_dir=None):
    """Natural vignetting of a distortion-free lens with a small flat pupil: E / E0 = cos^4 theta
    (e.g. Smith, Modern Optical Engineering, 4th ed., 9.9; Slater 1980, 'Illumination')."""
    return np.cos(field_angle_rad(params, image_shape)) ** 4


_RI_KEYS = ("prescription", "f_number", "focal_length_m", "pixel_pitch_m", "wavelengths_nm", "qe",
            "band_samples")


def ri_profile(params: ObjectiveParams, theta_max_rad: float, samples: int = 129):
    """Relative illumination of the prescription at `samples` field angles 0 .. theta_max.

    RI(theta) = [A(theta) / A(0)] cos(theta) f^2 sin(theta) / (y y'): the flux a unit solid angle
    of object sends through the entrance pupil (projected area A cos theta, A the unvignetted,
    transmitted share of the pupil, from optiland's traced rays' intensities) over the image
    area it covers (y dy dphi / (sin theta dtheta dphi), y(theta) the real chief ray's height).
    For y = f tan(theta) and no mechanical vignetting it is cos^4 theta; real distortion and
    vignetting change it (Reshidko & Sasian, Opt. Eng. 55(11), 115105, 2016). Rays are aimed at
    the paraxial entrance pupil (optiland's default), so pupil aberration is left out. Weighted
    over the band and normalised to 1 on axis. Returns (theta_rad, ri)."""
    import optiland.backend as be

    wl_nm, w = band(params)
    th_deg = np.degrees(np.linspace(0.0, theta_max_rad, samples))
    g = (np.arange(24) + 0.5) / 12 - 1.0                      # 24 x 24 pupil grid, inside the unit disc
    px, py = np.meshgrid(g, g)
    sel = px * px + py * py <= 1
    px, py = px[sel], py[sel]
    with warnings.catch_warnings():      # numba's pedantic IR warnings from optiland's JIT kernels
        warnings.simplefilter("ignore")
        lens = build_lens(params, wl_nm, float(th_deg[-1]))
        fmax = float(lens.fields.max_field)
        f_mm = params.focal_length_m * 1e3
        h = 1e-4 * max(th_deg[-1], 1e-3)
        ri = np.zeros(samples)
        for lam, wi in zip(wl_nm * 1e-3, w):
            def chief(t_deg):
                t_deg = np.asarray(t_deg, float)
                z = be.array(np.zeros_like(t_deg))
                r = lens.trace_generic(Hx=z, Hy=be.array(np.clip(t_deg / fmax, -1.0, 1.0)), Px=z, Py=z,
                                       wavelength=float(lam))
                return np.asarray(be.to_numpy(r.y), float)
            y = chief(th_deg)
            # dy/dtheta: central differences (y is odd in theta, so theta = 0 is central too); the
            # last angle, at the field's edge, by the second-order backward formula
            dy = (chief(th_deg + h) - chief(th_deg - h)) / np.radians(2 * h)
            t_end = th_deg[-1]
            dy[-1] = (3 * y[-1] - 4 * chief([t_end - h])[0] + chief([t_end - 2 * h])[0]) / np.radians(2 * h)
            # transmitted share of a uniform pupil grid at every angle, in one trace
            hy = np.repeat(th_deg / fmax, px.size)
            rays = lens.trace_generic(Hx=be.array(np.zeros_like(hy)), Hy=be.array(np.clip(hy, -1.0, 1.0)),
                                      Px=be.array(np.tile(px, samples)), Py=be.array(np.tile(py, samples)),
                                      wavelength=float(lam))
            inten = np.nan_to_num(np.asarray(be.to_numpy(rays.i), float)).reshape(samples, px.size)
            area = inten.mean(axis=1)
            th = np.radians(th_deg)
            with np.errstate(invalid="ignore", divide="ignore"):
                jac = np.where(th > 0, f_mm * f_mm * np.sin(th) / (y * dy), (f_mm / dy[0]) ** 2)
            ri += wi * (area / area[0]) * np.cos(th) * jac
    ri = ri / ri[0]      # relative to the axis (the band's on-axis scale is the layout's f-number)
    return np.radians(th_deg), ri


def _ri_prescription(params, image_shape, cache_dir=None):
    """Relative illumination from the prescription (`ri_profile`), cached, interpolated per pixel
    by a cubic spline in theta."""
    from scipy.interpolate import CubicSpline

    theta = field_angle_rad(params, image_shape)
    tmax = float(theta.max())
    check_field(params, math.degrees(tmax))
    path = resolve_cache_dir(cache_dir) / f"ri-{cache_key('ri', params, image_shape, _RI_KEYS)}.npz"
    th, ri = cached(path, lambda: ri_profile(params, tmax), load=_load_ri,
                    save=lambda tmp, v: save_npz(tmp, {"theta_rad": v[0], "ri": v[1]}),
                    check=lambda v: _ri_problem(v, tmax))
    if tmax == 0:
        return np.ones(theta.shape)
    return CubicSpline(th, ri)(theta)


def _load_ri(path):
    with np.load(path) as z:
        return z["theta_rad"], z["ri"]


def _ri_problem(v, theta_max_rad: float) -> str | None:
    """Why a loaded (theta_rad, ri) table is not `ri_profile`'s for `theta_max_rad`, or None."""
    th, ri = (np.asarray(a) for a in v)
    if th.ndim != 1 or th.shape != ri.shape or th.size < 2:
        return f"theta_rad {th.shape} and ri {ri.shape}: not two equal 1-D tables"
    if not (np.all(np.isfinite(th)) and np.all(np.isfinite(ri)) and ri.min() > 0 and ri[0] == 1.0):
        return "ri not finite, positive and 1 on axis"
    if th[0] != 0 or not np.isclose(th[-1], theta_max_rad, rtol=1e-12, atol=0) or \
            (theta_max_rad > 0 and np.any(np.diff(th) <= 0)):
        return f"angles {th[0]:.6g} .. {th[-1]:.6g} rad, not 0 .. {theta_max_rad:.6g} rising"
    return None


@dataclass(frozen=True)
class VignettingEntry:
    build: Callable        # (params, image_shape, cache_dir) -> (H, W) relative illumination, or None
    source: str


VIGNETTING.register("none", VignettingEntry(lambda params, shape, cache_dir=None: None, "none"),
                    source="no vignetting")
VIGNETTING.register("cos4", VignettingEntry(_ri_cos4, "cos4"),
                    source="cos^4 law of the field angle (Smith, Modern Optical Engineering, 9.9)")
VIGNETTING.register("prescription", VignettingEntry(_ri_prescription, "prescription"),
                    source="relative illumination of `prescription` from optiland ray traces: real chief-ray "
                    "heights (distortion) x pupil transmission x cos theta (Reshidko & Sasian 2016); the "
                    "bundled samples have no clear apertures, so it holds no mechanical vignetting")


def relative_illumination(params: ObjectiveParams, image_shape, *, cache_dir=None) -> np.ndarray | None:
    """(H, W) relative illumination (1 on axis) per pixel, or None for `vignetting = "none"`."""
    return VIGNETTING[params.vignetting].build(params, (int(image_shape[0]), int(image_shape[1])), cache_dir)
