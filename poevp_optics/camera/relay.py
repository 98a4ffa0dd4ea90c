"""Relay optics between DMD and sensor: PSF registry and energy-preserving convolution.

| psf       | kernel                                                    | reference |
|-----------|-----------------------------------------------------------|-----------|
| delta     | none: the stage is skipped and listed in skipped_stages   | - |
| gaussian  | pixel-integrated Gaussian, sigma_px                       | - |
| airy      | diffraction-limited incoherent PSF of a circular pupil, [2 J1(x)/x]^2 with x = pi r / (lambda N), N the working f-number at the sensor (layout.py), averaged over the sensor-weighted band S(lambda) and integrated over the pixel | Born & Wolf, Principles of Optics, 8.5.2 |
| measured  | an image (PNG/EXR, sensor-pixel sampling) from assets/ or the scene folder | the file |

Veiling glare (`glare_fraction` g > 0, any psf): the kernel becomes (1 - g) core + g halo, the
halo a Gaussian of `glare_sigma_px` (a stray-light pedestal; lenses have veiling-glare indices of
about 1-5 %, ISO 9358). With a delta core and g = 0 the stage is skipped.

Kernels are normalised to unit sum, so the convolution conserves flux. The camera renders a
guard band of the kernel's radius around the sensor's field (light from beyond the field's edge
spills in, as from the DMD's outer mirrors) and crops it after the blur; `convolve` continues
the image by reflection beyond what was rendered. Kernels up to 15 px wide are applied directly (OpenCV, float64), larger
ones by FFT in float64 (torch.fft) (a float32 FFT would put a noise floor at ~1e-7 of the peak into the dark
parts of a 200 dB scene). Support (an accuracy setting) defaults to the radius that holds
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

from poevp_optics.core.params import param
from poevp_optics.core.paths import ASSETS_DIR
from poevp_optics.core.registry import Registry

DIRECT_MAX_PX = 15
#: Fine samples evaluated at once while building a kernel (bounds its temporary memory).
STRIP_SAMPLES = 1 << 22


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
    return 2 * max(int(image_shape[0]), int(image_shape[1])) - 1


def _capped_radius(r: int, cap_px: int | None) -> int:
    return r if cap_px is None else max(min(r, (cap_px - 1) // 2), 0)


def _cap_note(wanted_r: int, r: int) -> str:
    if r >= wanted_r:
        return ""
    return (f"support capped at {2 * r + 1} px (asked for {2 * wanted_r + 1} px): wider taps only "
            "move light off the image; the energy beyond the cap is in the truncation error")


def _pixel_integrated(profile, radius_px: int, oversample: int = 7) -> np.ndarray:
    """Sample a radial profile f(r_px) on `oversample`^2 points per pixel and bin it; built in
    row strips of at most `STRIP_SAMPLES` fine samples (memory does not grow with n^2 o^2)."""
    n = 2 * radius_px + 1
    c = (np.arange(n * oversample) + 0.5) / oversample - (n / 2)
    out = np.empty((n, n))
    rows = max(1, STRIP_SAMPLES // (n * oversample * oversample))
    for i0 in range(0, n, rows):
        i1 = min(n, i0 + rows)
        x, y = np.meshgrid(c, c[i0 * oversample:i1 * oversample])
        fine = profile(np.hypot(x, y))
        out[i0:i1] = fine.reshape(i1 - i0, oversample, n, oversample).sum(axis=(1, 3))
    return out


def gaussian_radius_px(sigma_px: float, support_px: int = 0, energy: float = 0.9995) -> int:
    """Kernel radius (px) before any cap: support_px // 2, or the radius holding `energy`."""
    # 2-D Gaussian: energy outside radius r is exp(-r^2 / (2 sigma^2))
    if support_px:
        return support_px // 2
    return max(int(math.ceil(sigma_px * math.sqrt(-2 * math.log(1 - energy)))), 1)


def gaussian_psf(sigma_px: float, support_px: int = 0, energy: float = 0.9995,
                 cap_px: int | None = None) -> PSF:
    """Pixel-integrated Gaussian; cap_px: widest support allowed (`max_support_px`)."""
    wanted = gaussian_radius_px(sigma_px, support_px, energy)
    r = _capped_radius(wanted, cap_px)
    k = _pixel_integrated(lambda rr: np.exp(-0.5 * (rr / sigma_px) ** 2), r)
    # energy outside the square support, from the radial Gaussian tail (a lower bound)
    trunc = math.exp(-0.5 * ((r + 0.5) / sigma_px) ** 2)
    return PSF("gaussian", k / k.sum(), trunc, _cap_note(wanted, r))


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
    r = _capped_radius(wanted, cap_px)

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

    k = _pixel_integrated(profile, r)
    from scipy.special import j0

    x_edge = math.pi * (r + 0.5) * pixel_pitch_m / (lam_mean * f_number)
    trunc = float(j0(x_edge) ** 2 + j1(x_edge) ** 2)
    return PSF("airy", k / k.sum(), trunc, _cap_note(wanted, r))


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
    r = _capped_radius(support_px // 2 if support_px else wanted, cap_px)
    if r < wanted:
        c = img.shape[0] // 2
        cut = img[c - r:c + r + 1, c - r:c + r + 1]
        trunc = 1 - cut.sum() / total
        img = cut
    note = _cap_note(support_px // 2 if support_px else wanted, r) if cap_px is not None else ""
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
        radii.append(gaussian_radius_px(spec.glare_sigma_px, ctx.support_px, ctx.support_energy))
    r = max(radii)
    if r == 0:
        return 1
    return 2 * _capped_radius(r, ctx.cap_px) + 1


def build_psf(spec: RelaySpec, ctx: PSFContext) -> PSF | None:
    """The relay's PSF from its registry entry, or None for `delta` without glare (the stage is
    skipped). Glare (`glare_fraction` g > 0): (1 - g) core + g Gaussian halo, unit sum."""
    core = PSFS[spec.psf].build(spec, ctx)
    g = spec.glare_fraction
    if g <= 0:
        return core
    halo = gaussian_psf(spec.glare_sigma_px, ctx.support_px, ctx.support_energy, ctx.cap_px)
    ck = core.kernel if core else np.ones((1, 1))
    n = max(ck.shape[0], halo.kernel.shape[0])
    k = (1 - g) * _pad_to(ck, n) + g * _pad_to(halo.kernel, n)
    trunc = (1 - g) * (core.truncation_error if core else 0.0) + g * halo.truncation_error
    note = "; ".join(x for x in ((core.note if core else ""), halo.note and f"glare halo {halo.note}") if x)
    return PSF(f"{core.name if core else 'delta'}+glare", k / k.sum(), trunc, note)


def _pad_to(k: np.ndarray, n: int) -> np.ndarray:
    p = (n - k.shape[0]) // 2
    return np.pad(k, p) if p else k


def fft_shape(image_shape, kernel_px: int) -> tuple[int, int]:
    """FFT size for a same-size convolution of an image, continued by reflection over the
    kernel's reach on each side, with an odd kernel: the padded image (no wrap-around reaches the
    kept part), the reach limited to the image extent, rounded up to a fast FFT length. At most
    about (3H - 2) x (3W - 2), whatever the kernel."""
    from scipy.fft import next_fast_len

    r = kernel_px // 2
    h, w = int(image_shape[0]), int(image_shape[1])
    return (next_fast_len(h + 2 * min(r, h - 1), real=True), next_fast_len(w + 2 * min(r, w - 1), real=True))


def fft_bytes(image_shape, kernel_px: int) -> int:
    """Peak bytes of `convolve`'s FFT path: padded image and kernel (float64), their spectra and
    product (complex128), the inverse transform and the float64 copies of image and kernel."""
    fh, fw = fft_shape(image_shape, kernel_px)
    spectrum = fh * (fw // 2 + 1) * 16
    return 3 * spectrum + 2 * fh * fw * 8 + 2 * int(image_shape[0]) * int(image_shape[1]) * 8


def convolve(image: np.ndarray, psf: PSF) -> np.ndarray:
    """Linear convolution, same size. Beyond the image the field is continued by reflection
    (the DMD-plane image does not end at the sensor's edge: the camera renders a guard band of
    the PSF's radius and crops it, and reflection stands in for anything beyond the guard).

    Kernels up to DIRECT_MAX_PX wide: direct (OpenCV); wider: FFT (`fft_shape`), exact in
    float64 and with a cost set by the image, not the kernel."""
    import cv2
    import torch

    k = psf.kernel
    img = np.asarray(image)
    if k.shape[0] <= DIRECT_MAX_PX:
        # OpenCV correlates: flip the kernel for a convolution
        out = cv2.filter2D(img.astype(np.float64), -1, np.ascontiguousarray(k[::-1, ::-1]),
                           borderType=cv2.BORDER_REFLECT)
    else:
        h, w_ = img.shape
        c = k.shape[0] // 2
        ry, rx = min(c, h - 1), min(c, w_ - 1)        # taps reaching past the reflected image are dropped
        k = k[c - ry:c + ry + 1, c - rx:c + rx + 1]
        padded = np.pad(img.astype(np.float64), ((ry, ry), (rx, rx)), mode="symmetric")
        fh, fw = fft_shape(img.shape, 2 * c + 1)
        fi = torch.fft.rfft2(torch.from_numpy(padded), s=(fh, fw))
        fi *= torch.fft.rfft2(torch.from_numpy(np.ascontiguousarray(k)), s=(fh, fw))
        full = torch.fft.irfft2(fi, s=(fh, fw)).numpy()
        out = full[2 * ry:2 * ry + h, 2 * rx:2 * rx + w_]
    return np.maximum(out, 0.0).astype(image.dtype if np.issubdtype(np.asarray(image).dtype, np.floating) else np.float64)
