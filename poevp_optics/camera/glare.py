"""Veiling-glare halos of the camera's lenses: one registry, `GLARE_MODELS`, name -> halo class.

Veiling glare spreads a share g of every source's light over a wide halo H (unit sum): the stage
forms (1 - g) core + g H * x. The objective's halo is `power_law` (`objective.glare_model`,
shaped by objective.glare_exponent / glare_core_radius_deg / glare_outer_radius_deg); the
relay's is `gaussian` (relay.glare_fraction, relay.glare_sigma_px). Each entry is a frozen
dataclass of the halo's shape in pixels with

- `section`: the scene section whose keys shape it, and `from_keys(spec, support_px,
  support_energy)` building it from that section (and the stage's accuracy settings);
- `radius_px()`: the kernel's radius before any cap (the guard band, the memory estimate);
- `kernel(cap_radius_px)`: the unit-sum, pixel-integrated `GlareKernel`, its support capped at
  `cap_radius_px` (the image's extent, kernels.max_radius_px), with the energy left out;
- `energy_beyond(rho_px)`: the closed-form share of the halo's energy beyond radius rho.

Adding a halo is one class and one `GLARE_MODELS.register` call here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from poevp_optics.camera.kernels import capped_radius, cap_note, pixel_integrated, pixel_integrated_radial
from poevp_optics.core.registry import Registry

GLARE_MODELS = Registry("glare model")


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


def glare_radii_px(params) -> tuple[float, float]:
    """(core, outer) radii of the objective's halo on the image plane, px: f tan(angle) / pitch
    (params: ObjectiveParams)."""
    f = params.focal_length_m / params.pixel_pitch_m
    return (f * math.tan(math.radians(params.glare_core_radius_deg)),
            f * math.tan(math.radians(params.glare_outer_radius_deg)))


def _log_or_power(a: float, b: float, n: float) -> float:
    """int_a^b r^(1-n) dr."""
    return math.log(b / a) if abs(n - 2) < 1e-12 else (b ** (2 - n) - a ** (2 - n)) / (2 - n)


def power_law_halo(r_px, rc: float, ro: float, n: float):
    """Normalised power-law glare spread function (per px^2): A inside the core radius rc,
    A (r / rc)^-n out to ro, 0 beyond; A = 1 / (pi rc^2 + 2 pi rc^n int_rc^ro r^(1-n) dr)."""
    a = 1.0 / (math.pi * rc * rc + 2 * math.pi * rc ** n * _log_or_power(rc, ro, n))
    r = np.asarray(r_px, float)
    with np.errstate(divide="ignore"):
        return np.where(r < rc, a, np.where(r <= ro, a * (np.maximum(r, rc) / rc) ** -n, 0.0))


def power_law_energy_beyond(rho: float, rc: float, ro: float, n: float) -> float:
    """Share of the normalised power-law halo's energy beyond radius rho (closed form)."""
    a = 1.0 / (math.pi * rc * rc + 2 * math.pi * rc ** n * _log_or_power(rc, ro, n))
    if rho >= ro:
        return 0.0
    if rho <= rc:
        return a * (math.pi * (rc * rc - rho * rho) + 2 * math.pi * rc ** n * _log_or_power(rc, ro, n))
    return a * 2 * math.pi * rc ** n * _log_or_power(rho, ro, n)


@dataclass(frozen=True)
class PowerLawHalo:
    """ISO 18844-style glare spread function: flat inside `core_radius_px`, r^-`exponent` out to
    `outer_radius_px`, 0 beyond (`power_law_halo`), shift-invariant on the image plane (ISO
    18844:2017, image flare measurement; ISO 9358:1994, veiling glare index; power-law fits of
    measured lens glare, e.g. Talvala et al., ACM TOG 26(3), 2007). Pixel-integrated: 16^2
    sub-pixels within 4 core radii + 2 px, 3^2 beyond."""

    core_radius_px: float
    outer_radius_px: float
    exponent: float
    section: ClassVar[str] = "objective"

    @classmethod
    def from_keys(cls, params, support_px: int = 0, support_energy: float = 0.999) -> "PowerLawHalo":
        """From [objective] (ObjectiveParams): radii from the field angles; the support is the
        whole halo (support_px, support_energy unused)."""
        rc, ro = glare_radii_px(params)
        return cls(rc, ro, params.glare_exponent)

    def radius_px(self) -> int:
        return int(math.ceil(self.outer_radius_px + 1))

    def energy_beyond(self, rho_px: float) -> float:
        return power_law_energy_beyond(rho_px, self.core_radius_px, self.outer_radius_px, self.exponent)

    def kernel(self, cap_radius_px: int | None = None) -> GlareKernel:
        rc, ro, n = self.core_radius_px, self.outer_radius_px, self.exponent
        want = self.radius_px()
        r = capped_radius(want, cap_radius_px)

        def prof(rr):
            return power_law_halo(rr, rc, ro, n)

        k = pixel_integrated_radial(prof, r, 3)
        m = min(r, int(math.ceil(4 * rc + 2)))
        k[r - m:r + m + 1, r - m:r + m + 1] = pixel_integrated_radial(prof, m, 16)
        return GlareKernel("power_law", k / k.sum(), self.energy_beyond(r + 0.5), cap_note(want, r))


def gaussian_radius_px(sigma_px: float, support_px: int = 0, energy: float = 0.9995) -> int:
    """Radius (px) of a Gaussian kernel before any cap: support_px // 2, or the radius holding
    `energy` (2-D Gaussian: the energy beyond r is exp(-r^2 / (2 sigma^2)))."""
    if support_px:
        return support_px // 2
    return max(int(math.ceil(sigma_px * math.sqrt(-2 * math.log(1 - energy)))), 1)


@dataclass(frozen=True)
class GaussianHalo:
    """Pixel-integrated (7^2 sub-pixels) 2-D Gaussian of `sigma_px`: a stray-light pedestal
    (lenses have veiling-glare indices of about 1-5 %, ISO 9358:1994); support `support_px`, or
    the radius holding `support_energy`. Its energy beyond r is exp(-r^2 / (2 sigma^2))."""

    sigma_px: float
    support_px: int = 0
    support_energy: float = 0.9995
    section: ClassVar[str] = "relay"

    @classmethod
    def from_keys(cls, spec, support_px: int = 0, support_energy: float = 0.9995) -> "GaussianHalo":
        """From [relay] (RelaySpec): sigma = glare_sigma_px; support from the run's accuracy."""
        return cls(spec.glare_sigma_px, support_px, support_energy)

    def radius_px(self) -> int:
        return gaussian_radius_px(self.sigma_px, self.support_px, self.support_energy)

    def energy_beyond(self, rho_px: float) -> float:
        return math.exp(-0.5 * (rho_px / self.sigma_px) ** 2)

    def kernel(self, cap_radius_px: int | None = None) -> GlareKernel:
        want = self.radius_px()
        r = capped_radius(want, cap_radius_px)
        k = pixel_integrated(lambda rr: np.exp(-0.5 * (rr / self.sigma_px) ** 2), r)
        # energy outside the square support, from the radial Gaussian tail (a lower bound)
        return GlareKernel("gaussian", k / k.sum(), self.energy_beyond(r + 0.5), cap_note(want, r))


GLARE_MODELS.register("power_law", PowerLawHalo,
                      source="ISO 18844:2017 / ISO 9358:1994 style: flat core, r^-n halo (Talvala et al. 2007)")
GLARE_MODELS.register("gaussian", GaussianHalo,
                      source="a Gaussian stray-light pedestal of glare_sigma_px (veiling-glare index ~1-5 %, ISO 9358)")


def models_of(section: str) -> Registry:
    """The entries shaped by `section`'s keys, as a registry of the same name (the choices of that
    section's `glare_model` key: the objective's keys shape only `power_law`)."""
    view = Registry(GLARE_MODELS.what)
    for name in GLARE_MODELS:
        e = GLARE_MODELS.entry(name)
        if e.obj.section == section:
            view.register(name, e.obj, source=e.source, doc=e.doc)
    return view
