"""Relay optics between DMD and sensor: PSF registry and energy-preserving convolution.

| psf       | kernel                                                    | reference |
|-----------|-----------------------------------------------------------|-----------|
| delta     | none: the stage is skipped and listed in skipped_stages   | - |
| gaussian  | pixel-integrated Gaussian, sigma_px                       | - |
| airy      | diffraction-limited incoherent PSF of a circular pupil, [2 J1(x)/x]^2 with x = pi r / (lambda N), N the working f-number at the sensor (layout.py), averaged over the sensor-weighted band S(lambda) and integrated over the pixel | Born & Wolf, Principles of Optics, 8.5.2 |
| measured  | an image (PNG/EXR, sensor-pixel sampling) from assets/ or the scene folder | the file |

Veiling glare (`glare_fraction` g > 0, any psf): the kernel becomes (1 - g) core + g halo, the
halo glare.py's `gaussian` entry of `GLARE_MODELS` with sigma `glare_sigma_px` (a stray-light
pedestal; lenses have veiling-glare indices of about 1-5 %, ISO 9358). With a delta core and g = 0
the stage is skipped.

Kernels are normalised to unit sum, so the convolution conserves flux. The camera renders a
guard band of the kernel's radius around the sensor's field (light from beyond the field's edge
spills in, as from the DMD's outer mirrors) and crops it after the blur; `convolve` continues
the image by reflection beyond what was rendered (convolution.py's `convolve_reflect`, shared
with the objective: direct up to 15 px, else a float64 FFT). Support (an accuracy setting) defaults to the radius that holds
99.9 % of the untruncated kernel's energy; the missing energy is reported as truncation error.

Wide kernels are capped at 2 max(H, W) - 1 px for an H x W image (`max_support_px`): a tap
farther from the centre than the image's extent only moves light from inside the image to
outside it, so a wider kernel changes nothing but the unit-sum normalisation; the energy beyond
the cap is part of the reported truncation and the PSF says it was capped (`note`). The FFT
works on the image padded by the kernel's reach, at most (2H - 1) x (2W - 1): its cost and
memory do not grow with the kernel, and kernels are built in row strips, so a sigma of 1000 px
costs what the image allows, not 24 GB.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from poevp_optics.camera.convolution import DIRECT_MAX_PX, convolve_reflect, fft_bytes, fft_shape, pad_to  # noqa: F401
from poevp_optics.camera.glare import GLARE_MODELS, GaussianHalo, gaussian_radius_px
from poevp_optics.camera.kernels import STRIP_SAMPLES, cap_note, capped_radius, max_radius_px, pixel_integrated  # noqa: F401
from poevp_optics.core.params import param
from poevp_optics.core.paths import ASSETS_DIR
from poevp_optics.core.registry import Registry



@dataclass(frozen=True)
class PSF:
    """A normalised kernel (odd square, float64), the energy its truncation dropped, and a note
    when its support was capped at the image's extent."""

    name: str
    kernel: np.ndarray
    truncation_error: float
    note: str = ""


def max_support_px(image_shape) -> int:
    """Widest kernel (odd, px) that can matter for an image of `image_shape` (H, W): a tap
    farther than the image's extent moves light only off the image."""
    return 2 * max_radius_px(image_shape) + 1


def _cap_radius(cap_px: int | None) -> int | None:
    return None if cap_px is None else (cap_px - 1) // 2


def gaussian_psf(sigma_px: float, support_px: int = 0, energy: float = 0.9995,
                 cap_px: int | None = None) -> PSF:
    """Pixel-integrated Gaussian (glare.py's `GaussianHalo`); cap_px: widest support allowed
    (`max_support_px`)."""
    g = GaussianHalo(sigma_px, support_px, energy).kernel(_cap_radius(cap_px))
    return PSF("gaussian", g.kernel, g.truncation_error, g.note)


def _airy_band(band_nm: np.ndarray, weights: np.ndarray):
    sel = weights > 1e-4 * weights.max()
    lam_m, w = band_nm[sel] * 1e-9, weights[sel] / weights[sel].sum()
    return lam_m, w, float(np.sum(w * lam_m))


def airy_radius_px(f_number: float, pixel_pitch_m: float, band_nm: np.ndarray, weights: np.ndarray,
                   support_px: int = 0, energy: float = 0.999) -> int:
    """Kernel radius (px) before any cap: support_px // 2, or the radius whose encircled-energy
    tail 2 / (pi x) leaves 1 - `energy` outside (at most 128 px)."""
    if support_px:
        return support_px // 2
    lam_mean = _airy_band(band_nm, weights)[2]
    x_needed = 2 / (math.pi * (1 - energy))
    r = int(math.ceil(x_needed * lam_mean * f_number / (math.pi * pixel_pitch_m)))
    return max(min(r, 128), 1)


def airy_psf(f_number: float, pixel_pitch_m: float, band_nm: np.ndarray, weights: np.ndarray,
             support_px: int = 0, energy: float = 0.999, cap_px: int | None = None) -> PSF:
    """Polychromatic Airy PSF in sensor pixels, weighted by `weights` over `band_nm`."""
    from scipy.special import j1

    lam_m, w, lam_mean = _airy_band(band_nm, weights)
    # encircled energy of the Airy pattern: 1 - J0(x)^2 - J1(x)^2 -> tail ~ 2 / (pi x)
    wanted = airy_radius_px(f_number, pixel_pitch_m, band_nm, weights, support_px, energy)
    r = capped_radius(wanted, _cap_radius(cap_px))

    # radial profile on a fine 1-D grid (1/64 px), interpolated onto the 2-D sub-pixel grid
    r_grid = np.arange(0, (r + 1) * math.sqrt(2) + 1, 1 / 64)
    prof = np.zeros_like(r_grid)
    for lam, wi in zip(lam_m, w):
        x = math.pi * r_grid * pixel_pitch_m / (lam * f_number)
        with np.errstate(invalid="ignore", divide="ignore"):
            a = np.where(x > 1e-9, 2 * j1(x) / x, 1.0)
        prof += wi * a * a / (lam * lam)              # peak intensity scales as 1/lambda^2

    def profile(r_px):
        return np.interp(r_px, r_grid, prof)

    k = pixel_integrated(profile, r)
    from scipy.special import j0

    x_edge = math.pi * (r + 0.5) * pixel_pitch_m / (lam_mean * f_number)
    trunc = float(j0(x_edge) ** 2 + j1(x_edge) ** 2)
    return PSF("airy", k / k.sum(), trunc, cap_note(wanted, r))


class PSFFileError(ValueError):
    """A measured PSF file that cannot be used (not an image, wrong shape, empty)."""


def read_psf_image(path: Path) -> np.ndarray:
    """A measured PSF image (PNG/EXR, first channel or grey mean) as float64; PSFFileError when
    it is not a readable, odd-sized square image with some energy."""
    from poevp_optics.core.io import read_exr, read_png

    try:
        if path.suffix.lower() == ".exr":
            chans, _ = read_exr(path)
            img = next(iter(chans.values())).astype(np.float64)
        else:
            img = read_png(path).astype(np.float64)
            if img.ndim == 3:
                img = img.mean(axis=2)
    except (OSError, RuntimeError, StopIteration, ValueError) as e:
        raise PSFFileError(f"{path}: not a readable PNG or EXR image ({type(e).__name__})") from None
    if img.ndim != 2 or img.shape[0] % 2 == 0 or img.shape[1] % 2 == 0 or img.shape[0] != img.shape[1]:
        raise PSFFileError(f"{path}: a measured PSF must be an odd-sized square image, got "
                           f"{'x'.join(map(str, img.shape))} px")
    if not np.all(np.isfinite(img)):
        raise PSFFileError(f"{path}: the PSF image holds NaN or Inf")
    img = np.maximum(img, 0)
    if not img.sum() > 0:
        raise PSFFileError(f"{path}: PSF image is empty")
    return img


def measured_psf(path: Path, support_px: int = 0, cap_px: int | None = None) -> PSF:
    img = read_psf_image(Path(path))
    total = img.sum()
    trunc = 0.0
    wanted = img.shape[0] // 2
    r = capped_radius(support_px // 2 if support_px else wanted, _cap_radius(cap_px))
    if r < wanted:
        c = img.shape[0] // 2
        cut = img[c - r:c + r + 1, c - r:c + r + 1]
        trunc = 1 - cut.sum() / total
        img = cut
    note = cap_note(support_px // 2 if support_px else wanted, r) if cap_px is not None else ""
    return PSF("measured", img / img.sum(), float(trunc), note)


def measured_psf_path(measured_file: str, base_dir: Path | None) -> Path:
    """Where `relay.measured_file` is read from: as given if absolute, else the scene's folder,
    then assets/ (the first that exists)."""
    p = Path(measured_file)
    cands = [p] if p.is_absolute() else [(base_dir or Path.cwd()) / p, ASSETS_DIR / p]
    return next((c for c in cands if c.is_file()), cands[-1])


@dataclass(frozen=True)
class PSFContext:
    """What a PSF model needs besides its own [relay] keys: the sensor sampling, the cone at the
    sensor (layout.py), the sensor-weighted band, where files are read, and the accuracy."""

    pixel_pitch_m: float
    f_number: float = math.nan
    band_nm: np.ndarray | None = None
    band_weights: np.ndarray | None = None
    base_dir: Path | None = None
    cap_px: int | None = None           # `max_support_px` of the image it will blur
    support_px: int = 0                 # Accuracy.psf_support_px (0: from the energy)
    support_energy: float = 0.999       # Accuracy.psf_support_energy


@dataclass(frozen=True)
class PSFModel:
    """A registry entry: build the kernel, or tell its radius (px, before any cap) without
    building it (for the memory estimate and the guard band)."""

    build: Callable[[RelaySpec, PSFContext], "PSF | None"]
    radius_px: Callable[[RelaySpec, PSFContext], int]


PSFS = Registry("relay PSF")
PSFS.register("delta", PSFModel(lambda s, c: None, lambda s, c: 0),
              source="an ideal relay: the stage is skipped and listed in skipped_stages")
PSFS.register("gaussian", PSFModel(
    lambda s, c: gaussian_psf(s.sigma_px, c.support_px, c.support_energy, c.cap_px),
    lambda s, c: gaussian_radius_px(s.sigma_px, c.support_px, c.support_energy)),
    source="pixel-integrated Gaussian of sigma_px (a defocus/aberration stand-in)")
PSFS.register("airy", PSFModel(
    lambda s, c: airy_psf(c.f_number, c.pixel_pitch_m, c.band_nm, c.band_weights, c.support_px,
                          c.support_energy, c.cap_px),
    lambda s, c: airy_radius_px(c.f_number, c.pixel_pitch_m, c.band_nm, c.band_weights, c.support_px,
                                c.support_energy)),
    source="Born & Wolf, Principles of Optics, 8.5.2: [2 J1(x)/x]^2, polychromatic, pixel-integrated")
PSFS.register("measured", PSFModel(
    lambda s, c: measured_psf(measured_psf_path(s.measured_file, c.base_dir), c.support_px, c.cap_px),
    lambda s, c: min(read_psf_image(measured_psf_path(s.measured_file, c.base_dir)).shape[0] // 2,
                     c.support_px // 2 if c.support_px else 1 << 30)),
    source="an image file (PNG/EXR) sampled at the sensor pixel: the measured relay")


@dataclass(frozen=True)
class RelaySpec:
    """[relay]: relay lens between DMD and sensor (module docstring)."""

    psf: str = param("delta", choices=PSFS)
    f_number: float = param(math.nan, gt=0, max=1000.0)  # relay aperture stop (image side); NaN: none
    magnification: float = param(math.nan, gt=0, max=1000.0)  # NaN: from the registration (layout.py)
    sigma_px: float = param(1.0, gt=0, max=1000.0)
    support_px: int = param(0, min=0, max=4097)         # accuracy: 0 = chosen from the PSF's energy
    support_energy: float = param(0.999, gt=0.5, lt=1.0)  # accuracy: energy held by the automatic support
    measured_file: str = param("")
    transmission: float = param(0.9, gt=0, max=1.0)
    glare_fraction: float = param(0.0, min=0, max=0.5)   # veiling glare: energy in a wide halo
    glare_sigma_px: float = param(40.0, gt=0, max=4096.0)
    crosstalk_tolerance: float = param(0.05, gt=0, max=10.0)  # flag 8: |blurred / own exposure - 1| above
    guard_max_px: int = param(256, min=0, max=4096)      # accuracy: widest guard band rendered (px)


def kernel_size_px(spec: RelaySpec, ctx: PSFContext) -> int:
    """Width (px) of the kernel `build_psf` would build (cap included), without building it
    (1 when the stage is skipped): for the memory estimate and the guard band."""
    radii = [PSFS[spec.psf].radius_px(spec, ctx)]
    if spec.glare_fraction > 0:
        radii.append(_glare_halo(spec, ctx).radius_px())
    r = max(radii)
    if r == 0:
        return 1
    return 2 * capped_radius(r, _cap_radius(ctx.cap_px)) + 1


def build_psf(spec: RelaySpec, ctx: PSFContext) -> PSF | None:
    """The relay's PSF from its registry entry, or None for `delta` without glare (the stage is
    skipped). Glare (`glare_fraction` g > 0): (1 - g) core + g Gaussian halo, unit sum."""
    core = PSFS[spec.psf].build(spec, ctx)
    g = spec.glare_fraction
    if g <= 0:
        return core
    halo = _glare_halo(spec, ctx).kernel(_cap_radius(ctx.cap_px))
    ck = core.kernel if core else np.ones((1, 1))
    n = max(ck.shape[0], halo.kernel.shape[0])
    k = (1 - g) * pad_to(ck, n) + g * pad_to(halo.kernel, n)
    trunc = (1 - g) * (core.truncation_error if core else 0.0) + g * halo.truncation_error
    note = "; ".join(x for x in ((core.note if core else ""), halo.note and f"glare halo {halo.note}") if x)
    return PSF(f"{core.name if core else 'delta'}+glare", k / k.sum(), trunc, note)


def _glare_halo(spec: RelaySpec, ctx: PSFContext):
    """The relay's glare halo: glare.py's `gaussian` entry, shaped by [relay] and the accuracy."""
    return GLARE_MODELS["gaussian"].from_keys(spec, ctx.support_px, ctx.support_energy)


def convolve(image: np.ndarray, psf: PSF) -> np.ndarray:
    """Linear convolution, same size, clipped at 0, in the image's float dtype (float64 for
    others). Beyond the image the field is continued by reflection (the DMD-plane image does not
    end at the sensor's edge: the camera renders a guard band of the PSF's radius and crops it,
    and reflection stands in for anything beyond the guard): convolution.convolve_reflect."""
    img = np.asarray(image)
    out = convolve_reflect(img, psf.kernel)
    return np.maximum(out, 0.0).astype(img.dtype if np.issubdtype(img.dtype, np.floating) else np.float64)
