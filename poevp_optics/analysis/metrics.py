"""Image metrics: entropy (paper Eq. 5), local entropy, saturated fraction, errors, mask IoU."""

from __future__ import annotations

import numpy as np

from poevp_optics.core.units import to_8bit  # noqa: F401 (re-exported: control/ uses it too, so it lives in core/)


def crop(img: np.ndarray, box) -> np.ndarray:
    if box is None:
        return img
    y0, x0, y1, x1 = box
    return img[y0:y1, x0:x1]


def entropy_8bit(img_8bit: np.ndarray) -> float:
    """Shannon entropy (bits) of the 256-bin grey-level histogram (paper Eq. 5)."""
    v = np.clip(np.rint(np.asarray(img_8bit, dtype=np.float64)), 0, 255).astype(np.int64).ravel()
    if v.size == 0:
        return 0.0
    p = np.bincount(v, minlength=256) / v.size
    p = p[p > 0]
    return float(-(p * np.log2(p)).sum())


def local_entropy(img_8bit: np.ndarray, radius_px: int = 4) -> np.ndarray:
    """Entropy of each pixel's (2r+1)^2 neighbourhood (paper Sec. 5C), via histogram sums."""
    import cv2

    v = np.clip(np.rint(np.asarray(img_8bit, dtype=np.float64)), 0, 255).astype(np.uint8)
    k = 2 * radius_px + 1
    out = np.zeros(v.shape, np.float64)
    n = float(k * k)
    for level in np.unique(v):
        cnt = cv2.boxFilter((v == level).astype(np.float32), -1, (k, k), normalize=False,
                            borderType=cv2.BORDER_REFLECT)
        p = cnt / n
        with np.errstate(divide="ignore", invalid="ignore"):
            out -= np.where(p > 0, p * np.log2(p), 0.0)
    return out


def saturated_fraction(dn: np.ndarray, max_dn: int) -> float:
    a = np.asarray(dn)
    return float(np.mean(a >= max_dn - 0.5)) if a.size else 0.0


def relative_error(estimate: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> float | None:
    """Mean |estimate - truth| / mean truth over valid pixels (None if none are valid)."""
    v = np.asarray(valid, bool)
    if not v.any():
        return None
    t = np.asarray(truth, np.float64)[v]
    m = float(t.mean())
    if m <= 0:
        return None
    return float(np.mean(np.abs(np.asarray(estimate, np.float64)[v] - t)) / m)


def mask_iou(mask_a: np.ndarray, mask_b: np.ndarray, top: float, threshold: float = 0.98) -> float:
    """IoU of the suppressed regions (mask below threshold x top) of two masks."""
    a = np.asarray(mask_a) < threshold * top
    b = np.asarray(mask_b) < threshold * top
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def plate_white_fraction(img_8bit: np.ndarray, box, percentile: float = 90.0, seen=None) -> float | None:
    """The plate's white as a fraction of full scale: the `percentile`-th percentile of the
    8-bit values inside `box` (the white sheeting covers most of a plate, its characters the
    rest), / 255; with `seen` (bool, the box's shape) over the pixels that show the plate only
    (a car ahead hiding part of it is left out). None without a box or without a seen pixel.
    Issue 18's measure (band 40-90 %)."""
    if box is None:
        return None
    c = crop(img_8bit, box)
    if seen is not None:
        c = c[np.asarray(seen, bool)]
    return float(np.percentile(c, percentile) / 255.0) if c.size else None
