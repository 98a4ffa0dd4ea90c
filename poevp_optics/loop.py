"""The run over frames: render each exposure (K sub-frames), then the camera stages.

A static scene is rendered once and the same radiance reused for every frame and sub-frame;
the report lists that, and every other stage a scene leaves out, under `skipped_stages`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from . import __version__
from .frame import Frame, Quantity
from .io import write_exr, write_png
from .render import Renderer
from .report import write_report
from .scene import SceneSpec
from .tonemap import tonemap
from .units import PHOTON_RADIANCE_UNIT


@dataclass(frozen=True)
class RenderedExposure:
    """Ground truth for one frame: K sub-frame radiances and their time average."""

    index: int
    t_start_s: float
    exposure_s: float
    subframe_times_s: np.ndarray        # (K,) midpoints of K equal sub-intervals
    subframes: tuple[np.ndarray, ...]   # K x (H, W) photon radiance
    radiance: Frame                     # time average over the exposure
    variance: np.ndarray                # MC variance of `radiance` per pixel
    roi: tuple[int, int, int, int] | None
    rel_error: float | None
    rel_error_roi: float | None


def _seeds(base: int, frame: int, sub: int, n: int) -> list[int]:
    """Independent 31-bit seeds for (frame, sub-frame, split) from the scene seed."""
    state = np.random.SeedSequence([base, frame, sub]).generate_state(n)
    return [int(s & 0x7FFFFFFF) for s in state]


def _rel_error(mean: np.ndarray, var: np.ndarray, box=None) -> float | None:
    """RMS per-pixel MC standard error over the mean radiance of the frame (or of `box`)."""
    if box is not None:
        y0, x0, y1, x1 = box
        mean, var = mean[y0:y1, x0:x1], var[y0:y1, x0:x1]
    m = float(np.mean(mean, dtype=np.float64))
    if m <= 0:
        return None
    return float(np.sqrt(np.mean(var, dtype=np.float64)) / m)


def _union(a, b):
    if a is None:
        return b
    if b is None:
        return a
    return (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


def render_exposures(spec: SceneSpec, renderer: Renderer, progress: bool = True):
    """Yield a `RenderedExposure` per frame. Static scenes render once (K = 1) and reuse it."""
    acc = spec.accuracy
    cache = None
    frames = range(spec.timing.frames)
    for i in tqdm(frames, desc=f"render {spec.name}", unit="frame", disable=not progress or None,
                  leave=False):
        t0, t1 = spec.exposure_window_s(i)
        if spec.is_static:
            if cache is None:
                mean, var = renderer.render_with_error(_seeds(spec.render.seed, 0, 0, acc.mc_splits), acc.spp)
                cache = ((mean,), mean, var, renderer.roi_box())
            subs, mean, var, roi = cache
            times = np.array([(t0 + t1) / 2])
        else:
            times = spec.subframe_times_s(i)
            subs, var_sum, roi = [], None, None
            for k, t in enumerate(times):
                renderer.set_time(float(t))
                m, v = renderer.render_with_error(_seeds(spec.render.seed, i, k, acc.mc_splits), acc.spp)
                subs.append(m)
                var_sum = v if var_sum is None else var_sum + v
                roi = _union(roi, renderer.roi_box())
            mean = (np.sum(np.stack(subs), axis=0, dtype=np.float64) / len(subs)).astype(np.float32)
            var = var_sum / len(subs) ** 2
            subs = tuple(subs)
        frame = Frame(mean, Quantity.RADIANCE, PHOTON_RADIANCE_UNIT, t0, t1 - t0, i)
        yield RenderedExposure(i, t0, t1 - t0, times, subs, frame, var, roi,
                               _rel_error(mean, var), _rel_error(mean, var, roi))


def _exr_attrs(spec: SceneSpec, renderer: Renderer, ex: RenderedExposure, quantity: str) -> dict:
    return {"poevp_quantity": quantity, "poevp_unit": PHOTON_RADIANCE_UNIT,
            "poevp_scene": spec.name, "poevp_version": __version__, "poevp_frame": str(ex.index),
            "poevp_t_start_s": repr(ex.t_start_s), "poevp_exposure_s": repr(ex.exposure_s),
            "poevp_render_path": renderer.plan.mode, "poevp_variant": renderer.variant,
            "poevp_spp": str(spec.render.spp)}


def run_render(spec: SceneSpec, out_dir: Path, progress: bool = True) -> dict:
    """Render `spec` into `out_dir` (an empty staging folder); return the report dict."""
    out_dir = Path(out_dir)
    t_run = time.perf_counter()
    t_setup = time.perf_counter()
    renderer = Renderer(spec)
    setup_s = time.perf_counter() - t_setup
    per_frame = []
    t_write = 0.0
    for ex in render_exposures(spec, renderer, progress):
        tw = time.perf_counter()
        name = f"frame_{ex.index:04d}"
        if spec.outputs.radiance_exr:
            write_exr(out_dir / "radiance" / f"{name}.exr",
                      {"Y": ex.radiance.data, "mc_stderr": np.sqrt(ex.variance)},
                      _exr_attrs(spec, renderer, ex, "sensor-weighted photon radiance, exposure mean; "
                                 "mc_stderr = Monte Carlo standard error"))
        if spec.outputs.subframes_exr and not spec.is_static:
            for k, sub in enumerate(ex.subframes):
                write_exr(out_dir / "subframes" / f"{name}_sub{k:03d}.exr", {"Y": sub},
                          _exr_attrs(spec, renderer, ex, f"photon radiance at t = {ex.subframe_times_s[k]!r} s"))
        if spec.outputs.previews:
            write_png(out_dir / "preview" / f"{name}.png", tonemap(ex.radiance.data, spec.outputs.tonemap))
        t_write += time.perf_counter() - tw
        d = ex.radiance.data
        box = ex.roi
        roi_mean = float(np.mean(d[box[0]:box[2], box[1]:box[3]])) if box else None
        per_frame.append({"index": ex.index, "t_start_s": ex.t_start_s, "exposure_s": ex.exposure_s,
                          "subframe_times_s": ex.subframe_times_s, "roi": list(box) if box else None,
                          "radiance_mean": float(np.mean(d)), "radiance_max": float(np.max(d)),
                          "radiance_min": float(np.min(d)), "roi_radiance_mean": roi_mean,
                          "rel_error": ex.rel_error, "rel_error_roi": ex.rel_error_roi})

    def _avg(key):
        vals = [f[key] for f in per_frame if f[key] is not None]
        return float(np.mean(vals)) if vals else None

    skipped = {
        "dmd": "camera stages (DMD, relay, sensor, reconstruct) are not part of this build yet",
        "relay": "camera stages are not part of this build yet",
        "sensor": "camera stages are not part of this build yet",
        "reconstruct": "camera stages are not part of this build yet",
        "predict": "closed loop is not part of this build yet",
    }
    if spec.is_static:
        skipped["render_repeat"] = (f"static scene: rendered once and reused for all "
                                    f"{spec.timing.frames} frames; sub-frames not needed")
    stats = renderer.stats
    total = time.perf_counter() - t_run
    report = {
        "scene": spec.name, "scene_file": str(spec.toml_path), "description": spec.description,
        "version": __version__, "seed": spec.render.seed, "resolution": list(spec.render.resolution),
        "frames": spec.timing.frames, "unit": PHOTON_RADIANCE_UNIT,
        "timing": {"fps": spec.timing.fps, "exposure_s": spec.timing.exposure_s,
                   "exposure_offset_s": spec.timing.exposure_offset_s},
        "accuracy": {"spp": spec.render.spp, "subframes": 1 if spec.is_static else spec.render.subframes,
                     "mc_splits": spec.render.mc_splits},
        "stages": {"render": {
            "seconds": stats.seconds + setup_s, "mitsuba_seconds": stats.seconds,
            "setup_seconds": setup_s, "calls": stats.calls,
            "rel_error": _avg("rel_error"), "rel_error_roi": _avg("rel_error_roi"),
            "rel_error_definition": "RMS per-pixel Monte Carlo standard error / mean radiance "
                                    "(frame or ROI), from independent-seed renders; mean over frames",
            "path": renderer.plan.mode, "path_reason": renderer.plan.reason,
            "variant": renderer.variant, "variant_reason": renderer.variant_reason,
            "static": spec.is_static}},
        "skipped_stages": skipped,
        "io_seconds": t_write, "total_seconds": total,
        "per_frame": per_frame,
    }
    write_report(out_dir, report)
    return report
