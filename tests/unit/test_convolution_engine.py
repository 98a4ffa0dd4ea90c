"""The camera's one convolution module (camera/convolution.py) and glare registry (camera/glare.py)
against definitions computed independently: a direct reflect-padded sum, flux conservation, the
plain convolution as the constant-grid limit, and each halo's closed-form encircled energy."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from scipy import ndimage

from poevp_optics.camera.convolution import DIRECT_MAX_PX, convolve_reflect, field_convolve
from poevp_optics.camera.glare import GLARE_MODELS, GaussianHalo, PowerLawHalo


def _direct(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Same-size convolution by its definition: image continued by mirror reflection
    (...cba|abc...), sum_k K[k] x[i - k] (scipy.ndimage correlates; 'reflect' is that mirror)."""
    return ndimage.convolve(image, kernel, mode="reflect")


def _kernel(n: int, seed: int) -> np.ndarray:
    """A random odd n x n kernel, not symmetric (a flipped kernel would not pass)."""
    k = np.random.default_rng(seed).random((n, n)) + np.linspace(0, 1, n)[:, None]
    return k / k.sum()


@pytest.mark.parametrize("n", [3, DIRECT_MAX_PX, DIRECT_MAX_PX + 2, 41])
def test_reflect_convolution_equals_the_direct_reflect_padded_sum(n):
    """Every method (direct up to DIRECT_MAX_PX; OpenCV's block DFT for a wider kernel within the
    image, 17 px over 19 x 57; the padded FFT for one reaching beyond it) equals the definition
    to 1e-12 of the image's scale in float64, on an image smaller than the kernel in one axis
    (the reach is limited to the image's extent: 41 px over 19 rows)."""
    img = np.random.default_rng(n).random((19, 57)) * 1e3
    k = _kernel(n, n + 1)
    if n <= 19:
        ref = _direct(img, k)
    else:   # ndimage reflects once more beyond the reflected image; build the definition by hand
        ref = _loop_reference(img, k)
    got = convolve_reflect(img, k)
    assert got.dtype == np.float64 and got.shape == img.shape
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


def _loop_reference(img: np.ndarray, k: np.ndarray) -> np.ndarray:
    """sum over taps within the once-reflected image (taps reaching beyond it are dropped)."""
    h, w = img.shape
    c = k.shape[0] // 2
    ry, rx = min(c, h - 1), min(c, w - 1)
    pad = np.pad(img, ((ry, ry), (rx, rx)), mode="symmetric")
    out = np.zeros_like(img)
    for dy in range(-ry, ry + 1):
        for dx in range(-rx, rx + 1):
            out += k[c + dy, c + dx] * pad[ry - dy:ry - dy + h, rx - dx:rx - dx + w]
    return out


def _even_kernel(n: int, seed: int) -> np.ndarray:
    """A random odd n x n kernel equal to its mirror image in each axis (not in the diagonal)."""
    q = np.random.default_rng(seed).random((n // 2 + 1, n // 2 + 1)) * np.linspace(1, 2, n // 2 + 1)[:, None]
    k = np.block([[q[:0:-1, :0:-1], q[:0:-1]], [q[:, :0:-1], q]])
    return k / k.sum()


@pytest.mark.parametrize("shape,n", [((19, 57), 41), ((23, 16), 21), ((7, 9), 61), ((64, 30), 17)])
def test_even_kernels_go_by_dct_and_equal_the_reflect_padded_sum(shape, n):
    """An even kernel (the glare halos) goes by the DCT-II path, without padding, and gives the
    definition to 1e-12 of the image's scale: wider than the image in one or both axes (the
    reach capped at H - 1, W - 1), on odd and even image sizes. A kernel not quite even (one tap
    moved by 1e-9 of itself) goes by the FFT path and equals its own definition as well."""
    from poevp_optics.camera.convolution import _dct_multiplier, is_even

    img = np.random.default_rng(n).random(shape) ** 4 * 1e3
    k = _even_kernel(n, n + 2)
    assert is_even(k) and not np.array_equal(k, k.T)
    c = n // 2
    ry, rx = min(c, shape[0] - 1), min(c, shape[1] - 1)
    assert _dct_multiplier(k, k[c - ry:c + ry + 1, c - rx:c + rx + 1], shape, 1) is not None
    got = convolve_reflect(img, k)
    ref = _loop_reference(img, k)
    assert got.dtype == np.float64 and got.shape == img.shape
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
    odd = k.copy()
    odd[c - 1, c + 1] *= 1 + 1e-9
    assert not is_even(odd)
    np.testing.assert_allclose(convolve_reflect(img, odd), _loop_reference(img, odd), rtol=1e-12,
                               atol=1e-12 * np.abs(ref).max())


def test_the_loop_reference_is_ndimage_where_both_apply():
    img = np.random.default_rng(3).random((21, 30))
    k = _kernel(9, 4)
    np.testing.assert_allclose(_loop_reference(img, k), _direct(img, k), rtol=1e-13)


@pytest.mark.parametrize("n", [5, 31])
def test_a_unit_sum_kernel_conserves_flux_on_a_mirror_symmetric_image(n):
    """On an image that is its own mirror image about both borders' reflection (a tile of a
    periodic, mirror-symmetric field), reflection loses and gains the same light: the total is
    kept to rounding, by the FFT path and by the DCT path (an even kernel)."""
    rng = np.random.default_rng(n)
    q = rng.random((16, 24)) ** 4
    img = np.block([[q, q[:, ::-1]], [q[::-1], q[::-1, ::-1]]])       # symmetric about its centre lines
    for k in (_kernel(n, 7), _even_kernel(n, 7)):
        out = convolve_reflect(img, k)
        assert out.sum() == pytest.approx(img.sum(), rel=1e-12)


@dataclass
class _Grid:
    node_y_px: np.ndarray
    node_x_px: np.ndarray
    kernels: np.ndarray

    @property
    def radius_px(self) -> int:
        return self.kernels.shape[-1] // 2


def test_field_convolution_with_a_constant_grid_is_the_plain_convolution():
    """Bilinear hat weights sum to one, so the same kernel at every node of a 3 x 4 grid gives
    the shift-invariant convolution (Nagy & O'Leary 1998)."""
    img = np.random.default_rng(5).random((40, 64))
    k = _kernel(21, 8)
    grid = _Grid(np.linspace(0, 39, 3), np.linspace(0, 63, 4), np.broadcast_to(k, (3, 4, 21, 21)))
    np.testing.assert_allclose(field_convolve(img, grid), _loop_reference(img, k), rtol=1e-11, atol=1e-13)


def test_field_convolution_follows_the_node_kernels():
    """A point source at a node is blurred by that node's kernel alone (its weight is 1 there)."""
    img = np.zeros((41, 41))
    img[0, 40] = 1.0
    ks = np.zeros((2, 2, 5, 5))
    for j in range(2):
        for i in range(2):
            ks[j, i] = _kernel(5, 10 * j + i)
    out = field_convolve(img, _Grid(np.array([0.0, 40.0]), np.array([0.0, 40.0]), ks))
    np.testing.assert_allclose(out, _loop_reference(img, ks[0, 1]), atol=1e-15)


def test_field_convolution_is_the_overlap_add_of_the_nodes_tiles_and_the_estimate_counts_its_tile():
    """Each image's result is the overlap-add over the nodes' tiles of the tile's full linear
    convolution with its node kernel, by the definition (scipy.signal.convolve, direct sums;
    written here) to 1e-12 of the image's scale, on images of two shapes and a high dynamic range
    (a point 1e9 over the rest: the dark part keeps its own digits to 1e-6); the bytes of one
    node's convolution in flight are three float64 copies of the largest tile padded by the
    radius (`field_tile_bytes`, the memory estimate's term): a middle node's hat is non-zero
    strictly between its two neighbours, so with nodes at rows 0, 19.5, 39 its tile has 38 rows
    and with nodes every 21 columns 2 x 21 - 1 = 41 columns, each padded by 2 x 4."""
    from scipy.signal import convolve

    from poevp_optics.camera import convolution as cv

    def overlap_add(img, grid):
        h, w = img.shape
        r = grid.radius_px
        ry, rx = cv.reach_px(img.shape, 2 * r + 1)
        kern = grid.kernels[:, :, r - ry:r + ry + 1, r - rx:r + rx + 1]
        pad = np.pad(img, ((ry, ry), (rx, rx)), mode="symmetric")
        wy = cv.hat_weights(grid.node_y_px, np.arange(-ry, h + ry, dtype=float))
        wx = cv.hat_weights(grid.node_x_px, np.arange(-rx, w + rx, dtype=float))
        acc = np.zeros((h + 4 * ry, w + 4 * rx))
        for j, wj in enumerate(wy):
            rows = np.flatnonzero(wj)
            for i, wi in enumerate(wx):
                cols = np.flatnonzero(wi)
                r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
                part = pad[r0:r1, c0:c1] * (wj[r0:r1, None] * wi[None, c0:c1])
                acc[r0:r1 + 2 * ry, c0:c1 + 2 * rx] += convolve(part, kern[j, i], mode="full", method="direct")
        return acc[2 * ry:2 * ry + h, 2 * rx:2 * rx + w]

    rng = np.random.default_rng(11)
    ks = np.stack([np.stack([_kernel(9, 3 * j + i) for i in range(4)]) for j in range(3)])
    for shape in ((40, 64), (33, 50)):
        grid = _Grid(np.linspace(0, shape[0] - 1, 3), np.linspace(0, shape[1] - 1, 4), ks)
        img = rng.random(shape) ** 3
        want = overlap_add(img, grid)
        np.testing.assert_allclose(field_convolve(img, grid), want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
    img = rng.random((40, 64))
    img[20, 30] = 1e9
    grid = _Grid(np.linspace(0, 39, 3), np.linspace(0, 63, 4), ks)
    want = overlap_add(img, grid)
    got = field_convolve(img, grid)
    dark = want < 10
    assert dark.mean() > 0.9 and np.max(np.abs(got - want)[dark] / want[dark]) < 1e-6
    assert cv.field_tile_bytes((40, 64), grid.node_y_px, grid.node_x_px, 9) == 3 * (38 + 8) * (41 + 8) * 8


HALOS = {"power_law": PowerLawHalo(2.0, 30.0, 2.0), "gaussian": GaussianHalo(6.0, 0, 0.9995)}


def _tail(name: str, rho: float) -> float:
    """Closed forms, written here: power law A (pi rc^2 + 2 pi rc^n ln(ro/rc)) normalisation with
    n = 2; Gaussian exp(-rho^2 / 2 sigma^2)."""
    if name == "gaussian":
        return math.exp(-rho * rho / (2 * 6.0 ** 2))
    rc, ro = 2.0, 30.0
    a = 1 / (math.pi * rc * rc + 2 * math.pi * rc * rc * math.log(ro / rc))
    return 0.0 if rho >= ro else a * 2 * math.pi * rc * rc * math.log(ro / max(rho, rc)) + (
        a * math.pi * (rc * rc - rho * rho) if rho < rc else 0.0)


def test_every_registry_entry_is_tested_and_cites_a_source():
    assert set(GLARE_MODELS) == set(HALOS)
    for name in GLARE_MODELS:
        assert len(GLARE_MODELS.entry(name).source) > 10
        assert isinstance(HALOS[name], GLARE_MODELS[name])


@pytest.mark.parametrize("name", list(HALOS))
def test_each_glare_kernel_sums_to_one_and_its_tail_is_the_closed_form(name):
    halo = HALOS[name]
    g = halo.kernel()
    assert g.kernel.sum() == pytest.approx(1.0, abs=1e-12) and g.radius_px == halo.radius_px()
    for rho in (1.0, 5.0, 12.0, 25.0):
        assert halo.energy_beyond(rho) == pytest.approx(_tail(name, rho), rel=1e-12)
    # the kernel's own energy beyond rho (pixel centres farther than rho), renormalised by what its
    # support kept, matches the closed form to the pixel discretisation
    n = g.kernel.shape[0] // 2
    yy, xx = np.mgrid[-n:n + 1, -n:n + 1]
    for rho in (6.5, 12.5):
        outside = g.kernel[np.hypot(yy, xx) > rho].sum() * (1 - g.truncation_error) + g.truncation_error
        assert outside == pytest.approx(_tail(name, rho), rel=0.05, abs=2e-4)
    # a cap at the image's extent: the energy left out is the closed-form tail beyond it
    capped = halo.kernel(8)
    assert capped.radius_px == 8 and "capped" in capped.note
    assert capped.truncation_error == pytest.approx(_tail(name, 8.5), rel=1e-12)


def test_reflect_into_is_numpys_symmetric_pad_in_a_zero_fft_buffer():
    """`reflect_into` writes exactly np.pad(..., mode="symmetric") into the top-left of a zero
    array of the FFT's shape, for every reach up to the image's extent minus one (reach_px), and
    refuses a reach the image cannot mirror."""
    from poevp_optics.camera.convolution import reflect_into

    rng = np.random.default_rng(3)
    for h, w in ((1, 1), (2, 5), (7, 3), (9, 16)):
        img = rng.random((h, w))
        for ry in range(h):
            for rx in range(w):
                shape = (h + 2 * ry + int(rng.integers(0, 4)), w + 2 * rx + int(rng.integers(0, 4)))
                want = np.zeros(shape)
                pad = np.pad(img, ((ry, ry), (rx, rx)), mode="symmetric")
                want[:pad.shape[0], :pad.shape[1]] = pad
                np.testing.assert_array_equal(reflect_into(img, ry, rx, shape), want)
    with pytest.raises(ValueError, match="beyond an image of 2 x 5"):
        reflect_into(np.ones((2, 5)), 2, 0, (6, 5))
