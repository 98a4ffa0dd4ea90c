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
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .scene import RelaySpec

DIRECT_MAX_PX = 15


@dataclass(frozen=True)
class PSF:
    """A normalised kernel (odd square, float64) and the energy its truncation dropped."""

    name: str
    kernel: np.ndarray
    truncation_error: float


def _pixel_integrated(profile, radius_px: int, oversample: int = 7) -> np.ndarray:
    """Sample a radial profile f(r_px) on `oversample`^2 points per pixel and bin it."""
    n = 2 * radius_px + 1
    c = (np.arange(n * oversample) + 0.5) / oversample - (n / 2)
    x, y = np.meshgrid(c, c)
    fine = profile(np.hypot(x, y))
    return fine.reshape(n, oversample, n, oversample).sum(axis=(1, 3))


def gaussian_psf(sigma_px: float, support_px: int = 0, energy: float = 0.9995) -> PSF:
    # 2-D Gaussian: energy outside radius r is exp(-r^2 / (2 sigma^2))
    r = support_px // 2 if support_px else max(int(math.ceil(sigma_px * math.sqrt(-2 * math.log(1 - energy)))), 1)
    k = _pixel_integrated(lambda rr: np.exp(-0.5 * (rr / sigma_px) ** 2), r)
    # energy outside the square support, from the radial Gaussian tail (a lower bound)
    trunc = math.exp(-0.5 * ((r + 0.5) / sigma_px) ** 2)
    return PSF("gaussian", k / k.sum(), trunc)


def airy_psf(f_number: float, pixel_pitch_m: float, band_nm: np.ndarray, weights: np.ndarray,
             support_px: int = 0, energy: float = 0.999) -> PSF:
    """Polychromatic Airy PSF in sensor pixels, weighted by `weights` over `band_nm`."""
    from scipy.special import j1

    sel = weights > 1e-4 * weights.max()
    lam_m, w = band_nm[sel] * 1e-9, weights[sel] / weights[sel].sum()
    lam_mean = float(np.sum(w * lam_m))
    # encircled energy of the Airy pattern: 1 - J0(x)^2 - J1(x)^2 -> tail ~ 2 / (pi x)
    if support_px:
        r = support_px // 2
    else:
        x_needed = 2 / (math.pi * (1 - energy))            # encircled-energy tail 2 / (pi x)
        r = int(math.ceil(x_needed * lam_mean * f_number / (math.pi * pixel_pitch_m)))
        r = max(min(r, 128), 1)

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
    return PSF("airy", k / k.sum(), trunc)


def measured_psf(path: Path, support_px: int = 0) -> PSF:
    from .io import read_exr, read_png

    if path.suffix.lower() == ".exr":
        chans, _ = read_exr(path)
        img = next(iter(chans.values())).astype(np.float64)
    else:
        img = read_png(path).astype(np.float64)
        if img.ndim == 3:
            img = img.mean(axis=2)
    if img.ndim != 2 or img.shape[0] % 2 == 0 or img.shape[1] % 2 == 0 or img.shape[0] != img.shape[1]:
        raise ValueError(f"{path}: a measured PSF must be an odd-sized square image, got {img.shape}")
    img = np.maximum(img, 0)
    total = img.sum()
    if not total > 0:
        raise ValueError(f"{path}: PSF image is empty")
    trunc = 0.0
    if support_px and support_px < img.shape[0]:
        c, r = img.shape[0] // 2, support_px // 2
        cut = img[c - r:c + r + 1, c - r:c + r + 1]
        trunc = 1 - cut.sum() / total
        img = cut
    return PSF("measured", img / img.sum(), float(trunc))


def build_psf(spec: RelaySpec, *, pixel_pitch_m: float, f_number: float, band_nm=None,
              band_weights=None, base_dir: Path | None = None) -> PSF | None:
    """The scene's PSF, or None for `delta` without glare (the stage is skipped). `f_number`:
    the working f-number of the cone at the sensor (layout.OpticalLayout.sensor_f_number)."""
    core = _core_psf(spec, pixel_pitch_m, f_number, band_nm, band_weights, base_dir)
    g = spec.glare_fraction
    if g <= 0:
        return core
    halo = gaussian_psf(spec.glare_sigma_px, spec.support_px, spec.support_energy)
    ck = core.kernel if core else np.ones((1, 1))
    n = max(ck.shape[0], halo.kernel.shape[0])
    k = (1 - g) * _pad_to(ck, n) + g * _pad_to(halo.kernel, n)
    trunc = (1 - g) * (core.truncation_error if core else 0.0) + g * halo.truncation_error
    return PSF(f"{core.name if core else 'delta'}+glare", k / k.sum(), trunc)


def _pad_to(k: np.ndarray, n: int) -> np.ndarray:
    p = (n - k.shape[0]) // 2
    return np.pad(k, p) if p else k


def _core_psf(spec: RelaySpec, pixel_pitch_m, f_number, band_nm, band_weights, base_dir) -> PSF | None:
    if spec.psf == "delta":
        return None
    if spec.psf == "gaussian":
        return gaussian_psf(spec.sigma_px, spec.support_px, spec.support_energy)
    if spec.psf == "airy":
        return airy_psf(f_number, pixel_pitch_m, band_nm, band_weights, spec.support_px,
                        spec.support_energy)
    from .spectra import ASSETS_DIR

    p = Path(spec.measured_file)
    cands = [p] if p.is_absolute() else [(base_dir or Path.cwd()) / p, ASSETS_DIR / p]
    path = next((c for c in cands if c.is_file()), cands[-1])
    return measured_psf(path, spec.support_px)


def convolve(image: np.ndarray, psf: PSF) -> np.ndarray:
    """Linear convolution, same size. Beyond the image the field is continued by reflection
    (the DMD-plane image does not end at the sensor's edge: the camera renders a guard band of
    the PSF's radius and crops it, and reflection stands in for anything beyond the guard)."""
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
        kh = k.shape[0]
        r = kh // 2
        padded = np.pad(img.astype(np.float64), r, mode="symmetric")
        ph, pw = padded.shape
        fh, fw = ph + kh - 1, pw + kh - 1
        fi = torch.fft.rfft2(torch.from_numpy(padded), s=(fh, fw))
        fk = torch.fft.rfft2(torch.from_numpy(k), s=(fh, fw))
        full = torch.fft.irfft2(fi * fk, s=(fh, fw)).numpy()
        out = full[2 * r:2 * r + h, 2 * r:2 * r + w_]
    return np.maximum(out, 0.0).astype(image.dtype if np.issubdtype(np.asarray(image).dtype, np.floating) else np.float64)
