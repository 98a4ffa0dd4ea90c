"""The ground truth of each frame: radiance samples over the exposure and their time average.

A static scene is rendered once and reused for every frame (K = 1 is exact). Static geometry
with PWM lamps renders each emitter group once (the scene without the flickering lamps, and each
lamp alone) and hands the camera those images as a `basis`, whose exposures it integrates exactly
against the lamps' drive: no time samples. A moving scene is sampled at the frame's radiance
nodes (`SceneSpec.subframe_times_s`: K uniform nodes with both ends, joined by the DMD's switching
times); its time average uses the nodes' hat-function weights. Monte Carlo error: every sample
is split into `mc_splits` independent-seed renders (renderer.py).
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from poevp_optics.core.frame import Frame, Quantity, RenderedExposure
from poevp_optics.core.seeds import render_seeds
from poevp_optics.core.units import PHOTON_RADIANCE_UNIT


def rel_error(mean: np.ndarray, var: np.ndarray, box=None) -> float | None:
    """RMS per-pixel MC standard error over the mean radiance of the frame (or of `box`)."""
    if box is not None:
        y0, x0, y1, x1 = box
        mean, var = mean[y0:y1, x0:x1], var[y0:y1, x0:x1]
    m = float(np.mean(mean, dtype=np.float64))
    if m <= 0:
        return None
    return float(np.sqrt(np.mean(var, dtype=np.float64)) / m)


def union_box(a, b):
    """The smallest box holding boxes a and b (None: no box)."""
    if a is None:
        return b
    if b is None:
        return a
    return (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


def flicker_bases(spec, renderer):
    """Static geometry with PWM lamps: the image without the flickering lamps and one image per
    flickering lamp (radiance is linear in each lamp's drive), each rendered once."""
    from poevp_optics.render.renderer import Renderer

    acc = spec.accuracy
    emissive = {n for n, e in spec.spectra.items() if e.kind != "reflectance"}
    groups = [("rest", frozenset(spec.flicker))] + [(p, frozenset(emissive - {p})) for p in spec.flicker]
    out = {}
    for j, (name, zero) in enumerate(groups):
        r = Renderer(spec, zero_params=zero, guard_px=renderer.guard_px)
        out[name] = r.render_with_error(render_seeds(spec.render.seed, 0, 1000 + j, acc.mc_splits), acc.spp)
        renderer.stats.calls += r.stats.calls
        renderer.stats.seconds += r.stats.seconds
    return out, renderer.roi_box()


def _exposure(i, t0, t1, times, subs, mean, var, roi, **extra) -> RenderedExposure:
    frame = Frame(mean, Quantity.RADIANCE, PHOTON_RADIANCE_UNIT, t0, t1 - t0, i)
    return RenderedExposure(i, t0, t1 - t0, times, subs, frame, var, roi, rel_error(mean, var),
                            rel_error(mean, var, roi), **extra)


def _lamp_exposure(spec, i, t0, t1, bases, roi):
    from poevp_optics.sources.flicker import drive_mean

    rest_m, rest_v = bases["rest"]
    mean, var = rest_m.astype(np.float64), rest_v.astype(np.float64)
    for p, fl in spec.flicker.items():
        d = float(drive_mean(np.array([t0]), np.array([t1]), fl)[0])
        mean, var = mean + d * bases[p][0], var + d * d * bases[p][1]
    subs = (rest_m, *[bases[p][0] for p in spec.flicker])
    return _exposure(i, t0, t1, np.array([(t0 + t1) / 2]), subs, mean.astype(np.float32), var, roi,
                     basis=("rest", *spec.flicker))


def _moving_exposure(spec, renderer, i, t0, t1):
    acc = spec.accuracy
    times = spec.subframe_times_s(i)
    weights = spec.subframe_weights(i)              # time average of the piecewise-linear L(t)
    subs, variances, roi = [], [], None
    mean = var = 0.0
    for k, t in enumerate(times):
        renderer.set_time(float(t))
        m, v = renderer.render_with_error(render_seeds(spec.render.seed, i, k, acc.mc_splits), acc.spp)
        subs.append(m)
        variances.append(v)
        mean = mean + weights[k] * m.astype(np.float64)
        var = var + weights[k] ** 2 * v
        roi = union_box(roi, renderer.roi_box())
    return _exposure(i, t0, t1, times, tuple(subs), mean.astype(np.float32), var, roi,
                     subframe_variances=tuple(variances))


def render_exposures(spec, renderer, progress: bool = True):
    """Yield a `RenderedExposure` per frame (module docstring)."""
    acc = spec.accuracy
    static = bases = None
    for i in tqdm(range(spec.timing.frames), desc=f"render {spec.name}", unit="frame",
                  disable=not progress or None, leave=False):
        t0, t1 = spec.exposure_window_s(i)
        if spec.is_static:
            if static is None:
                mean, var = renderer.render_with_error(render_seeds(spec.render.seed, 0, 0, acc.mc_splits), acc.spp)
                static = (mean, var, renderer.roi_box())
            mean, var, roi = static
            yield _exposure(i, t0, t1, np.array([(t0 + t1) / 2]), (mean,), mean, var, roi)
        elif spec.geometry_static:                   # flickering lamps, nothing moves
            if bases is None:
                bases, roi0 = flicker_bases(spec, renderer)
            yield _lamp_exposure(spec, i, t0, t1, bases, roi0)
        else:
            yield _moving_exposure(spec, renderer, i, t0, t1)
