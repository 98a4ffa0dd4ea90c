"""The ground truth of each frame: radiance samples over the exposure and their time average.

A static scene is rendered once and reused for every frame (K = 1 is exact). Static geometry
with PWM lamps renders each emitter group once (the scene without the flickering lamps, and each
lamp alone) and hands the camera those images as a `basis`, whose exposures it integrates exactly
against the lamps' drive: no time samples. A moving scene is sampled at the frame's radiance
nodes (`RenderScene.subframe_times_s`: K uniform nodes with both ends, joined by the DMD's switching
times); its time average uses the nodes' hat-function weights. Monte Carlo error: every sample
is split into `mc_splits` independent-seed renders (renderer.py).
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from poevp_optics.core.frame import RenderedExposure
from poevp_optics.core.seeds import render_seeds
from poevp_optics.render.progressive import Replicates, Target, rel_error, render_to_target

__all__ = ["RenderedExposure", "rel_error", "render_exposures", "render_sample", "flicker_bases"]


def union_box(a, b):
    """The smallest box holding boxes a and b (None: no box)."""
    if a is None:
        return b
    if b is None:
        return a
    return (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


def render_sample(scene, renderer, frame: int, sample: int, rel_target: float = 0.0,
                  reps: Replicates | None = None):
    """One radiance sample at the renderer's pose: (mean, variance of the mean, spp used, target
    met or None, replicates or None). rel_target 0: `render.spp` in `mc_splits` renders."""
    acc = scene.accuracy
    if not rel_target > 0:
        m, v = renderer.render_with_error(render_seeds(scene.render.seed, frame, sample, acc.mc_splits), acc.spp)
        used = renderer.last_used_spp
        if scene.render.roi_spp > 0:
            m, v = add_roi_samples(scene, renderer, frame, sample, m, v, used)
        return m, v, used, None, None
    target = Target(rel_target, acc.max_spp, renderer.roi_box())
    reps, met = render_to_target(renderer, lambda n: render_seeds(scene.render.seed, frame, sample, n),
                                 acc.spp, acc.mc_splits, target, reps)
    return reps.mean.astype(np.float32), reps.variance_of_mean(), reps.spp, met, reps


#: render_seeds' sample index offset of the ROI box renders (apart from every frame sample's).
ROI_STREAM = 1 << 20
#: Pixels added around the ROI shape's projected box (its bounding box is conservative already).
ROI_MARGIN_PX = 1


def add_roi_samples(scene, renderer, frame: int, sample: int, mean, var, spp: int):
    """`render.roi_spp` more samples per pixel over the ROI shape's box at the current pose
    (Renderer.render_box, own seeds), pooled with the frame's `spp` there: mean
    (n1 m1 + n2 m2) / (n1 + n2), variance (n1^2 v1 + n2^2 v2) / (n1 + n2)^2 (independent
    unbiased estimates of the same pixel integral). The frame's pixels elsewhere keep `spp`:
    the effort goes where the error target is (issue 27). Returns (mean, var)."""
    box = renderer.roi_box()
    if box is None:
        return mean, var
    h, w = mean.shape
    y0, x0, y1, x1 = box
    box = (max(0, y0 - ROI_MARGIN_PX), max(0, x0 - ROI_MARGIN_PX), min(h, y1 + ROI_MARGIN_PX),
           min(w, x1 + ROI_MARGIN_PX))
    y0, x0, y1, x1 = box
    seeds = render_seeds(scene.render.seed, frame, ROI_STREAM + sample, scene.accuracy.mc_splits)
    m2, v2, n2 = renderer.render_box_with_error(seeds, scene.render.roi_spp, box)
    n1 = float(spp)
    mean = mean.astype(np.float64).copy()
    var = np.asarray(var, dtype=np.float64).copy()
    a, b = n1 / (n1 + n2), n2 / (n1 + n2)
    mean[y0:y1, x0:x1] = a * mean[y0:y1, x0:x1] + b * m2
    var[y0:y1, x0:x1] = a * a * var[y0:y1, x0:x1] + b * b * v2
    return mean.astype(np.float32), var


def flicker_bases(scene, renderer):
    """Static geometry with PWM lamps: the image without the flickering lamps and one image per
    flickering lamp (radiance is linear in each lamp's drive), each rendered once (to the
    target, when one is set). Returns ({name: (mean, var, spp, met)}, roi)."""
    from poevp_optics.render.renderer import Renderer

    emissive = {n for n, e in scene.spectra.items() if e.kind != "reflectance"}
    groups = [("rest", frozenset(scene.flicker))] + [(p, frozenset(emissive - {p})) for p in scene.flicker]
    out = {}
    for j, (name, zero) in enumerate(groups):
        r = Renderer(scene, zero_params=zero, guard_px=renderer.guard_px)
        out[name] = render_sample(scene, r, 0, 1000 + j, scene.accuracy.target_rel_error)[:4]
        renderer.stats.calls += r.stats.calls
        renderer.stats.seconds += r.stats.seconds
    return out, renderer.roi_box()


def _exposure(i, t0, t1, times, subs, mean, var, roi, **extra) -> RenderedExposure:
    return RenderedExposure.build(i, t0, t1, times, subs, mean, var, roi, rel_error(mean, var),
                                  rel_error(mean, var, roi), **extra)


def _met(flags) -> bool | None:
    flags = [f for f in flags if f is not None]
    return all(flags) if flags else None


def _lamp_exposure(scene, i, t0, t1, bases, roi):
    from poevp_optics.sources.flicker import drive_mean

    rest_m, rest_v = bases["rest"][:2]
    mean, var = rest_m.astype(np.float64), rest_v.astype(np.float64)
    for p, fl in scene.flicker.items():
        d = float(drive_mean(np.array([t0]), np.array([t1]), fl)[0])
        mean, var = mean + d * bases[p][0], var + d * d * bases[p][1]
    names = ("rest", *scene.flicker)
    subs = tuple(bases[n][0] for n in names)
    return _exposure(i, t0, t1, np.array([(t0 + t1) / 2]), subs, mean.astype(np.float32), var, roi,
                     basis=names, spp=tuple(bases[n][2] for n in names), target_met=_met(bases[n][3] for n in names))


def _combine(samples, weights):
    """Time average and its MC variance of the samples [(mean, var, ...)] with `weights`."""
    mean = sum(w * s[0].astype(np.float64) for w, s in zip(weights, samples))
    var = sum(w * w * s[1] for w, s in zip(weights, samples))
    return mean, var


def _moving_exposure(scene, renderer, i, t0, t1):
    times = scene.subframe_times_s(i)
    weights = scene.subframe_weights(i)              # time average of the piecewise-linear L(t)
    target = scene.accuracy.target_rel_error
    share = target / float(np.sqrt(np.sum(weights ** 2))) if target > 0 else 0.0
    samples, roi = [], None
    for k, t in enumerate(times):
        renderer.set_time(float(t))
        samples.append(render_sample(scene, renderer, i, k, share))
        roi = union_box(roi, renderer.roi_box())
    mean, var = _combine(samples, weights)
    for _ in range(3):                              # tighten while the frame misses the target
        err = rel_error(mean, var, roi)
        if not target > 0 or err is None or err <= target or all(s[3] is False for s in samples):
            break
        share *= target / err
        for k, t in enumerate(times):
            renderer.set_time(float(t))
            samples[k] = render_sample(scene, renderer, i, k, share, samples[k][4])
        mean, var = _combine(samples, weights)
    met = None if not target > 0 else bool(rel_error(mean, var, roi) is not None and rel_error(mean, var, roi) <= target)
    return _exposure(i, t0, t1, times, tuple(s[0] for s in samples), mean.astype(np.float32), var, roi,
                     subframe_variances=tuple(s[1] for s in samples), spp=tuple(s[2] for s in samples),
                     target_met=met)


def render_exposures(scene, renderer, progress: bool = True):
    """Yield a `RenderedExposure` per frame (module docstring)."""
    acc = scene.accuracy
    static = bases = None
    for i in tqdm(range(scene.timing.frames), desc=f"render {scene.name}", unit="frame",
                  disable=not progress or None, leave=False):
        t0, t1 = scene.exposure_window_s(i)
        if scene.is_static:
            if static is None:
                static = (*render_sample(scene, renderer, 0, 0, acc.target_rel_error)[:4], renderer.roi_box())
            mean, var, spp, met, roi = static
            yield _exposure(i, t0, t1, np.array([(t0 + t1) / 2]), (mean,), mean, var, roi,
                            spp=(spp,), target_met=met)
        elif scene.geometry_static:                   # flickering lamps, nothing moves
            if bases is None:
                bases, roi0 = flicker_bases(scene, renderer)
            yield _lamp_exposure(scene, i, t0, t1, bases, roi0)
        else:
            yield _moving_exposure(scene, renderer, i, t0, t1)
