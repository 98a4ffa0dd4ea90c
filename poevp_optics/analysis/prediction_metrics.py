"""Prediction quality: PSNR, MS-SSIM (Wang, Simoncelli & Bovik 2003), and what the mask needs:
the IoU of the saturated regions, the fraction of truly saturated pixels a prediction leaves
undimmed, and the fraction of the pixels that switched (came on or went out) it gets right;
`tail` summarises per-frame scores with their p90 and worst frame beside the median.

A frame whose truth holds no saturated pixel has nothing to dim: its saturated-region scores are
NaN and `tail` leaves it out (counted). A prediction that loses the highlight (no saturated pixel
where the truth has some) scores IoU 0 and undimmed fraction 1: a miss, never a skipped frame.
"""

from __future__ import annotations

import numpy as np

_MS_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)   # Wang et al. 2003, Table 1


def psnr(pred: np.ndarray, truth: np.ndarray, peak: float = 255.0) -> float:
    mse = float(np.mean((np.asarray(pred, np.float64) - np.asarray(truth, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(peak * peak / mse)


#: SSIM window: 11 x 11 px Gaussian, sigma 1.5 px (Wang et al. 2004).
_WINDOW, _SIGMA = 11, 1.5


def _window_mean(img: np.ndarray) -> np.ndarray:
    """Local mean under the SSIM window, 'valid' (only where the whole window fits): OpenCV's
    separable Gaussian blur, float64, with the rim the window overhangs cut off."""
    import cv2

    r = _WINDOW // 2
    return cv2.GaussianBlur(img, (_WINDOW, _WINDOW), _SIGMA, borderType=cv2.BORDER_REFLECT)[r:-r, r:-r]


def _half(img: np.ndarray) -> np.ndarray:
    """2 x 2 average, odd edges dropped."""
    h, w = img.shape[0] // 2 * 2, img.shape[1] // 2 * 2
    return img[:h, :w].reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3))


def ms_ssim(pred: np.ndarray, truth: np.ndarray, peak: float = 255.0) -> float:
    """Multi-scale SSIM of two grey images (5 scales, 11x11 Gaussian window, sigma 1.5)."""
    x, y = np.asarray(pred, np.float64), np.asarray(truth, np.float64)
    c1, c2 = (0.01 * peak) ** 2, (0.03 * peak) ** 2
    # as many scales as fit an 11 px window (small images use fewer, weights renormalised)
    n = 1
    while n < len(_MS_WEIGHTS) and min(x.shape) // 2 ** n >= _WINDOW:
        n += 1
    weights = np.array(_MS_WEIGHTS[:n]) / sum(_MS_WEIGHTS[:n])
    out = 1.0
    for i, wt in enumerate(weights):
        mx, my = _window_mean(x), _window_mean(y)
        sxx, syy = _window_mean(x * x) - mx * mx, _window_mean(y * y) - my * my
        sxy = _window_mean(x * y) - mx * my
        cs = float(np.mean((2 * sxy + c2) / (sxx + syy + c2)))
        if i == len(weights) - 1:
            lum = float(np.mean((2 * mx * my + c1) / (mx * mx + my * my + c1)))
            out *= max(lum * cs, 1e-8) ** wt
        else:
            out *= max(cs, 1e-8) ** wt
            x, y = _half(x), _half(y)
    return float(out)


#: 8-bit value from which a pixel counts as saturated: the mask laws' clip marker (masks.py,
#: control/predictors/flow.py SATURATED).
SATURATED_8BIT = 254.5


def saturated_iou(pred: np.ndarray, truth: np.ndarray, level: float = SATURATED_8BIT) -> float:
    """IoU of the saturated (>= level) regions of a prediction and the truth: the pixels the
    mask law dims against those it must dim. NaN when the truth has none (nothing to score);
    0 when the prediction has none (a miss)."""
    a, b = np.asarray(pred) >= level, np.asarray(truth) >= level
    n_true = int(b.sum())
    if n_true == 0:
        return float("nan")
    return float(np.logical_and(a, b).sum() / np.logical_or(a, b).sum())


def undimmed_fraction(pred: np.ndarray, truth: np.ndarray, level: float = SATURATED_8BIT) -> float:
    """Fraction of the truly saturated pixels (truth >= level) the prediction leaves undimmed
    (prediction < level there: the law leaves those mirrors white and they clip). NaN when the
    truth has none; 1 for a prediction that loses the highlight."""
    b = np.asarray(truth) >= level
    n_true = int(b.sum())
    if n_true == 0:
        return float("nan")
    return float(np.logical_and(b, np.asarray(pred) < level).sum() / n_true)


def switched_right(pred: np.ndarray, prev: np.ndarray, truth: np.ndarray, level: float = SATURATED_8BIT) -> float:
    """Of the pixels whose saturation (>= level) changed from `prev` (the newest frame the
    predictor saw) to `truth` (a light moving, appearing or going out), the fraction the
    prediction gets right: the motion the mask must follow, undiluted by standing lights.
    0 for a prediction that repeats `prev` (hold); NaN when no pixel changed."""
    s_prev, s_true = np.asarray(prev) >= level, np.asarray(truth) >= level
    changed = s_prev != s_true
    n = int(changed.sum())
    if n == 0:
        return float("nan")
    return float(((np.asarray(pred) >= level) == s_true)[changed].sum() / n)


def highlight_iou(pred: np.ndarray, truth: np.ndarray, level: float = 250.0) -> float:
    """`saturated_iou` at `level` (250: the DMVFN training's validation): NaN when the truth has
    no highlight, 0 when the prediction lost it."""
    return saturated_iou(pred, truth, level)


def tail(values, higher_is_better: bool) -> dict:
    """Summary of per-frame scores: n scored, `left_out` (NaN: frames with no true highlight),
    mean, median, p90 (the score 90 % of the frames reach or beat: the 10th percentile of a
    higher-is-better score, the 90th of an error) and the worst frame. An infinite error (a
    miss) counts as the worst; with nothing scored every statistic is NaN."""
    v = np.asarray(list(values), dtype=np.float64)
    keep = v[~np.isnan(v)]
    out = {"n": int(keep.size), "left_out": int(v.size - keep.size)}
    if keep.size == 0:
        return {**out, **dict.fromkeys(("mean", "median", "p90", "worst"), float("nan"))}
    q = 10.0 if higher_is_better else 90.0
    return {**out, "mean": float(np.mean(keep)), "median": float(np.median(keep)),
            "p90": float(np.percentile(keep, q, method="inverted_cdf")),
            "worst": float(keep.min() if higher_is_better else keep.max())}
