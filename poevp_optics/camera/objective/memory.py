"""Memory estimate of the objective stage (apps/run/memory.py): an upper bound of its kernel radius
without building a kernel, and its peak bytes."""

from __future__ import annotations

import math

import numpy as np

from poevp_optics.camera.convolution import fft_bytes, field_tile_bytes
from poevp_optics.camera.glare import glare_radii_px
from poevp_optics.camera.kernels import max_radius_px
from poevp_optics.camera.objective.params import ObjectiveParams, band
from poevp_optics.camera.objective.psfs import airy_radius_px, node_positions_px

def radius_bound_px(params: ObjectiveParams, image_shape) -> int:
    """An upper bound of `radius_px` without building a kernel (the memory estimate): the glare
    halo's outer radius, and per PSF the Gaussian/Airy support radius or, for a prescription, 1.25 x
    the half width of optiland's FFT field lambda_max N (rays - 1) / 2 (the kernels are cut from
    it; 1.25 covers the off-axis widening of its sampling), all capped at the image's extent."""
    r = int(math.ceil(glare_radii_px(params)[1] + 1)) if params.glare_fraction > 0 else 0
    return min(max(r, psf_radius_bound_px(params, image_shape)), max_radius_px(image_shape))


def psf_radius_bound_px(params: ObjectiveParams, image_shape) -> int:
    """`radius_bound_px` of the PSF alone (no glare): the field-varying convolution's kernels."""
    r = 0
    if params.psf == "gaussian":
        r = math.ceil(params.sigma_px * math.sqrt(-2 * math.log(1 - params.support_energy)))
    elif params.psf == "airy":
        r = airy_radius_px(params)
    elif params.psf == "prescription":
        lam_max_m = float(np.max(band(params)[0])) * 1e-9
        r = math.ceil(1.25 * lam_max_m * params.f_number * (params.pupil_rays - 1) / 2 / params.pixel_pitch_m)
    return min(r, max_radius_px(image_shape))


def memory_bytes(params: ObjectiveParams, image_shape, subframes: int) -> int:
    """Peak bytes of the stage on an image of `image_shape` (upper bound, from `radius_bound_px`):
    the PSF grid, the reflected and accumulated float64 images of `field_convolve`, one full-size
    FFT each for the PSF and the glare (convolution.fft_bytes), the largest node tile of the
    field-varying convolution in flight (convolution.field_tile_bytes, at the PSF's own radius
    bound), the relative illumination, the camera's float32 outputs of `subframes` images (kept
    for the frame's captures), and with glare the frame's float64 glare veil (kept for its report
    record: camera.py `dmd_image`)."""
    h, w = int(image_shape[0]), int(image_shape[1])
    r = radius_bound_px(params, image_shape)
    samples = params.field_samples if params.psf == "prescription" else 1
    nodes = (2 * samples - 1) ** 2
    n = 2 * r + 1
    total = nodes * n * n * 8 + (h + 2 * r) * (w + 2 * r) * 8 + (h + 4 * r) * (w + 4 * r) * 8
    total += fft_bytes((h, w), n) * (2 if params.glare_fraction > 0 else 1) + 2 * h * w * 8
    if params.psf != "delta":
        total += field_tile_bytes((h, w), node_positions_px(samples, h), node_positions_px(samples, w),
                                  2 * psf_radius_bound_px(params, image_shape) + 1)
    veil = h * w * 8 if params.glare_fraction > 0 else 0
    return int(total + subframes * h * w * 4 + veil)
