"""Kernels on the pixel grid: radial profiles integrated over each pixel, and the cap of a
kernel's support at the image's extent (a tap farther than the image's extent moves light only
off the image). Used by the relay's PSFs, the objective's PSF grids and the glare halos (glare.py).

Two pixel integrators, both the midpoint rule on oversample^2 sub-pixels per pixel:
`pixel_integrated` (the relay's: the whole (2R+1)^2 grid, summed) and `pixel_integrated_radial`
(the objective's: one quadrant, averaged and mirrored, half the profile evaluations). After
normalisation to unit sum they agree to rounding (~1e-16 relative) but not bit for bit, so each
stage keeps the one its recorded regression outputs and on-disk PSF grids were made with.
"""

from __future__ import annotations

import numpy as np

#: Fine samples evaluated at once while building a kernel (bounds its temporary memory).
STRIP_SAMPLES = 1 << 22


def max_radius_px(image_shape) -> int:
    """Widest kernel radius (px) that can matter for an image of `image_shape` (H, W):
    max(H, W) - 1; a tap farther than the image's extent moves light only off the image."""
    return max(int(image_shape[0]), int(image_shape[1])) - 1


def capped_radius(radius_px: int, cap_radius_px: int | None) -> int:
    """`radius_px` limited to `cap_radius_px` (None: no cap), never below 0."""
    return radius_px if cap_radius_px is None else max(min(radius_px, int(cap_radius_px)), 0)


def cap_note(want: int, r: int) -> str:
    """The report's note when a kernel's radius `want` was capped at `r` (px); '' when not."""
    return "" if r >= want else (f"support capped at {2 * r + 1} px by the image's extent (asked for "
                                 f"{2 * want + 1} px); the energy beyond is in the truncation error")


def pixel_integrated(profile, radius_px: int, oversample: int = 7) -> np.ndarray:
    """Sample a radial profile f(r_px) on `oversample`^2 points per pixel of a (2R+1)^2 kernel
    and sum them; built in row strips of at most `STRIP_SAMPLES` fine samples (memory does not
    grow with n^2 o^2). Not normalised."""
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


def pixel_integrated_radial(profile, radius_px: int, oversample: int) -> np.ndarray:
    """Integrate a radial profile f(r_px) over each pixel of a (2R+1)^2 kernel by the midpoint
    rule on oversample^2 sub-pixels; one quadrant is computed and mirrored (the profile is
    radial), in row strips (memory stays ~ 4 M samples). Not normalised."""
    n = radius_px + 1
    sub = (np.arange(oversample) + 0.5) / oversample - 0.5
    cols = (np.arange(n)[:, None] + sub[None, :]).ravel()
    quad = np.empty((n, n))
    rows_per = max(1, STRIP_SAMPLES // (n * oversample * oversample))
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
