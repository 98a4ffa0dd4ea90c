"""Veiling glare: the glare spread function (`GLARE_MODELS` registry: power_law) and the glare
floor it puts under a dark spot (VGI, ISO 9358)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from poevp_optics.camera.objective.params import GLARE_MODELS, ObjectiveParams
from poevp_optics.camera.objective.psfs import cap_note, max_radius_px, pixel_integrated_radial

@dataclass(frozen=True, eq=False)
class GlareKernel:
    """Unit-sum glare spread function on the pixel grid and the energy its support left out."""

    name: str
    kernel: np.ndarray
    truncation_error: float
    note: str = ""

    @property
    def radius_px(self) -> int:
        return self.kernel.shape[0] // 2


def glare_radii_px(params: ObjectiveParams) -> tuple[float, float]:
    """(core, outer) radii of the halo on the image plane, px: f tan(angle) / pitch."""
    f = params.focal_length_m / params.pixel_pitch_m
    return (f * math.tan(math.radians(params.glare_core_radius_deg)),
            f * math.tan(math.radians(params.glare_outer_radius_deg)))


def power_law_halo(r_px, rc: float, ro: float, n: float):
    """Normalised power-law glare spread function (per px^2): A inside the core radius rc,
    A (r / rc)^-n out to ro, 0 beyond; A = 1 / (pi rc^2 + 2 pi rc^n int_rc^ro r^(1-n) dr)."""
    tail = math.log(ro / rc) if abs(n - 2) < 1e-12 else (ro ** (2 - n) - rc ** (2 - n)) / (2 - n)
    a = 1.0 / (math.pi * rc * rc + 2 * math.pi * rc ** n * tail)
    r = np.asarray(r_px, float)
    with np.errstate(divide="ignore"):
        return np.where(r < rc, a, np.where(r <= ro, a * (np.maximum(r, rc) / rc) ** -n, 0.0))


def power_law_energy_beyond(rho: float, rc: float, ro: float, n: float) -> float:
    """Share of the normalised halo's energy beyond radius rho (closed form)."""
    def integral(a, b):     # int_a^b r^(1-n) dr
        return math.log(b / a) if abs(n - 2) < 1e-12 else (b ** (2 - n) - a ** (2 - n)) / (2 - n)

    a = 1.0 / (math.pi * rc * rc + 2 * math.pi * rc ** n * integral(rc, ro))
    if rho >= ro:
        return 0.0
    if rho <= rc:
        return a * (math.pi * (rc * rc - rho * rho) + 2 * math.pi * rc ** n * integral(rc, ro))
    return a * 2 * math.pi * rc ** n * integral(rho, ro)


def _power_law_glare(params: ObjectiveParams, image_shape) -> GlareKernel:
    """ISO 18844-style glare spread function: a flat core of `glare_core_radius_deg` and a 1/r^n
    halo to `glare_outer_radius_deg`, shift-invariant on the image plane (ISO 18844:2017, image
    flare measurement; ISO 9358:1994, veiling glare index; power-law fits of measured lens glare,
    e.g. Talvala et al., ACM TOG 26(3), 2007). Pixel-integrated (16^2 sub-pixels within 4 core
    radii + 2 px, 3^2 beyond)."""
    rc, ro = glare_radii_px(params)
    n = params.glare_exponent
    want = int(math.ceil(ro + 1))
    r = min(want, max_radius_px(image_shape))

    def prof(rr):
        return power_law_halo(rr, rc, ro, n)

    k = pixel_integrated_radial(prof, r, 3)
    m = min(r, int(math.ceil(4 * rc + 2)))
    k[r - m:r + m + 1, r - m:r + m + 1] = pixel_integrated_radial(prof, m, 16)
    trunc = power_law_energy_beyond(r + 0.5, rc, ro, n)
    return GlareKernel("power_law", k / k.sum(), trunc, cap_note(want, r))


GLARE_MODELS.register("power_law", _power_law_glare,
                      source="ISO 18844:2017 / ISO 9358:1994 style: flat core, r^-n halo (Talvala et al. 2007)")


def glare_kernel(params: ObjectiveParams, image_shape) -> GlareKernel | None:
    """The glare spread function for an image of `image_shape`, or None when glare_fraction = 0."""
    if params.glare_fraction <= 0:
        return None
    return GLARE_MODELS[params.glare_model](params, (int(image_shape[0]), int(image_shape[1])))


def glare_floor(params: ObjectiveParams, image_shape, black_radius_px: float) -> dict:
    """The veiling-glare floor under a dark spot: a black disc of radius rho (px) in a uniform
    white field L gets g L E_H(> rho) at its centre (the halo's energy beyond rho,
    `power_law_energy_beyond`), while the white field keeps L (unit-sum kernels): the veiling
    glare index VGI = g E_H(> rho) (ISO 9358:1994; rho -> 0 gives g). The glare is in the image the
    mirrors see, so no mask lowers it: a scene's darkest-to-brightest ratio below VGI is veiled,
    and the encoded DR is capped at floor_db = -20 log10 VGI whatever the DMD's attenuation.
    Valid for the `power_law` model; the halo's kernel truncation at the image's extent is
    reported beside it."""
    g = params.glare_fraction
    if g <= 0:
        return {"glare_fraction": 0.0, "black_radius_px": float(black_radius_px), "vgi": 0.0,
                "floor_db": math.inf}
    rc, ro = glare_radii_px(params)
    vgi = g * power_law_energy_beyond(float(black_radius_px), rc, ro, params.glare_exponent)
    kernel = glare_kernel(params, image_shape)
    return {"glare_fraction": g, "black_radius_px": float(black_radius_px), "vgi": vgi,
            "floor_db": float(-20 * math.log10(vgi)) if vgi > 0 else math.inf,
            "halo_radii_px": [rc, ro], "halo_truncation": kernel.truncation_error}
