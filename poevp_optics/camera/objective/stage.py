"""The objective stage: out = (1 - g) B(V x) + g H * (V x) (package docstring), its guard band,
and its report summary."""

from __future__ import annotations

import math

import numpy as np

from poevp_optics.camera.convolution import convolve_reflect, field_convolve
from poevp_optics.camera.glare import GlareKernel
from poevp_optics.camera.objective.glare import glare_kernel, glare_radius_px
from poevp_optics.camera.objective.params import ObjectiveParams, band
from poevp_optics.camera.objective.prescriptions import corner_radius_m
from poevp_optics.camera.objective.psfs import PSFGrid, psf_grid
from poevp_optics.camera.objective.vignetting import relative_illumination

def is_identity(params: ObjectiveParams) -> bool:
    """True when the stage changes nothing (no PSF, no vignetting, no glare): skip it."""
    return params.psf == "delta" and params.vignetting == "none" and params.glare_fraction <= 0


def radius_px(params: ObjectiveParams, image_shape, *, rendered_px: int = 0, cap_px: int | None = None,
              cache_dir=None) -> int:
    """Guard band (px) the camera must render on each side of an image of `image_shape` (the
    sensor's footprint on the DMD) so that light from beyond it reaches it through the stage's
    widest kernel: max(PSF radius, glare radius). The prescription's kernels depend on the field
    the image spans, so the radius is iterated with the guard included (a fixed point within 3
    steps), starting from the guard rendered anyway: `rendered_px` (another stage's) or the glare
    radius. When the kernels on that field fit inside it, their radius is returned after one grid
    (the grid the camera then uses). The kernels only widen with the field, so once the radius
    reaches `cap_px` (the caller's cap, e.g. objective.guard_max_px) no grid is needed beyond."""
    h, w = int(image_shape[0]), int(image_shape[1])
    rg = glare_radius_px(params, (h, w))
    if params.psf == "delta" or (cap_px is not None and rg >= cap_px):
        return rg
    r = max(0, int(rendered_px), rg)
    for step in range(3):
        rn = psf_grid(params, (h + 2 * r, w + 2 * r), cache_dir=cache_dir).radius_px
        if rn <= r:
            if step == 0:
                r = rn                   # fits inside the guard rendered anyway: its own need there
            break
        r = rn
        if cap_px is not None and r >= cap_px:
            break
    return max(r, rg)


def apply(image: np.ndarray, params: ObjectiveParams, *, cache_dir=None, grid: PSFGrid | None = None,
          glare: GlareKernel | None = None, ri: np.ndarray | None = None) -> np.ndarray:
    """The image the objective forms on the DMD: (1 - g) B(V x) + g H * (V x) (module docstring).

    image: (H, W) float32 or float64, finite and >= 0 (sensor-weighted photon radiance of the
    pinhole render, guard band included; the optical axis at its centre). grid, glare, ri:
    precomputed `psf_grid`, `glare_kernel`, `relative_illumination` for this shape (built when
    None). Returns a new array of the input's float dtype (float64 inside)."""
    return apply_with_veil(image, params, cache_dir=cache_dir, grid=grid, glare=glare, ri=ri)[0]


def apply_with_veil(image: np.ndarray, params: ObjectiveParams, *, cache_dir=None, grid: PSFGrid | None = None,
                    glare: GlareKernel | None = None,
                    ri: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """(`apply`'s image, its veiling-glare term g H * (V x) in float64, the same numbers that
    image was summed from; None without glare)."""
    x = np.asarray(image)
    if x.ndim != 2:
        raise ValueError(f"objective.apply: image must be 2-D (H, W), got shape {x.shape}")
    if not np.issubdtype(x.dtype, np.floating):
        raise ValueError(f"objective.apply: image must be float32 or float64, got {x.dtype}")
    if not np.all(np.isfinite(x)) or (x.size and x.min() < 0):
        raise ValueError("objective.apply: image holds NaN, Inf or negative radiance")
    if is_identity(params):
        return x.copy(), None
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
    veil = None
    if g > 0:
        if glare is None:
            glare = glare_kernel(params, shape)
        veil = g * convolve_reflect(v, glare.kernel)
        out = (1 - g) * core + veil
    else:
        out = core
    return np.maximum(out, 0.0).astype(x.dtype), veil


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
