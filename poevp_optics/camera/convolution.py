"""The camera's convolutions (objective and relay): same-size linear convolution of an image
continued by reflection beyond its border, shift-invariant (`convolve_reflect`) or field-varying
over a grid of PSFs (`field_convolve`), in float64.

Borders: the image is continued by mirror reflection (`np.pad` mode "symmetric", OpenCV
BORDER_REFLECT: ...cba|abc...) over the kernel's reach, the reach limited to the image's extent
(taps beyond the reflected image are dropped); the camera renders a guard band of the kernel's
radius and crops it afterwards, so reflection stands in only for what lies beyond the guard.

Methods (`convolve_reflect`):
- kernels up to `DIRECT_MAX_PX` wide: direct (OpenCV filter2D, float64), faster than an FFT of
  the whole image for small kernels (1080 x 1920, 7 px: 9 ms vs 42 ms on 2 shared cores);
- wider and uneven, up to `BLOCK_DFT_MAX_PX`, reaching no further than the image: OpenCV
  filter2D again, which takes such kernels by a block DFT (float64): the relay's 29 px PSF on
  1128 x 1968 mirrors 0.066 CPU s a call against 0.148 by the padded FFT below, to 7e-16 of the
  peak apart, the same for any thread count;
- wider: one real FFT (scipy.fft, float64) of the padded image at `fft_shape` (no wrap-around
  reaches the kept part), so the cost is set by the image, not the kernel. The kernel's spectrum
  is cached by (kernel identity, cropped size, FFT shape): the PSF and the glare kernel are the
  same for every frame of a run, so each is transformed once per image size. A float32 FFT would
  put a noise floor at ~1e-7 of the peak into the dark parts of a 200 dB scene;
- wider and even (equal to its mirror image in each axis, as the radial glare halos are): one
  DCT-II of the image itself (`_dct_multiplier`), the same sum without the padding. The
  objective's 3225 px glare halo on 1128 x 1968 mirrors: 0.57 s by the padded FFT (3382 x 5192),
  0.064 s by the DCT, the two equal to 1.6e-15 of each pixel.
One rule and one FFT backend serve both stages. Measured when they were merged (issue 30): the
relay's wide kernels had gone through torch.fft, and scipy.fft moves highbeam_plate's 29 px Airy
blur by at most 24 on a peak of 4.3e16 (1.5e-15 of the peak, 1.6e-11 of the dimmest pixel) with
every regression hash unchanged; the objective had taken kernels <= 15 px by FFT too, and the
direct path moves them by < 1e-15 of the peak (no regression case has an objective).

Field-varying (`field_convolve`): sum over nodes n of K_n * (w_n x), w_n the bilinear hat
weights of node n (a partition of unity; each source point's PSF is the bilinear interpolation
of its four neighbouring node PSFs, and a constant grid gives the plain convolution: Nagy &
O'Leary, SIAM J. Sci. Comput. 19(4), 1998), each node one OpenCV filter2D (float64) over the
tile its weight covers, the tiles overlap-added.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from poevp_optics.core import runtime
from poevp_optics.core.memo import kept

#: Widest kernel (px) applied directly; wider ones by FFT.
DIRECT_MAX_PX = 15

#: Widest uneven kernel (px) OpenCV's filter2D takes (its block DFT) where the kernel's reach
#: stays within the image; wider ones, and those reaching beyond it, by the padded FFT.
BLOCK_DFT_MAX_PX = 65

#: Kernel spectra by (kernel identity, cropped size, FFT shape) -> (kernel, spectrum); the entry
#: holds the kernel, so its id cannot be reused while the entry lives. At most 8 entries.
_KERNEL_SPECTRA: dict = {}
_CACHE_ENTRIES = 8


class KernelGrid(Protocol):
    """What `field_convolve` reads of a PSF grid (objective.psfs.PSFGrid): kernels[j, i], the
    unit-sum (2r+1)^2 kernel at (node_y_px[j], node_x_px[i]) in pixel coordinates."""

    node_y_px: np.ndarray
    node_x_px: np.ndarray
    kernels: np.ndarray

    @property
    def radius_px(self) -> int: ...


def reach_px(image_shape, kernel_px: int) -> tuple[int, int]:
    """(rows, columns) the image is continued by reflection on each side for an odd kernel of
    `kernel_px`: its radius, limited to the image's extent (H - 1, W - 1)."""
    r = int(kernel_px) // 2
    return min(r, int(image_shape[0]) - 1), min(r, int(image_shape[1]) - 1)


def fft_shape(image_shape, kernel_px: int) -> tuple[int, int]:
    """FFT size for a same-size convolution of an image continued by reflection over the
    kernel's reach (`reach_px`) with an odd kernel: the padded image (no wrap-around reaches the
    kept part), rounded up to a fast real-FFT length. At most about (3H - 2) x (3W - 2)."""
    from scipy.fft import next_fast_len

    ry, rx = reach_px(image_shape, kernel_px)
    h, w = int(image_shape[0]), int(image_shape[1])
    return next_fast_len(h + 2 * ry, real=True), next_fast_len(w + 2 * rx, real=True)


def fft_bytes(image_shape, kernel_px: int) -> int:
    """Peak bytes of `convolve_reflect`'s FFT path: padded image and kernel (float64), their
    spectra and product (complex128, the kernel's kept in the cache), the inverse transform and
    the float64 copies of image and kernel."""
    fh, fw = fft_shape(image_shape, kernel_px)
    spectrum = fh * (fw // 2 + 1) * 16
    return 3 * spectrum + 2 * fh * fw * 8 + 2 * int(image_shape[0]) * int(image_shape[1]) * 8


def pad_to(kernel: np.ndarray, n: int) -> np.ndarray:
    """An odd square kernel zero-padded to n x n (n odd, not smaller), centre kept."""
    p = (n - kernel.shape[0]) // 2
    return np.pad(kernel, p) if p else kernel


def _kernel_spectrum(kernel: np.ndarray, k: np.ndarray, shape, workers: int) -> np.ndarray:
    from scipy import fft as sfft

    return kept(_KERNEL_SPECTRA, _CACHE_ENTRIES, (id(kernel), k.shape, shape), kernel,
                 lambda: sfft.rfft2(k, s=shape, workers=workers))


def is_even(k: np.ndarray) -> bool:
    """True when `k` equals its own mirror image in each axis exactly (k[-m, n] = k[m, -n] =
    k[m, n]), as the radial glare halos are."""
    return bool(np.array_equal(k, k[::-1]) and np.array_equal(k, k[:, ::-1]))


def _dct_multiplier(kernel: np.ndarray, k: np.ndarray, image_shape, workers: int) -> np.ndarray | None:
    """The DCT-II multiplier of the cropped kernel `k` on an H x W image (cached like the
    spectra), or None where `k` is not even (the FFT path then). For an even kernel reaching
    at most H - 1, W - 1 (`reach_px`), convolution with the image continued by reflection is
    circular convolution of its 2H x 2W mirror-periodic extension, so the DCT-II diagonalises it:
    DCT(out)[u, v] = K[u, v] DCT(image)[u, v], K the real DFT of `k` wrapped onto 2H x 2W,
    taken at bins u < H, v < W (Martucci, IEEE Trans. Signal Process. 42(5), 1994: symmetric
    convolution)."""
    from scipy import fft as sfft

    def build():
        if not is_even(k):
            return None
        h, w = int(image_shape[0]), int(image_shape[1])
        ry, rx = k.shape[0] // 2, k.shape[1] // 2
        wrapped = np.zeros((2 * h, 2 * w))
        wrapped[np.ix_(np.arange(-ry, ry + 1) % (2 * h), np.arange(-rx, rx + 1) % (2 * w))] = k
        return np.ascontiguousarray(sfft.rfft2(wrapped, workers=workers).real[:h, :w])

    return kept(_KERNEL_SPECTRA, _CACHE_ENTRIES, (id(kernel), k.shape, ("dct", *image_shape)), kernel, build)


def convolve_reflect(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Same-size linear convolution (float64) of `image` (H, W) with an odd square `kernel`,
    the image continued by reflection over the kernel's reach (module docstring): direct up to
    `DIRECT_MAX_PX`, else by DCT for an even kernel and by FFT for any other, the kernel's
    multiplier or spectrum cached. No clipping, no normalisation."""
    img = np.asarray(image, np.float64)
    if kernel.shape[0] <= DIRECT_MAX_PX:
        return _filter2d(img, kernel)
    from scipy import fft as sfft

    h, w = img.shape
    c = kernel.shape[0] // 2
    ry, rx = reach_px(img.shape, kernel.shape[0])
    k = kernel[c - ry:c + ry + 1, c - rx:c + rx + 1]
    workers = runtime.fft_workers()
    mult = _dct_multiplier(kernel, k, img.shape, workers)
    if mult is not None:                    # an even kernel: DCT-II, no padding (module docstring)
        spec = sfft.dctn(img, type=2, workers=workers)
        spec *= mult
        return sfft.idctn(spec, type=2, workers=workers, overwrite_x=True)
    if kernel.shape[0] <= BLOCK_DFT_MAX_PX and (ry, rx) == (c, c):
        return _filter2d(img, kernel)
    shape = fft_shape(img.shape, kernel.shape[0])
    spec = sfft.rfft2(reflect_into(img, ry, rx, shape), workers=workers)
    spec *= _kernel_spectrum(kernel, k, shape, workers)
    full = sfft.irfft2(spec, s=shape, workers=workers)
    return full[2 * ry:2 * ry + h, 2 * rx:2 * rx + w]


def _filter2d(img: np.ndarray, kernel: np.ndarray, border: str = "reflect") -> np.ndarray:
    """Same-size convolution by OpenCV's filter2D (float64), the image continued by reflection
    (border "reflect", ...cba|abc...: the module's reflection while the kernel's radius stays
    within the image) or by zeros ("zero"); OpenCV correlates, so the kernel is flipped."""
    import cv2

    flag = {"reflect": cv2.BORDER_REFLECT, "zero": cv2.BORDER_CONSTANT}[border]
    return cv2.filter2D(img, -1, np.ascontiguousarray(kernel[::-1, ::-1]), borderType=flag)


def reflect_into(img: np.ndarray, ry: int, rx: int, shape) -> np.ndarray:
    """`np.pad(img, ((ry, ry), (rx, rx)), mode="symmetric")` written into the top-left corner of
    a zero array of `shape` (the FFT's input: one copy, where padding and then zero-filling to the
    FFT size made two of the largest array of a frame). ry < H and rx < W (`reach_px`), so one
    mirror image of each edge covers the reach."""
    h, w = img.shape
    if not (0 <= ry < h and 0 <= rx < w):
        raise ValueError(f"reflect_into: reach ({ry}, {rx}) beyond an image of {h} x {w}")
    out = np.zeros(shape, np.float64)
    out[ry:ry + h, rx:rx + w] = img
    out[:ry, rx:rx + w] = img[ry - 1::-1][:ry]                       # rows ry-1 .. 0
    out[ry + h:2 * ry + h, rx:rx + w] = img[h - 1:h - ry - 1:-1]     # rows h-1 .. h-ry
    band = out[:2 * ry + h]
    band[:, :rx] = band[:, 2 * rx - 1:rx - 1:-1]
    band[:, rx + w:2 * rx + w] = band[:, rx + w - 1:w - 1:-1]
    return out


def hat_weights(nodes: np.ndarray, coords: np.ndarray) -> np.ndarray:
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


def field_convolve(image: np.ndarray, grid: KernelGrid) -> np.ndarray:
    """Spatially varying convolution (float64): sum over nodes of K_n * (w_n x), w_n bilinear
    hat weights over the node grid (clamped beyond it), on the image continued by reflection.
    Each node convolves only the rows and columns where its weight is non-zero (overlap-add),
    its tile zero-padded by the kernel's radius and filtered by OpenCV (`filter2D`, float64, which
    takes all but the smallest kernels by a block DFT), the full linear convolution of the tile. On the
    objective's 33 px kernels over 1128 x 1968 mirrors its largest tile takes 0.07 s where one
    real FFT of it (scipy.fft, one thread) took 0.19 s, to 2e-15 of the peak apart; the sum is
    the same for any thread count."""
    import cv2

    def node_convolve(part: np.ndarray, kern: np.ndarray) -> np.ndarray:
        ky, kx = kern.shape[0] // 2, kern.shape[1] // 2
        return _filter2d(cv2.copyMakeBorder(part, ky, ky, kx, kx, cv2.BORDER_CONSTANT, value=0.0), kern, "zero")

    return _field_convolve(np.asarray(image, np.float64), grid, node_convolve)


def field_tile_bytes(image_shape, nodes_y: np.ndarray, nodes_x: np.ndarray, kernel_px: int) -> int:
    """Peak bytes of one node's convolution in `field_convolve` on an image of `image_shape`
    (float64): its weighted tile, the tile padded by the kernel's radius and the filtered
    result, for the largest tile of nodes at `nodes_y`, `nodes_x` px."""
    ry, rx = reach_px(image_shape, kernel_px)
    sides = []
    for nodes, size, r in ((nodes_y, int(image_shape[0]), ry), (nodes_x, int(image_shape[1]), rx)):
        spans = hat_spans(hat_weights(np.asarray(nodes, float), np.arange(-r, size + r, dtype=float)))
        sides.append(max(b - a for a, b in filter(None, spans)) + 2 * r)
    return 3 * sides[0] * sides[1] * 8


def hat_spans(weights: np.ndarray) -> list[tuple[int, int] | None]:
    """Per node, (first, last + 1) of the coordinates where its hat weight is non-zero: the rows
    or columns its tile covers (None where it covers none)."""
    out = []
    for wn in weights:
        nz = np.flatnonzero(wn)
        out.append((int(nz[0]), int(nz[-1]) + 1) if nz.size else None)
    return out


def _field_convolve(img: np.ndarray, grid: KernelGrid, node_convolve) -> np.ndarray:
    h, w = img.shape
    r = grid.radius_px
    ry, rx = reach_px(img.shape, 2 * r + 1)
    kern = grid.kernels[:, :, r - ry:r + ry + 1, r - rx:r + rx + 1]
    padded = np.pad(img, ((ry, ry), (rx, rx)), mode="symmetric")
    wy = hat_weights(np.asarray(grid.node_y_px, float), np.arange(-ry, h + ry, dtype=float))
    wx = hat_weights(np.asarray(grid.node_x_px, float), np.arange(-rx, w + rx, dtype=float))
    acc = np.zeros((h + 4 * ry, w + 4 * rx))
    col_spans = hat_spans(wx)
    for j, rows in enumerate(hat_spans(wy)):
        if rows is None:
            continue
        r0, r1 = rows
        for i, cols in enumerate(col_spans):
            if cols is None:
                continue
            c0, c1 = cols
            part = padded[r0:r1, c0:c1] * (wy[j, r0:r1, None] * wx[i, None, c0:c1])
            acc[r0:r1 + 2 * ry, c0:c1 + 2 * rx] += node_convolve(part, kern[j, i])
    return acc[2 * ry:2 * ry + h, 2 * rx:2 * rx + w]
