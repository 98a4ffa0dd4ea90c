"""Objective lens: the image it forms on the DMD (before the mirrors can do anything).

Stage order (camera.py): render (pinhole) -> objective -> DMD -> relay -> sensor. The renderer draws
a pinhole image of sensor-weighted photon radiance on the mirror grid. A real
objective blurs it by diffraction and by aberrations that grow over the field, dims the field's
edge (vignetting), and spreads a little of every source's light over the whole image (veiling
glare). All three happen before the DMD, so no mask can undo them: glare around a headlamp is a
floor under the mask's attenuation. `apply(image, params)` models them as

    out = (1 - g) B(V x) + g H * (V x)

x the pinhole image, V the relative illumination (vignetting) per pixel, B the field-dependent
PSF blur (each source's PSF sums to one: flux is conserved), H the glare spread function (unit
sum), g the glare fraction. The optical axis is at the image's centre (the camera's guard band
is symmetric). Units pass through unchanged (V, B and H are dimensionless).

Keys of [objective] (`ObjectiveSpec`; kind: physics, or accuracy: numerics only, ACCURACY_KEYS).
The stage resolves them into `ObjectiveParams` with what the camera knows: the f-number from the
optical layout (layout.py), the image-plane pitch (the DMD mirror pitch; the sensor pitch without a
DMD) and the sensor's QE.

| key                    | type   | unit  | default   | kind     | source / meaning |
|------------------------|--------|-------|-----------|----------|------------------|
| f_number               | float  | -     | NaN       | physics  | working f-number at the DMD; NaN: from sensor.f_number / M (layout.py) |
| psf                    | str    | -     | "delta"   | physics  | registry `OBJECTIVE_PSFS`: delta, gaussian, airy, prescription |
| focal_length_m         | float  | m     | 0.025     | physics  | effective focal length; sets field angle tan(theta) = r / f |
| prescription           | str    | -     | "double_gauss" | physics | registry `PRESCRIPTIONS`, scaled to focal_length_m, stopped to f_number |
| sigma_px               | float  | px    | 1.0       | physics  | sigma of the `gaussian` PSF |
| wavelengths_nm         | tuple  | nm    | ()        | physics  | explicit wavelengths, weighted by the sensor response there; () = the sensor band |
| vignetting             | str    | -     | "none"    | physics  | registry `VIGNETTING`: none, cos4, prescription |
| glare_fraction         | float  | -     | 0.0       | physics  | g: share of the image-plane energy in the glare halo (ISO 9358 VGI ~ 1-5 %) |
| glare_model            | str    | -     | "power_law" | physics | registry `GLARE_MODELS` |
| glare_exponent         | float  | -     | 2.0       | physics  | n in the halo's r^-n (a Harvey-model slope typical of polished optics, Stover, Optical Scattering, 3rd ed.) |
| glare_core_radius_deg  | float  | deg   | 0.05      | physics  | halo flat inside this field angle from the source |
| glare_outer_radius_deg | float  | deg   | 30.0      | physics  | halo ends here (capped at the image's extent; the rest is reported as truncation) |
| field_samples          | int    | -     | 3         | accuracy | PSF nodes per quadrant and axis, axis and edge included (3: a 5 x 5 grid) |
| band_samples           | int    | -     | 3         | accuracy | wavelengths of the sensor band for the prescription (equal-weight quantiles) |
| pupil_rays             | int    | -     | 256       | accuracy | pupil samples per axis of optiland's FFT PSF (its field is lambda N (rays - 1) wide) |
| support_energy         | float  | -     | 0.999     | accuracy | PSF kernels keep the square holding this energy; the rest is reported |
| guard_max_px           | int    | px    | 256       | accuracy | widest guard band rendered for the objective's kernels |

Registries (core.registry, name -> entry with its source): `OBJECTIVE_PSFS`, `PRESCRIPTIONS`, `VIGNETTING`, `GLARE_MODELS`.
Adding one is one entry.

Spatially varying blur: the PSF is computed at a grid of field nodes and the image is blurred as
sum_n K_n * (w_n x), w_n the bilinear hat weights of node n (a partition of unity): each source
point's PSF is the bilinear interpolation of its four neighbouring node PSFs, so every source
keeps its flux and a constant PSF gives exactly the plain convolution (Nagy & O'Leary, SIAM J.
Sci. Comput. 19(4), 1998, "Restoring images degraded by spatially variant blur"). Each node is
an overlap-add of FFT convolutions (float64) over the tiles its weight covers.

Borders, as in relay.convolve: the image is continued by reflection over the kernel's reach;
the camera renders a guard band of `radius_px(params, footprint)` around the sensor's footprint
and crops it afterwards. Kernels wider than the image are capped at its extent (the energy
beyond is reported as truncation).

Model limits (what the prescription path leaves out, and why it is acceptable here): the lens
is centred and rotationally symmetric (one optiland PSF per field radius, rotated to each node);
distortion changes the relative illumination but does not move pixels (the render is a pinhole
projection; kernels are centred on the band-mean chief ray, lateral colour kept); the band
weights assume a spectrum flat in energy across each band part (as the relay's Airy PSF does);
rays are aimed at the paraxial pupil (no pupil aberration); the bundled samples have no clear
apertures, so `prescription` vignetting holds no mechanical vignetting; polarisation and
spectral transmission are ignored; optiland's FFT PSF covers a field lambda N (rays - 1) wide,
and the diffraction wings beyond it are reported with the truncation (Airy asymptote).

The prescription PSF grid is cached on disk ($POEVP_CACHE_DIR/objective, default
~/.cache/poevp_optics/objective; core.runtime.cache_dir), keyed by a SHA-256 of the parameters that shape it, the image
shape, this module's CACHE_VERSION and optiland's version (optiland import + numba JIT take
seconds).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import tempfile
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, get_type_hints

import numpy as np

from poevp_optics.core.exceptions import ParamError
from poevp_optics.core.params import Where, check_value, param
from poevp_optics.core.registry import Registry
from poevp_optics.sources import spectra

#: Bump when a change alters cached PSF grids or relative-illumination tables.
CACHE_VERSION = 2

#: Parameters that change numerics only (they belong to the run's Accuracy settings).
ACCURACY_KEYS = ("field_samples", "band_samples", "pupil_rays", "support_energy", "guard_max_px")

#: Default image-side f-number of `ObjectiveParams`: the sensor preset's f/2.8 divided by the relay
#: magnification M = sensor pitch / mirror pitch = 3.45 um / 7.56 um (layout.py, 1:1 registration).
DEFAULT_F_NUMBER = 2.8 / (3.45e-6 / 7.56e-6)

OBJECTIVE_PSFS = Registry("objective PSF")
PRESCRIPTIONS = Registry("lens prescription")
VIGNETTING = Registry("vignetting model")
GLARE_MODELS = Registry("glare model")


class ObjectiveParamError(ParamError):
    """A parameter out of range; the message names `objective.<key>` and the allowed range."""


@dataclass(frozen=True)
class ObjectiveSpec:
    """[objective]: the lens that images the scene onto the DMD (table in the module docstring)."""

    f_number: float = param(math.nan, gt=0, max=1000.0)  # at the DMD; NaN: from sensor.f_number
    psf: str = param("delta", choices=OBJECTIVE_PSFS)
    focal_length_m: float = param(0.025, gt=1e-4, max=10.0)
    prescription: str = param("double_gauss", choices=PRESCRIPTIONS)
    sigma_px: float = param(1.0, gt=1e-3, max=4096.0)
    wavelengths_nm: tuple[float, ...] = param((), min=spectra.WAVELENGTH_MIN_NM, max=spectra.WAVELENGTH_MAX_NM)
    vignetting: str = param("none", choices=VIGNETTING)
    glare_fraction: float = param(0.0, min=0.0, max=0.5)
    glare_model: str = param("power_law", choices=GLARE_MODELS)
    glare_exponent: float = param(2.0, gt=0.5, max=6.0)
    glare_core_radius_deg: float = param(0.05, gt=1e-4, max=10.0)
    glare_outer_radius_deg: float = param(30.0, gt=1e-4, max=89.0)
    field_samples: int = param(3, min=1, max=16)           # accuracy
    band_samples: int = param(3, min=1, max=32)            # accuracy
    pupil_rays: int = param(256, min=32, max=2048)         # accuracy
    support_energy: float = param(0.999, min=0.5, lt=1.0)  # accuracy
    guard_max_px: int = param(256, min=0, max=4096)        # accuracy: widest guard band rendered (px)

    def check(self) -> None:
        """Cross-key rule (ObjectiveParamError naming the key); the scene validator calls it."""
        if self.glare_outer_radius_deg < self.glare_core_radius_deg:
            raise ObjectiveParamError(
                f"objective.glare_outer_radius_deg = {self.glare_outer_radius_deg!r}: must be >= "
                f"glare_core_radius_deg = {self.glare_core_radius_deg!r}")

    @property
    def is_identity(self) -> bool:
        """True when the stage changes nothing (delta PSF, no vignetting, no glare)."""
        return self.psf == "delta" and self.vignetting == "none" and self.glare_fraction <= 0


@dataclass(frozen=True)
class ObjectiveParams(ObjectiveSpec):
    """The [objective] keys resolved for one camera: f_number from the layout, the image-plane
    pitch (m) and the sensor QE (a spectra.py source). Every field is checked against its bounds
    (ObjectiveParamError naming `objective.<key>`); the defaults are the DLP6500 + IMX253 set-up."""

    f_number: float = param(DEFAULT_F_NUMBER, min=0.5, max=1000.0)
    pixel_pitch_m: float = param(7.56e-6, gt=1e-7, max=1e-3)   # DMD mirror pitch (DLP6500)
    qe: str = param("file:spectra/imx253_mono_qe.csv")

    def __post_init__(self):
        object.__setattr__(self, "wavelengths_nm", tuple(float(w) for w in self.wavelengths_nm))
        hints = get_type_hints(type(self))
        where = Where(error=ObjectiveParamError)
        for f in dataclasses.fields(self):
            check_value(where, f"objective.{f.name}", getattr(self, f.name), hints[f.name], f.metadata)
        self.check()

    @classmethod
    def resolve(cls, spec: ObjectiveSpec, *, f_number: float, pixel_pitch_m: float, qe: str) -> "ObjectiveParams":
        """The spec's keys with what the camera knows (class docstring)."""
        keys = {f.name: getattr(spec, f.name) for f in dataclasses.fields(ObjectiveSpec)}
        return cls(**{**keys, "f_number": f_number, "pixel_pitch_m": pixel_pitch_m, "qe": qe})


# ---------------------------------------------------------------------------------------------
# Band: which wavelengths the objective is evaluated at, with the sensor's weights
# ---------------------------------------------------------------------------------------------

def sensor_band(params: ObjectiveParams) -> tuple[np.ndarray, np.ndarray]:
    """(wavelengths_nm, weights summing to 1) on spectra's 5 nm grid: the sensor response
    S = QE lambda / (h c) (`spectra.sensor_response_e_per_J`), i.e. the share of the signal of an
    equal-energy spectrum that each wavelength carries."""
    s = spectra.sensor_response_e_per_J(spectra.load_spectrum(params.qe, emissive=True))
    sel = s > 0
    return spectra.WAVELENGTHS_NM[sel], s[sel] / s[sel].sum()


def band(params: ObjectiveParams) -> tuple[np.ndarray, np.ndarray]:
    """Wavelength nodes (nm) and weights (sum 1) for the prescription PSF.

    `wavelengths_nm` given: those, weighted by the sensor response S there. Otherwise the sensor
    band split into `band_samples` parts of equal signal (quantiles of the cumulative S), each
    represented by its S-weighted mean wavelength with its share of the signal: a quadrature
    exact for anything linear in lambda within each part."""
    s_grid = spectra.sensor_response_e_per_J(spectra.load_spectrum(params.qe, emissive=True))
    wl_grid = spectra.WAVELENGTHS_NM
    if params.wavelengths_nm:
        wl = np.asarray(params.wavelengths_nm, float)
        w = np.interp(wl, wl_grid, s_grid)
        if not w.sum() > 0:
            raise ObjectiveParamError(f"objective.wavelengths_nm = {params.wavelengths_nm}: the sensor "
                                      f"({params.qe}) does not respond there")
        return wl, w / w.sum()
    fine = np.arange(wl_grid[0], wl_grid[-1] + 1e-9, 0.1)
    sf = np.interp(fine, wl_grid, s_grid)
    cum = np.cumsum(sf)
    part = np.minimum((params.band_samples * (cum - 0.5 * sf) / cum[-1]).astype(int), params.band_samples - 1)
    wl, w = [], []
    for k in range(params.band_samples):
        m = part == k
        if sf[m].sum() > 0:
            wl.append(float(np.sum(fine[m] * sf[m]) / sf[m].sum()))
            w.append(float(sf[m].sum()))
    w = np.asarray(w)
    return np.asarray(wl), w / w.sum()


# ---------------------------------------------------------------------------------------------
# Prescriptions (optiland)
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Prescription:
    """A lens design: `build()` returns an optiland Optic at its design scale; `field_deg` is the
    half field angle it was designed for (larger fields are refused)."""

    build: Callable
    field_deg: float
    source: str


def _double_gauss():
    from optiland.samples.objectives import DoubleGauss

    return DoubleGauss()


def _cooke_triplet():
    from optiland.samples.objectives import CookeTriplet

    return CookeTriplet()


def _perfect_lens():
    import optiland.backend as be
    from optiland import optic

    lens = optic.Optic()
    lens.surfaces.add(index=0, radius=be.inf, thickness=be.inf)
    lens.surfaces.add(index=1, surface_type="paraxial", f=100.0, thickness=100.0, is_stop=True)
    lens.surfaces.add(index=2)
    lens.set_aperture(aperture_type="imageFNO", value=5.0)
    lens.wavelengths.add(value=0.55, is_primary=True)
    return lens


def _register_prescription(name: str, build: Callable, field_deg: float, source: str) -> None:
    PRESCRIPTIONS.register(name, Prescription(build, field_deg, source), source=source)


_register_prescription("double_gauss", _double_gauss, 14.0,
                       "optiland.samples.objectives.DoubleGauss (optiland 0.6.3): f = 100 mm, f/5, half field "
                       "14 deg, six elements (N-SSK2, N-SK2, F5, N-SK16)")
_register_prescription("cooke_triplet", _cooke_triplet, 20.0,
                       "optiland.samples.objectives.CookeTriplet (optiland 0.6.3): EPD 10 mm, f ~ 50 mm, half "
                       "field 20 deg (SK16 / F2 / SK16)")
_register_prescription("perfect", _perfect_lens, 45.0,
                       "optiland paraxial (thin-lens phase) surface, stop at the lens: a diffraction-limited "
                       "Airy PSF on axis (Born & Wolf 8.5.2)")


def corner_radius_m(params: ObjectiveParams, image_shape) -> float:
    """Distance (m) from the optical axis (image centre) to the farthest pixel centre."""
    h, w = int(image_shape[0]), int(image_shape[1])
    return math.hypot((h - 1) / 2, (w - 1) / 2) * params.pixel_pitch_m


def check_field(params: ObjectiveParams, field_max_deg: float) -> None:
    """Refuse a field wider than the prescription was designed for (ObjectiveParamError)."""
    pres = PRESCRIPTIONS[params.prescription]
    if field_max_deg > pres.field_deg * (1 + 1e-9):
        raise ObjectiveParamError(
            f"objective.focal_length_m = {params.focal_length_m:g}: the image's corner is {field_max_deg:.2f} deg "
            f"off axis, beyond the {params.prescription!r} design field of {pres.field_deg:g} deg; use a "
            "longer focal length or a smaller image")


def _lens(params: ObjectiveParams, wl_nm: np.ndarray, field_max_deg: float):
    """The prescription at the band's wavelengths (primary: the one nearest the band's mean),
    scaled to `focal_length_m` at the primary wavelength, stopped to image-side `f_number`
    (paraxial F/# = f / EPD, optiland's 'imageFNO'), with angle fields 0 .. field_max_deg."""
    check_field(params, field_max_deg)
    lens = PRESCRIPTIONS[params.prescription].build()
    for i in reversed(range(len(lens.wavelengths))):
        lens.wavelengths.remove(i)
    primary = int(np.argmin(np.abs(wl_nm - np.mean(wl_nm))))
    for i, wl in enumerate(wl_nm):
        lens.wavelengths.add(value=float(wl) * 1e-3, is_primary=(i == primary))
    scale = params.focal_length_m * 1e3 / float(lens.paraxial.f2())
    lens.updater.scale_system(scale)
    for surf in lens.surfaces:                 # optiland's scale_system leaves thin-lens focal lengths
        model = getattr(surf, "interaction_model", None)
        if type(model).__name__ == "ThinLensInteractionModel":
            model.f = model.f * scale
    lens.update()
    f_mm = float(lens.paraxial.f2())
    if abs(f_mm / (params.focal_length_m * 1e3) - 1) > 1e-6:
        raise RuntimeError(f"scaling {params.prescription!r} gave f = {f_mm} mm, not {params.focal_length_m * 1e3} mm")
    lens.set_aperture(aperture_type="imageFNO", value=params.f_number)
    for i in reversed(range(len(lens.fields))):
        lens.fields.remove(i)
    lens.fields.set_type(field_type="angle")
    lens.fields.add(y=0.0)
    lens.fields.add(y=max(field_max_deg, 1e-6))
    return lens


# ---------------------------------------------------------------------------------------------
# PSF grid
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class PSFGrid:
    """Kernels at a grid of field nodes (pixel coordinates of the image they were built for:
    pixel centres at integers). kernels[j, i] is the unit-sum (2r+1)^2 kernel at
    (node_y_px[j], node_x_px[i]); truncation_error the largest energy any node's support leaves
    out (reported, not restored); note says what capped a support."""

    name: str
    node_y_px: np.ndarray
    node_x_px: np.ndarray
    kernels: np.ndarray
    truncation_error: float
    note: str = ""
    image_shape: tuple[int, int] | None = None      # the image it was built for (None: shift-invariant)

    @property
    def radius_px(self) -> int:
        return self.kernels.shape[-1] // 2


def node_positions_px(field_samples: int, size: int) -> np.ndarray:
    """2 field_samples - 1 equally spaced nodes from the first to the last pixel centre (one node
    at the centre for field_samples = 1)."""
    c = (size - 1) / 2
    if field_samples == 1 or size == 1:
        return np.array([c])
    return c + np.linspace(-1.0, 1.0, 2 * field_samples - 1) * c


def _pixel_integrated_radial(profile, radius_px: int, oversample: int) -> np.ndarray:
    """Integrate a radial profile f(r_px) over each pixel of a (2R+1)^2 kernel by the midpoint
    rule on oversample^2 sub-pixels; one quadrant is computed and mirrored (the profile is
    radial), in row strips (memory stays ~ 4 M samples)."""
    n = radius_px + 1
    sub = (np.arange(oversample) + 0.5) / oversample - 0.5
    cols = (np.arange(n)[:, None] + sub[None, :]).ravel()
    quad = np.empty((n, n))
    rows_per = max(1, (1 << 22) // (n * oversample * oversample))
    for i0 in range(0, n, rows_per):
        i1 = min(n, i0 + rows_per)
        rows = (np.arange(i0, i1)[:, None] + sub[None, :]).ravel()
        f = profile(np.hypot(rows[:, None], cols[None, :]))
        quad[i0:i1] = f.reshape(i1 - i0, oversample, n, oversample).mean(axis=(1, 3))
    full = np.empty((2 * radius_px + 1, 2 * radius_px + 1))
    full[radius_px:, radius_px:] = quad
    full[:radius_px, radius_px:] = quad[:0:-1]
    full[:, :radius_px] = full[:, :radius_px:-1]
    return full


def max_radius_px(image_shape) -> int:
    """Widest kernel radius that can matter for an image of this shape (relay.max_support_px):
    a tap farther than the image's extent moves light only off the image."""
    return max(int(image_shape[0]), int(image_shape[1])) - 1


def _single(name, kernel, trunc, note=""):
    k = kernel / kernel.sum()
    return PSFGrid(name, np.zeros(1), np.zeros(1), k[None, None], float(trunc), note)


def _gaussian_grid(params: ObjectiveParams, image_shape, cache_dir=None) -> PSFGrid:
    """Pixel-integrated Gaussian of `gaussian_sigma_px`, support holding `support_energy`
    (2-D Gaussian: energy beyond r is exp(-r^2 / 2 sigma^2))."""
    s = params.sigma_px
    want = max(1, math.ceil(s * math.sqrt(-2 * math.log(1 - params.support_energy))))
    r = min(want, max_radius_px(image_shape))
    k = _pixel_integrated_radial(lambda rr: np.exp(-0.5 * (rr / s) ** 2), r, 7)
    trunc = math.exp(-0.5 * ((r + 0.5) / s) ** 2)
    return _single("gaussian", k, trunc, _cap_note(want, r))


def _cap_note(want, r):
    return "" if r >= want else (f"support capped at {2 * r + 1} px by the image's extent (asked for "
                                 f"{2 * want + 1} px); the energy beyond is in the truncation error")


def airy_radius_px(params: ObjectiveParams) -> int:
    """Radius (px) whose Airy encircled-energy tail 2 / (pi x) leaves 1 - support_energy out."""
    wl, w = _airy_band(params)
    x = 2 / (math.pi * (1 - params.support_energy))
    return max(1, math.ceil(x * float(np.sum(w * wl)) * 1e-9 * params.f_number / (math.pi * params.pixel_pitch_m)))


def _airy_band(params):
    if params.wavelengths_nm:
        return band(params)
    return sensor_band(params)


def _airy_grid(params: ObjectiveParams, image_shape, cache_dir=None) -> PSFGrid:
    """Diffraction-limited incoherent PSF of a circular pupil, [2 J1(x) / x]^2 with
    x = pi r / (lambda N) (Born & Wolf, Principles of Optics, 7th ed., 8.5.2), each wavelength
    normalised to unit energy (peak ~ 1 / lambda^2) and weighted by the sensor band (the whole
    5 nm grid, or `wavelengths_nm`), integrated over the pixel (7 x 7 sub-pixels)."""
    from scipy.special import j0, j1

    wl, w = _airy_band(params)
    lam_m = wl * 1e-9
    want = airy_radius_px(params)
    r = min(want, max_radius_px(image_shape))
    r_grid = np.arange(0.0, (r + 1) * math.sqrt(2) + 1, 1 / 64)
    prof = np.zeros_like(r_grid)
    for lam, wi in zip(lam_m, w):
        x = math.pi * r_grid * params.pixel_pitch_m / (lam * params.f_number)
        with np.errstate(invalid="ignore", divide="ignore"):
            a = np.where(x > 1e-9, 2 * j1(x) / x, 1.0)
        prof += wi * a * a / (lam * lam)
    k = _pixel_integrated_radial(lambda rr: np.interp(rr, r_grid, prof), r, 7)
    x_edge = math.pi * (r + 0.5) * params.pixel_pitch_m / (float(np.sum(w * lam_m)) * params.f_number)
    trunc = float(j0(x_edge) ** 2 + j1(x_edge) ** 2)       # 1 - EE(x) of the Airy pattern
    return _single("airy", k, trunc, _cap_note(want, r))


def _fft_grid_size(params) -> int:
    """optiland's FFT grid, 2 x pupil_rays (its default): PSF samples lambda N / Q apart with
    Q = grid / (rays - 1) > 2, finer than the Nyquist spacing lambda N / 2 of the incoherent PSF
    (cut-off 1 / (lambda N)), so the band-limited interpolation in `_node_kernel` is exact
    whatever the pixel pitch."""
    return 2 * params.pupil_rays


def _prescription_samples(params: ObjectiveParams, radii_m: np.ndarray, field_max_deg: float):
    """optiland FFT PSFs at field angles atan(r / f) for each radius r and band wavelength.

    Returns a list over radii of dicts: 'sign' (+1 when the chief ray lands at +y), and per
    wavelength 'psf' (unit sum, centred on that wavelength's chief ray at index grid // 2; rows
    along +y, the radial direction), 'dy_um', 'dx_um' (sample spacings: lambda (rays - 1) /
    (grid dM), dM the spread of the image-space direction cosine M between the pupil's edges
    Py = +-1, likewise L for x: image-plane coordinates are conjugate to direction cosines,
    Goodman, Introduction to Fourier Optics, 3rd ed., 4.2), 'shift_um' (the chief ray's height
    minus the band-weighted mean: lateral colour)."""
    import optiland.backend as be
    from optiland.psf import FFTPSF

    wl_nm, w = band(params)
    lens = _lens(params, wl_nm, field_max_deg)
    f_deg = float(lens.fields.max_field)
    out = []
    for r in radii_m:
        theta = math.degrees(math.atan(r / params.focal_length_m))
        hy = min(theta / f_deg, 1.0)
        per = []
        ys = []
        for lam in wl_nm * 1e-3:
            rays = lens.trace_generic(Hx=0.0, Hy=hy, Px=be.array([0.0, 1.0, -1.0, 0.0, 0.0]),
                                      Py=be.array([0.0, 0.0, 0.0, 1.0, -1.0]), wavelength=float(lam))
            y_chief = float(be.to_numpy(rays.y)[0]) * 1e3                   # mm -> um
            ell, m = be.to_numpy(rays.L), be.to_numpy(rays.M)
            d_l, d_m = abs(ell[1] - ell[2]), abs(m[3] - m[4])
            grid = _fft_grid_size(params)
            p = FFTPSF(lens, field=(0.0, hy), wavelength=float(lam), num_rays=params.pupil_rays, grid_size=grid)
            psf = np.asarray(be.to_numpy(p.psf), float)
            if not (np.all(np.isfinite(psf)) and psf.sum() > 0):
                raise ObjectiveParamError(f"objective.prescription = {params.prescription!r}: optiland gave no "
                                          f"PSF at {theta:.2f} deg, {lam * 1e3:.0f} nm")
            per.append({"psf": psf / psf.sum(), "dx_um": lam * (params.pupil_rays - 1) / (grid * d_l),
                        "dy_um": lam * (params.pupil_rays - 1) / (grid * d_m)})
            ys.append(y_chief)
        ys = np.asarray(ys)
        y_mean = float(np.sum(w * ys))
        for d, y in zip(per, ys):
            d["shift_um"] = y - y_mean
        out.append({"sign": 1.0 if y_mean >= 0 else -1.0, "per_wl": per, "weights": w})
    return out


#: Band-limited upsampling of the pixel-integrated PSF before the spline lookup, and the spline
#: order: together 3e-5 of the peak against the exact Fourier sum (perfect lens, 7.56 um pixels).
_UPSAMPLE = 2
_SPLINE_ORDER = 5


def _node_kernel(sample, u, radius_px: int, pitch_um: float) -> np.ndarray:
    """Pixel energies of one node's PSF on a (2R+1)^2 kernel, the node's radial unit vector u =
    (ux, uy) in image coordinates (x along columns, y down the rows).

    Per wavelength: the optiland PSF (band-limited, periodic over its FFT field) is convolved with
    the pixel's square aperture in the Fourier domain (the square rotated into the PSF's frame:
    sinc(p nu.e_x) sinc(p nu.e_y)), which is the exact pixel integral of its band-limited
    interpolant; zero-padding the spectrum upsamples it by `_UPSAMPLE` and periodic quintic
    splines sample it at the rotated pixel centres."""
    from scipy.ndimage import map_coordinates

    ux, uy = u
    vx, vy = -uy, ux                                     # tangential unit vector
    a, b = np.mgrid[-radius_px:radius_px + 1, -radius_px:radius_px + 1].astype(float)
    dx_img, dy_img = b * pitch_um, a * pitch_um          # um, x along columns, y down the rows
    rho = dx_img * ux + dy_img * uy                      # radial (away from the axis)
    tau = dx_img * vx + dy_img * vy
    s = sample["sign"]
    out = np.zeros_like(rho)
    for d, wgt in zip(sample["per_wl"], sample["weights"]):
        psf = d["psf"]
        g = psf.shape[0]
        spec = d.get("_spec")
        if spec is None:
            spec = d["_spec"] = np.fft.rfft2(psf)
        nu_col = np.fft.rfftfreq(g, d=d["dx_um"])[None, :]      # cycles / um along the PSF's x (tangential)
        nu_row = np.fft.fftfreq(g, d=d["dy_um"])[:, None]       # along the PSF's y (radial)
        # the image's x and y axes in the PSF frame (x_psf = tau, y_psf = sign rho)
        box = (np.sinc(pitch_um * (nu_col * vx + nu_row * s * ux)) *
               np.sinc(pitch_um * (nu_col * vy + nu_row * s * uy)))
        up, h = _UPSAMPLE, g // 2
        big = np.zeros((up * g, up * g // 2 + 1), complex)
        big[:h, :h + 1] = (spec * box)[:h, :h + 1]
        big[-h:, :h + 1] = (spec * box)[-h:, :h + 1]
        energy = np.fft.irfft2(big, s=(up * g, up * g)) * (up * up * pitch_um * pitch_um / (d["dx_um"] * d["dy_um"]))
        rows = up * h + up * (s * rho - d["shift_um"]) / d["dy_um"]
        cols = up * h + up * tau / d["dx_um"]
        out += wgt * map_coordinates(energy, [rows, cols], order=_SPLINE_ORDER, mode="grid-wrap")
    return np.maximum(out, 0.0)


def _prescription_grid_build(params: ObjectiveParams, image_shape) -> PSFGrid:
    h, w = int(image_shape[0]), int(image_shape[1])
    pitch = params.pixel_pitch_m
    ys, xs = node_positions_px(params.field_samples, h), node_positions_px(params.field_samples, w)
    cy, cx = (h - 1) / 2, (w - 1) / 2
    # unique radii: one optiland PSF per field angle, rotated to each node's azimuth (a centred,
    # rotationally symmetric lens: the PSF at azimuth phi is the one at phi = 0 rotated)
    offs = [(float(y - cy), float(x - cx)) for y in ys for x in xs]
    radii_px = sorted({round(math.hypot(dy, dx), 9) for dy, dx in offs})
    field_max_deg = math.degrees(math.atan(corner_radius_m(params, image_shape) / params.focal_length_m))
    check_field(params, field_max_deg)
    with warnings.catch_warnings():      # numba's pedantic IR warnings from optiland's JIT kernels
        warnings.simplefilter("ignore")
        samples = _prescription_samples(params, np.asarray(radii_px) * pitch, field_max_deg)
    by_r = dict(zip(radii_px, samples))
    pitch_um = pitch * 1e6
    # evaluate on the largest square inside every wavelength's FFT field (periodic beyond)
    half_field_um = min(min(d["psf"].shape[0] * d["dx_um"], d["psf"].shape[0] * d["dy_um"]) / 2
                        for s in samples for d in s["per_wl"])
    r_eval = max(1, min(int(half_field_um / pitch_um - 0.5), max_radius_px(image_shape)))
    raw = np.empty((len(ys), len(xs), 2 * r_eval + 1, 2 * r_eval + 1))
    ny, nx = len(ys), len(xs)
    for j in range(ny // 2, ny):                     # one quadrant (axes included) ...
        for i in range(nx // 2, nx):
            dy, dx = ys[j] - cy, xs[i] - cx
            rr = math.hypot(dy, dx)
            u = (dx / rr, dy / rr) if rr > 0 else (0.0, 1.0)
            raw[j, i] = _node_kernel(by_r[round(rr, 9)], u, r_eval, pitch_um)
    for j in range(ny):                              # ... mirrored: the lens is symmetric about both axes
        for i in range(nx):
            jj, ii = max(j, ny - 1 - j), max(i, nx - 1 - i)
            k = raw[jj, ii]
            raw[j, i] = k[::-1 if jj != j else 1, ::-1 if ii != i else 1]
    # support: the smallest square holding support_energy at every node (of the FFT field's energy)
    ring = np.maximum(np.abs(np.arange(-r_eval, r_eval + 1))[:, None], np.abs(np.arange(-r_eval, r_eval + 1))[None, :])
    inside = np.stack([np.bincount(ring.ravel(), weights=k.ravel(), minlength=r_eval + 1)
                       for k in raw.reshape(-1, *raw.shape[2:])]).cumsum(axis=1)      # (nodes, r_eval + 1)
    ok = inside >= params.support_energy
    need = np.where(ok.any(axis=1), ok.argmax(axis=1), r_eval)
    r = int(max(1, need.max()))
    trunc_field = float(np.max(1.0 - inside[:, r]))
    # energy beyond the FFT field (aliased into it by the periodic FFT): the Airy asymptote
    # 1 - EE(x) ~ 2 / (pi x) at the field's half width, x = pi r / (lambda N)
    wl_nm, wts = band(params)
    x_half = math.pi * half_field_um / (float(np.sum(wts * wl_nm)) * 1e-3 * params.f_number)
    trunc_beyond = 2.0 / (math.pi * x_half)
    note = ""
    if not ok.any(axis=1).all():
        note = (f"support limited by optiland's FFT field ({2 * r_eval + 1} px): raise "
                f"objective.pupil_rays for support_energy {params.support_energy}")
    kern = raw[:, :, r_eval - r:r_eval + r + 1, r_eval - r:r_eval + r + 1]
    kern = kern / kern.sum(axis=(2, 3), keepdims=True)
    return PSFGrid(f"prescription:{params.prescription}", np.asarray(ys, float), np.asarray(xs, float),
                   np.ascontiguousarray(kern), trunc_field + trunc_beyond, note, (h, w))


def _cache_dir(cache_dir) -> Path:
    from poevp_optics.core.runtime import cache_dir as package_cache_dir

    return Path(cache_dir) if cache_dir is not None else package_cache_dir("objective")


def _optiland_version() -> str:
    from importlib.metadata import version

    return version("optiland")


def cache_key(kind: str, params: ObjectiveParams, image_shape, keys) -> str:
    """SHA-256 of what shapes a cached object: its kind, the listed parameters, the image shape,
    CACHE_VERSION, optiland's version and the QE table's content."""
    p = asdict(params)
    qe = spectra.load_spectrum(params.qe, emissive=True)
    blob = json.dumps({"kind": kind, "v": CACHE_VERSION, "optiland": _optiland_version(),
                       "shape": [int(image_shape[0]), int(image_shape[1])],
                       "params": {k: p[k] for k in keys},
                       "qe": hashlib.sha256(np.ascontiguousarray(qe).tobytes()).hexdigest()},
                      sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:32]


def _atomic_savez(path: Path, **arrays):
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


_GRID_KEYS = ("prescription", "f_number", "focal_length_m", "pixel_pitch_m", "wavelengths_nm", "qe",
              "field_samples", "band_samples", "pupil_rays", "support_energy")


def _prescription_grid(params: ObjectiveParams, image_shape, cache_dir=None) -> PSFGrid:
    """Field-dependent PSF of the `prescription` (optiland FFT PSFs, Kramer Harrison, optiland
    0.6.3, `optiland.psf.FFTPSF`), at `field_samples` nodes per quadrant axis and the band's
    wavelengths, resampled to the pixel grid; cached on disk."""
    path = _cache_dir(cache_dir) / f"psf-{cache_key('psf_grid', params, image_shape, _GRID_KEYS)}.npz"
    if path.is_file():
        try:
            with np.load(path) as z:
                return PSFGrid(str(z["name"]), z["node_y_px"], z["node_x_px"], z["kernels"],
                               float(z["truncation_error"]), str(z["note"]), tuple(int(v) for v in z["image_shape"]))
        except (OSError, KeyError, ValueError):
            path.unlink(missing_ok=True)              # unreadable: rebuild
    g = _prescription_grid_build(params, image_shape)
    _atomic_savez(path, name=np.array(g.name), node_y_px=g.node_y_px, node_x_px=g.node_x_px,
                  kernels=g.kernels, truncation_error=np.array(g.truncation_error), note=np.array(g.note),
                  image_shape=np.array(g.image_shape))
    return g


@dataclass(frozen=True)
class PSFEntry:
    """Registry entry: `build(params, image_shape, cache_dir) -> PSFGrid | None` and its source."""

    build: Callable
    source: str


OBJECTIVE_PSFS.register("delta", PSFEntry(lambda params, shape, cache_dir=None: None, "no blur"),
                        source="a perfect pinhole image: no blur (the stage applies only vignetting and glare)")
OBJECTIVE_PSFS.register("gaussian", PSFEntry(_gaussian_grid, "gaussian"),
                        source="pixel-integrated Gaussian of sigma_px (a generic blur)")
OBJECTIVE_PSFS.register("airy", PSFEntry(_airy_grid, "airy"),
                        source="diffraction-limited circular pupil at the layout's f-number, sensor band: "
                        "Born & Wolf, Principles of Optics, 7th ed., 8.5.2")
OBJECTIVE_PSFS.register("prescription", PSFEntry(_prescription_grid, "prescription"),
                        source="optiland 0.6.3 FFT PSFs of `prescription` over the field and band, bilinear "
                        "PSF interpolation (Nagy & O'Leary 1998)")


def psf_grid(params: ObjectiveParams, image_shape, *, cache_dir=None) -> PSFGrid | None:
    """The PSF grid for an image of `image_shape` (H, W), or None for `psf = "delta"`."""
    return OBJECTIVE_PSFS[params.psf].build(params, (int(image_shape[0]), int(image_shape[1])), cache_dir)


# ---------------------------------------------------------------------------------------------
# Vignetting (relative illumination)
# ---------------------------------------------------------------------------------------------

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
        lens = _lens(params, wl_nm, float(th_deg[-1]))
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
    path = _cache_dir(cache_dir) / f"ri-{cache_key('ri', params, image_shape, _RI_KEYS)}.npz"
    if path.is_file():
        with np.load(path) as z:
            th, ri = z["theta_rad"], z["ri"]
    else:
        th, ri = ri_profile(params, tmax)
        _atomic_savez(path, theta_rad=th, ri=ri)
    if tmax == 0:
        return np.ones(theta.shape)
    return CubicSpline(th, ri)(theta)


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


# ---------------------------------------------------------------------------------------------
# Veiling glare
# ---------------------------------------------------------------------------------------------

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

    k = _pixel_integrated_radial(prof, r, 3)
    m = min(r, int(math.ceil(4 * rc + 2)))
    k[r - m:r + m + 1, r - m:r + m + 1] = _pixel_integrated_radial(prof, m, 16)
    trunc = power_law_energy_beyond(r + 0.5, rc, ro, n)
    return GlareKernel("power_law", k / k.sum(), trunc, _cap_note(want, r))


GLARE_MODELS.register("power_law", _power_law_glare,
                      source="ISO 18844:2017 / ISO 9358:1994 style: flat core, r^-n halo (Talvala et al. 2007)")


def glare_kernel(params: ObjectiveParams, image_shape) -> GlareKernel | None:
    """The glare spread function for an image of `image_shape`, or None when glare_fraction = 0."""
    if params.glare_fraction <= 0:
        return None
    return GLARE_MODELS[params.glare_model](params, (int(image_shape[0]), int(image_shape[1])))


# ---------------------------------------------------------------------------------------------
# Convolutions (reflection beyond the border, as relay.convolve)
# ---------------------------------------------------------------------------------------------

def convolve_reflect(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Same-size linear convolution of an image continued by reflection over the kernel's reach
    (taps beyond the reflected image are dropped), as relay.convolve: one float64 FFT of the
    padded image's size (wrap-around lands only in the discarded border), so the cost is set by
    the image, not the kernel."""
    from scipy import fft as sfft

    h, w = image.shape
    c = kernel.shape[0] // 2
    ry, rx = min(c, h - 1), min(c, w - 1)
    k = kernel[c - ry:c + ry + 1, c - rx:c + rx + 1]
    padded = np.pad(np.asarray(image, np.float64), ((ry, ry), (rx, rx)), mode="symmetric")
    shape = (sfft.next_fast_len(padded.shape[0], real=True), sfft.next_fast_len(padded.shape[1], real=True))
    spec = sfft.rfft2(padded, s=shape)
    spec *= sfft.rfft2(k, s=shape)
    full = sfft.irfft2(spec, s=shape)
    return full[2 * ry:2 * ry + h, 2 * rx:2 * rx + w]


def _hat_weights(nodes: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """(len(nodes), len(coords)) piecewise-linear hat weights, clamped beyond the end nodes;
    they sum to 1 at every coordinate."""
    n = len(nodes)
    if n == 1:
        return np.ones((1, len(coords)))
    c = np.clip(coords, nodes[0], nodes[-1])
    idx = np.clip(np.searchsorted(nodes, c, side="right") - 1, 0, n - 2)
    t = (c - nodes[idx]) / (nodes[idx + 1] - nodes[idx])
    wts = np.zeros((n, len(coords)))
    cols = np.arange(len(coords))
    wts[idx, cols] = 1 - t
    wts[idx + 1, cols] += t
    return wts


def field_convolve(image: np.ndarray, grid: PSFGrid) -> np.ndarray:
    """Spatially varying convolution: sum over nodes of K_n * (w_n x), w_n bilinear hat weights
    over the node grid (clamped beyond it), on the image continued by reflection; float64.
    Each node convolves only the rows and columns where its weight is non-zero (overlap-add)."""
    from scipy.signal import fftconvolve

    img = np.asarray(image, np.float64)
    h, w = img.shape
    r = grid.radius_px
    ry, rx = min(r, h - 1), min(r, w - 1)
    kern = grid.kernels[:, :, r - ry:r + ry + 1, r - rx:r + rx + 1]
    padded = np.pad(img, ((ry, ry), (rx, rx)), mode="symmetric")
    wy = _hat_weights(np.asarray(grid.node_y_px, float), np.arange(-ry, h + ry, dtype=float))
    wx = _hat_weights(np.asarray(grid.node_x_px, float), np.arange(-rx, w + rx, dtype=float))
    acc = np.zeros((h + 4 * ry, w + 4 * rx))
    for j in range(wy.shape[0]):
        rows = np.flatnonzero(wy[j])
        if rows.size == 0:
            continue
        r0, r1 = rows[0], rows[-1] + 1
        for i in range(wx.shape[0]):
            cols = np.flatnonzero(wx[i])
            if cols.size == 0:
                continue
            c0, c1 = cols[0], cols[-1] + 1
            part = padded[r0:r1, c0:c1] * (wy[j, r0:r1, None] * wx[i, None, c0:c1])
            acc[r0:r1 + 2 * ry, c0:c1 + 2 * rx] += fftconvolve(part, kern[j, i], mode="full")
    return acc[2 * ry:2 * ry + h, 2 * rx:2 * rx + w]


# ---------------------------------------------------------------------------------------------
# The stage
# ---------------------------------------------------------------------------------------------

def is_identity(params: ObjectiveParams) -> bool:
    """True when the stage changes nothing (no PSF, no vignetting, no glare): skip it."""
    return params.psf == "delta" and params.vignetting == "none" and params.glare_fraction <= 0


def radius_px(params: ObjectiveParams, image_shape, *, cache_dir=None) -> int:
    """Guard band (px) the camera must render on each side of an image of `image_shape` (the
    sensor's footprint on the DMD) so that light from beyond it reaches it through the stage's
    widest kernel: max(PSF radius, glare radius). The prescription's kernels depend on the field
    the image spans, so the radius is iterated with the guard included (a fixed point within 3
    steps). Callers cap it as they cap the relay's (e.g. relay.guard_max_px)."""
    h, w = int(image_shape[0]), int(image_shape[1])
    g = glare_kernel(params, (h, w))
    rg = g.radius_px if g is not None else 0
    if params.psf == "delta":
        return rg
    r = 0
    for _ in range(3):
        grid = psf_grid(params, (h + 2 * r, w + 2 * r), cache_dir=cache_dir)
        rn = grid.radius_px
        if rn <= r:
            break
        r = rn
    return max(r, rg)


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


def radius_bound_px(params: ObjectiveParams, image_shape) -> int:
    """An upper bound of `radius_px` without building a kernel (the memory estimate): the glare
    halo's outer radius, and per PSF the Gaussian/Airy support radius or, for a prescription, 1.25 x
    the half width of optiland's FFT field lambda_max N (rays - 1) / 2 (the kernels are cut from
    it; 1.25 covers the off-axis widening of its sampling), all capped at the image's extent."""
    cap = max_radius_px(image_shape)
    r = int(math.ceil(glare_radii_px(params)[1] + 1)) if params.glare_fraction > 0 else 0
    if params.psf == "gaussian":
        r = max(r, math.ceil(params.sigma_px * math.sqrt(-2 * math.log(1 - params.support_energy))))
    elif params.psf == "airy":
        r = max(r, airy_radius_px(params))
    elif params.psf == "prescription":
        lam_max_m = float(np.max(band(params)[0])) * 1e-9
        r = max(r, math.ceil(1.25 * lam_max_m * params.f_number * (params.pupil_rays - 1) / 2 / params.pixel_pitch_m))
    return min(r, cap)


def memory_bytes(params: ObjectiveParams, image_shape, subframes: int) -> int:
    """Peak bytes of the stage on an image of `image_shape` (upper bound, from `radius_bound_px`):
    the PSF grid, the reflected and accumulated float64 images of `field_convolve`, one full-size
    FFT each for the PSF and the glare (relay.fft_bytes), the relative illumination, and the
    camera's float32 outputs of `subframes` images (kept for the frame's captures)."""
    from poevp_optics.camera.relay import fft_bytes

    h, w = int(image_shape[0]), int(image_shape[1])
    r = radius_bound_px(params, image_shape)
    nodes = (2 * params.field_samples - 1) ** 2 if params.psf == "prescription" else 1
    n = 2 * r + 1
    total = nodes * n * n * 8 + (h + 2 * r) * (w + 2 * r) * 8 + (h + 4 * r) * (w + 4 * r) * 8
    total += fft_bytes((h, w), n) * (2 if params.glare_fraction > 0 else 1) + 2 * h * w * 8
    return int(total + subframes * h * w * 4)


def apply(image: np.ndarray, params: ObjectiveParams, *, cache_dir=None, grid: PSFGrid | None = None,
          glare: GlareKernel | None = None, ri: np.ndarray | None = None) -> np.ndarray:
    """The image the objective forms on the DMD: (1 - g) B(V x) + g H * (V x) (module docstring).

    image: (H, W) float32 or float64, finite and >= 0 (sensor-weighted photon radiance of the
    pinhole render, guard band included; the optical axis at its centre). grid, glare, ri:
    precomputed `psf_grid`, `glare_kernel`, `relative_illumination` for this shape (built when
    None). Returns a new array of the input's float dtype (float64 inside)."""
    x = np.asarray(image)
    if x.ndim != 2:
        raise ValueError(f"objective.apply: image must be 2-D (H, W), got shape {x.shape}")
    if not np.issubdtype(x.dtype, np.floating):
        raise ValueError(f"objective.apply: image must be float32 or float64, got {x.dtype}")
    if not np.all(np.isfinite(x)) or (x.size and x.min() < 0):
        raise ValueError("objective.apply: image holds NaN, Inf or negative radiance")
    if is_identity(params):
        return x.copy()
    shape = x.shape
    v = x.astype(np.float64)
    if ri is None:
        ri = relative_illumination(params, shape, cache_dir=cache_dir)
    if ri is not None and ri.shape != shape:
        raise ValueError(f"objective.apply: relative illumination of shape {ri.shape} for an image of {shape}")
    if grid is None and params.psf != "delta":
        grid = psf_grid(params, shape, cache_dir=cache_dir)
    if grid is not None and grid.image_shape is not None and tuple(grid.image_shape) != shape:
        raise ValueError(f"objective.apply: PSF grid built for {grid.image_shape}, image is {shape}")
    if ri is not None:
        v = v * ri
    core = field_convolve(v, grid) if grid is not None else v
    g = params.glare_fraction
    if g > 0:
        if glare is None:
            glare = glare_kernel(params, shape)
        out = (1 - g) * core + g * convolve_reflect(v, glare.kernel)
    else:
        out = core
    return np.maximum(out, 0.0).astype(x.dtype)


def summary(params: ObjectiveParams, image_shape, *, cache_dir=None) -> dict:
    """What a report needs: PSF name, kernel radius, truncation, notes, band, glare radius and
    truncation, vignetting at the corner, and the skipped parts."""
    grid = psf_grid(params, image_shape, cache_dir=cache_dir)
    g = glare_kernel(params, image_shape)
    ri = relative_illumination(params, image_shape, cache_dir=cache_dir)
    wl, w = band(params)
    return {
        "psf": grid.name if grid is not None else "delta",
        "psf_radius_px": grid.radius_px if grid is not None else 0,
        "psf_nodes": [len(grid.node_y_px), len(grid.node_x_px)] if grid is not None else [0, 0],
        "psf_truncation_error": grid.truncation_error if grid is not None else 0.0,
        "psf_note": grid.note if grid is not None else "",
        "wavelengths_nm": [float(a) for a in wl], "wavelength_weights": [float(a) for a in w],
        "corner_field_deg": math.degrees(math.atan(corner_radius_m(params, image_shape) / params.focal_length_m)),
        "vignetting": params.vignetting,
        "relative_illumination_min": float(ri.min()) if ri is not None else 1.0,
        "glare_fraction": params.glare_fraction,
        "glare_radius_px": g.radius_px if g is not None else 0,
        "glare_truncation_error": g.truncation_error if g is not None else 0.0,
        "glare_note": g.note if g is not None else "",
    }
