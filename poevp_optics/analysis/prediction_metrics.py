"""Prediction quality: PSNR, MS-SSIM (Wang, Simoncelli & Bovik 2003) and highlight IoU."""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

_MS_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)   # Wang et al. 2003, Table 1


def psnr(pred: np.ndarray, truth: np.ndarray, peak: float = 255.0) -> float:
    mse = float(np.mean((np.asarray(pred, np.float64) - np.asarray(truth, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(peak * peak / mse)


def _gauss(size=11, sigma=1.5):
    x = torch.arange(size, dtype=torch.float64) - size // 2
    g = torch.exp(-x * x / (2 * sigma * sigma))
    g = g / g.sum()
    return (g[:, None] * g[None, :])[None, None]


def ms_ssim(pred: np.ndarray, truth: np.ndarray, peak: float = 255.0) -> float:
    """Multi-scale SSIM of two grey images (5 scales, 11x11 Gaussian window, sigma 1.5)."""
    x = torch.from_numpy(np.asarray(pred, np.float64))[None, None]
    y = torch.from_numpy(np.asarray(truth, np.float64))[None, None]
    w = _gauss()
    c1, c2 = (0.01 * peak) ** 2, (0.03 * peak) ** 2
    # as many scales as fit an 11 px window (small images use fewer, weights renormalised)
    n = 1
    while n < len(_MS_WEIGHTS) and min(x.shape[-2:]) // 2 ** n >= 11:
        n += 1
    weights = np.array(_MS_WEIGHTS[:n]) / sum(_MS_WEIGHTS[:n])
    vals = []
    for i, wt in enumerate(weights):
        mx, my = F.conv2d(x, w), F.conv2d(y, w)
        sxx = F.conv2d(x * x, w) - mx * mx
        syy = F.conv2d(y * y, w) - my * my
        sxy = F.conv2d(x * y, w) - mx * my
        cs = ((2 * sxy + c2) / (sxx + syy + c2)).mean()
        if i == len(weights) - 1:
            lum = ((2 * mx * my + c1) / (mx * mx + my * my + c1)).mean()
            vals.append((lum * cs).clamp(min=1e-8) ** wt)
        else:
            vals.append(cs.clamp(min=1e-8) ** wt)
            x, y = F.avg_pool2d(x, 2), F.avg_pool2d(y, 2)
    return float(torch.stack(vals).prod())


def highlight_iou(pred: np.ndarray, truth: np.ndarray, level: float = 250.0) -> float:
    """IoU of the saturated (>= level) regions; 1 when neither has any."""
    a, b = np.asarray(pred) >= level, np.asarray(truth) >= level
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0
