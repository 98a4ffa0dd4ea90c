"""Convolutions of the objective stage, the image continued by reflection beyond its border (as
relay.convolve): a shift-invariant FFT convolution and the field-varying one over a PSF grid."""

from __future__ import annotations

import numpy as np

from poevp_optics.camera.objective.psfs import PSFGrid
from poevp_optics.core import runtime

#: Kernel spectra of convolve_reflect by (kernel identity, cropped size, FFT shape): the glare
#: kernel is the same for every frame of a run, so its FFT is taken once per image size.
_KERNEL_SPECTRA: dict = {}

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
    workers = runtime.fft_workers()
    key = (id(kernel), k.shape, shape)
    hit = _KERNEL_SPECTRA.get(key)
    if hit is None or hit[0] is not kernel:
        if len(_KERNEL_SPECTRA) >= 8:
            _KERNEL_SPECTRA.pop(next(iter(_KERNEL_SPECTRA)))
        hit = _KERNEL_SPECTRA[key] = (kernel, sfft.rfft2(k, s=shape, workers=workers))   # holds the kernel
    spec = sfft.rfft2(padded, s=shape, workers=workers)
    spec *= hit[1]
    full = sfft.irfft2(spec, s=shape, workers=workers)
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
    from scipy import fft as sfft
    from scipy.signal import fftconvolve

    with sfft.set_workers(runtime.fft_workers()):
        return _field_convolve(image, grid, fftconvolve)


def _field_convolve(image: np.ndarray, grid: PSFGrid, fftconvolve) -> np.ndarray:
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
