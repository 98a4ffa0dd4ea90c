"""Error-targeted rendering: independent-seed replicates until the Monte Carlo error estimate
reaches `render.target_rel_error` (over the ROI, or the frame) or `render.max_spp`.

A radiance sample is the mean of k equal-size renders (replicates) with independent seeds; the
variance of that mean is s^2 / k with s^2 the replicates' sample variance (Welford's running
update, Welford 1962), unbiased for iid MC and for randomised QMC replicates alike (Owen 2013,
ch. 17; render/samplers.py). Its error falls as 1 / sqrt(k), so after a pass with estimate e the
replicates needed for the target T are k (e / T)^2 (x `SAFETY` for the estimate's own scatter);
each pass renders what is missing, capped at max_spp. The first pass is `render.mc_splits`
replicates of render.spp / mc_splits samples: with a target met at once, the result equals the
untargeted render's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

SAFETY = 1.1          # replicates beyond the 1/sqrt(k) prediction, for the estimate's scatter


@dataclass
class Replicates:
    """Running mean and sum of squared deviations (Welford) of equal-size renders."""

    k: int = 0
    spp: int = 0                               # total samples per pixel so far
    mean: np.ndarray | None = None
    m2: np.ndarray | None = None
    seeds_used: list = field(default_factory=list)

    def add(self, img: np.ndarray, spp: int) -> None:
        x = img.astype(np.float64)
        self.k += 1
        self.spp += int(spp)
        if self.mean is None:
            self.mean, self.m2 = x.copy(), np.zeros_like(x)
            return
        delta = x - self.mean
        self.mean += delta / self.k
        self.m2 += delta * (x - self.mean)

    def variance_of_mean(self) -> np.ndarray:
        """Per pixel: s^2 / k, the variance of the replicates' mean (needs k >= 2)."""
        return self.m2 / (self.k * (self.k - 1))


@dataclass(frozen=True)
class Target:
    """What to render to: the relative error, the spp cap per radiance sample, and the box
    (y0, x0, y1, x1) the error is taken over (None: the frame); with `boxes`, the largest error
    over them (every plate in view held to the target)."""

    rel_error: float
    max_spp: int
    box: tuple[int, int, int, int] | None = None
    boxes: tuple = ()            # several ROIs (render.roi_shape = "plates"): the worst box decides


def rel_error(mean: np.ndarray, var: np.ndarray, box=None, pixels=None) -> float | None:
    """RMS per-pixel MC standard error over the mean radiance of the frame (or of `box`; with
    `pixels`, bool of the box's shape, of those pixels of it: a plate's own)."""
    if box is not None:
        y0, x0, y1, x1 = box
        mean, var = mean[y0:y1, x0:x1], var[y0:y1, x0:x1]
        if pixels is not None and np.any(pixels):
            mean, var = mean[pixels], var[pixels]
    m = float(np.mean(mean, dtype=np.float64))
    if m <= 0:
        return None
    return float(np.sqrt(np.mean(var, dtype=np.float64)) / m)


def max_box_error(mean: np.ndarray, var: np.ndarray, boxes) -> float | None:
    """The largest `rel_error` over `boxes` (None where none has a positive mean): every plate
    is held to the error target, the worst one decides."""
    errs = [e for e in (rel_error(mean, var, b) for b in boxes if b is not None) if e is not None]
    return max(errs) if errs else None


def rel_error_unclipped(mean: np.ndarray, var: np.ndarray, clipped: np.ndarray) -> tuple[float | None, float]:
    """`rel_error` over the pixels that are not `clipped` (bool, mean's shape): pixels clipped in
    the capture read full scale whatever their radiance, so their MC error does not reach the
    camera's output. Returns (RMS standard error / mean radiance over the unclipped pixels, or
    None when none are left or their mean is not > 0; the clipped fraction)."""
    keep = ~np.asarray(clipped, dtype=bool)
    frac = float(1.0 - np.mean(keep)) if keep.size else 0.0
    if not keep.any():
        return None, frac
    m = float(np.mean(mean[keep], dtype=np.float64))
    if m <= 0:
        return None, frac
    return float(np.sqrt(np.mean(var[keep], dtype=np.float64)) / m), frac


def pixel_rel_errors(mean: np.ndarray, var: np.ndarray, clipped: np.ndarray) -> tuple[float | None, float | None]:
    """Median and 90th percentile over the unclipped pixels with mean > 0 of each pixel's own
    relative MC error sqrt(var) / mean (None, None when there are none). Unlike `rel_error`, a
    few bright pixels (lamp edges 1e4x the road) cannot dominate it."""
    keep = ~np.asarray(clipped, dtype=bool) & (np.asarray(mean) > 0)
    if not keep.any():
        return None, None
    r = np.sqrt(np.asarray(var, dtype=np.float64)[keep]) / np.asarray(mean, dtype=np.float64)[keep]
    return float(np.median(r)), float(np.percentile(r, 90))


def rel_error_of(reps: Replicates, box) -> float | None:
    """`rel_error` of the replicates' mean over `box` (or the frame)."""
    return rel_error(reps.mean, reps.variance_of_mean(), box)


def replicates_needed(k: int, err: float, target: float, k_max: int) -> int:
    """Replicates after the next pass: k (err / target)^2 x SAFETY, at least k + 1, at most k_max."""
    want = math.ceil(k * (err / target) ** 2 * SAFETY)
    return int(min(k_max, max(k + 1, want)))


def render_to_target(renderer, seeds_for, spp: int, splits: int, target: Target,
                     reps: Replicates | None = None) -> tuple[Replicates, bool]:
    """Add replicates of spp // splits samples (seeds: `seeds_for(n)`, the first n of one
    stream) until the estimate over `target.box` is <= target.rel_error, or the next pass
    would pass target.max_spp. Continues `reps` when given. Returns (replicates, target met)."""
    reps = reps or Replicates()
    size = max(1, spp // splits)
    per = renderer.sample_count(size)
    k_max = max(splits, target.max_spp // per)
    want = max(splits, reps.k)
    while True:
        seeds = seeds_for(want)
        while reps.k < want:
            img = renderer.render_once(seeds[reps.k], size)
            reps.add(img, renderer.last_spp)
            reps.seeds_used.append(seeds[reps.k - 1])
        if target.boxes:
            err = max_box_error(reps.mean, reps.variance_of_mean(), target.boxes)
        else:
            err = rel_error_of(reps, target.box)
        if err is None or err <= target.rel_error:
            return reps, True
        if reps.k >= k_max:
            return reps, False
        want = replicates_needed(reps.k, err, target.rel_error, k_max)
