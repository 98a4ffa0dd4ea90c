"""PSF grids: kernels at a grid of field nodes (`PSFGrid`) for the `OBJECTIVE_PSFS` registry:
delta, pixel-integrated Gaussian, Airy, and the prescription's optiland FFT PSFs resampled to the
pixel grid (cached on disk, cache.py)."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Callable

import numpy as np

from poevp_optics.camera.kernels import cap_note, max_radius_px, pixel_integrated_radial
from poevp_optics.camera.objective.cache import cache_key, resolve_cache_dir
from poevp_optics.camera.objective.params import (OBJECTIVE_PSFS, ObjectiveParamError, ObjectiveParams, band,
                                                  sensor_band)
from poevp_optics.camera.objective.prescriptions import build_lens, check_field, corner_radius_m
from poevp_optics.core.cache import cached, save_npz

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


def _single(name, kernel, trunc, note=""):
    k = kernel / kernel.sum()
    return PSFGrid(name, np.zeros(1), np.zeros(1), k[None, None], float(trunc), note)


def _gaussian_grid(params: ObjectiveParams, image_shape, cache_dir=None) -> PSFGrid:
    """Pixel-integrated Gaussian of `gaussian_sigma_px`, support holding `support_energy`
    (2-D Gaussian: energy beyond r is exp(-r^2 / 2 sigma^2))."""
    s = params.sigma_px
    want = max(1, math.ceil(s * math.sqrt(-2 * math.log(1 - params.support_energy))))
    r = min(want, max_radius_px(image_shape))
    k = pixel_integrated_radial(lambda rr: np.exp(-0.5 * (rr / s) ** 2), r, 7)
    trunc = math.exp(-0.5 * ((r + 0.5) / s) ** 2)
    return _single("gaussian", k, trunc, cap_note(want, r))


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
    k = pixel_integrated_radial(lambda rr: np.interp(rr, r_grid, prof), r, 7)
    x_edge = math.pi * (r + 0.5) * params.pixel_pitch_m / (float(np.sum(w * lam_m)) * params.f_number)
    trunc = float(j0(x_edge) ** 2 + j1(x_edge) ** 2)       # 1 - EE(x) of the Airy pattern
    return _single("airy", k, trunc, cap_note(want, r))


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
    lens = build_lens(params, wl_nm, field_max_deg)
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



_GRID_KEYS = ("prescription", "f_number", "focal_length_m", "pixel_pitch_m", "wavelengths_nm", "qe",
              "field_samples", "band_samples", "pupil_rays", "support_energy")


def _prescription_grid(params: ObjectiveParams, image_shape, cache_dir=None) -> PSFGrid:
    """Field-dependent PSF of the `prescription` (optiland FFT PSFs, Kramer Harrison, optiland
    0.6.3, `optiland.psf.FFTPSF`), at `field_samples` nodes per quadrant axis and the band's
    wavelengths, resampled to the pixel grid; cached on disk (a file that fails its check is rebuilt)."""
    path = resolve_cache_dir(cache_dir) / f"psf-{cache_key('psf_grid', params, image_shape, _GRID_KEYS)}.npz"
    return cached(path, lambda: _prescription_grid_build(params, image_shape), load=_load_grid,
                  save=_save_grid, check=lambda g: _grid_problem(g, params, image_shape))


def _grid_problem(g: PSFGrid, params: ObjectiveParams, image_shape) -> str | None:
    """Why a loaded grid is not the prescription grid for `image_shape` (name, image shape, the
    node positions `node_positions_px` puts there, odd square finite non-negative unit-sum
    kernels, a finite truncation), or None."""
    h, w = int(image_shape[0]), int(image_shape[1])
    want = f"prescription:{params.prescription}"
    if g.name != want:
        return f"name {g.name!r}, not {want!r}"
    if g.image_shape != (h, w):
        return f"built for {g.image_shape}, not ({h}, {w})"
    for axis, nodes, size in (("y", g.node_y_px, h), ("x", g.node_x_px, w)):
        expect = node_positions_px(params.field_samples, size)
        if nodes.shape != expect.shape or not np.allclose(nodes, expect, rtol=0, atol=1e-9):
            return f"node_{axis}_px {np.asarray(nodes).tolist()}, not {expect.tolist()}"
    k = g.kernels
    if k.ndim != 4 or k.shape[:2] != (g.node_y_px.size, g.node_x_px.size) or k.shape[2] != k.shape[3] \
            or k.shape[2] % 2 != 1:
        return f"kernels of shape {k.shape}, not ({g.node_y_px.size}, {g.node_x_px.size}, 2r+1, 2r+1)"
    if not np.issubdtype(k.dtype, np.floating) or not np.all(np.isfinite(k)) or k.min() < 0:
        return f"kernels not finite, non-negative floats ({k.dtype})"
    sums = k.sum(axis=(2, 3))
    if not np.allclose(sums, 1.0, rtol=0, atol=1e-6):    # normalised in float64 at build: ~1e-15
        return f"kernel sums {sums.min():.6g} .. {sums.max():.6g}, not 1"
    if not (np.isfinite(g.truncation_error) and g.truncation_error >= 0):
        return f"truncation_error {g.truncation_error}"
    return None


def _load_grid(path) -> PSFGrid:
    with np.load(path) as z:
        return PSFGrid(str(z["name"]), z["node_y_px"], z["node_x_px"], z["kernels"],
                       float(z["truncation_error"]), str(z["note"]), tuple(int(v) for v in z["image_shape"]))


def _save_grid(path, g: PSFGrid) -> None:
    save_npz(path, {"name": np.array(g.name), "node_y_px": g.node_y_px, "node_x_px": g.node_x_px,
                    "kernels": g.kernels, "truncation_error": np.array(g.truncation_error),
                    "note": np.array(g.note), "image_shape": np.array(g.image_shape)})


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
