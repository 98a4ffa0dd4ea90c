"""Test sequences for `poevp evaluate`: a scene's plate moved along a named motion at a set image
speed (pixels per frame), rendered physically (Mitsuba, the scene's own lights and materials) and
cached by content.

Motion kinds (image-plane speed v px/frame at the plate's base distance Z0; u = time in frames,
centred on the sequence's middle frame; the lateral path is centred on the frame):

| kind        | lateral x(u) (px)                                  | range z(u)                  |
|-------------|----------------------------------------------------|-----------------------------|
| lateral     | d v u                                              | Z0                          |
| approaching | d v u                                              | Z0 - 12 m/s t (closing)     |
| receding    | d v u                                              | Z0 + 12 m/s t               |
| swerve      | A sin(2 pi u / T), T = the sequence, peak speed v  | Z0                          |
| reversal    | +v until frame `change`, -v two frames later (paper Sec. 8's failure case) | Z0  |

d = +-1 alternates with the text index (half the plates cross each way). 12 m/s (43 km/h) is a
closing or opening speed between two cars in traffic. Pixel to metre: measured on the scene
itself (the plate's box at three probe poses, `calibrate`), so any scene with a plate works.

Exposure: the motion within one exposure is blur, v x t_exp x fps pixels; `EXPOSURE_S` (2 ms, an
ALPR-style short shutter) keeps it under 3.6 px at 60 px/frame, so the benchmark measures the
mask's lag, not motion blur. K = 2 radiance nodes (both ends of the exposure) per frame.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from poevp_optics.camera.dmd import node_time_weights_s, node_times_s
from poevp_optics.core.exceptions import SceneError
from poevp_optics.core.io import atomic_path
from poevp_optics.core.cache import (CacheCheckError, UncheckedFile, build_lock, cache_file, discard, json_digest,
                                     load_verified, note_rebuilt, write_checksum)
from poevp_optics.core.seeds import render_seeds
from poevp_optics.render.exposures import RenderedExposure, rel_error, union_box
from poevp_optics.sources.ldr_highlight import srgb_to_linear
from poevp_optics.sources.motion import MotionSpec

KINDS = ("lateral", "approaching", "receding", "swerve", "reversal")
EXPOSURE_S = 0.002
NODES = 2
#: Largest plate displacement between two radiance nodes of one exposure (px): with NODES = 2 a
#: 48 px/frame plate at 30 fps moved 2.9 px within the 2 ms exposure and showed as two sharp
#: copies on 6 px characters; 0.5 px keeps the node sum a smooth blur (Nyquist on the pixel grid).
MAX_NODE_STEP_PX = 0.5
RANGE_SPEED_M_PER_S = 12.0
CACHE_VERSION = "eval-seq-v2"

#: How E sets the plate's peak, in units of the LDR saturation level (module docstring).
E_READINGS = ("display", "linear")


def peak_gain(e: float, reading: str = "display") -> float:
    """Plate peak / saturation for over-exposure rate E: the peak's code value is 255 (E + 1), decoded
    by extended sRGB (`display`, paper Sec. 4.A's domain), or (E + 1) in radiance (`linear`)."""
    if reading == "linear":
        return float(e) + 1.0
    return float(srgb_to_linear(np.float64(e) + 1.0))


@dataclass(frozen=True)
class SequenceSpec:
    """One test sequence: plate text, motion kind, image speed (px/frame), frames, direction."""

    text: str
    kind: str
    speed_px: float
    frames: int
    direction: int = 1
    change: int = 4          # reversal: the frame in which the motion turns


def eval_overrides(resolution, spp: int, frames: int, text: str) -> list[str]:
    """Scene overrides shared by every test sequence (short shutter, no image outputs). The 2 ms
    8-bit window is shorter than a DLPC900 can show (26.8 ms, camera/dmd.py), so the benchmark's
    DMD is the `ideal` controller: it measures the mask's lag, not the controller's limits."""
    return ["dmd.controller='ideal'", f"render.resolution={list(resolution)}", f"render.spp={spp}", f"render.subframes={NODES}",
            f"timing.exposure_s={EXPOSURE_S}", f"timing.dmd_window_s={EXPOSURE_S}",
            f"timing.frames={frames}", f"plate.text={json.dumps(text)}", "outputs.previews=false",
            "outputs.contact_sheet=false", "outputs.radiance_exr=false"]


def plate_motion(spec) -> tuple[str, tuple[str, ...]]:
    """(motion id, attached ids) that carry the plate: the scene's motion entry naming the ROI
    shape, else the ROI shape alone."""
    roi = spec.render.roi_shape
    if not roi:
        raise SceneError(f"{spec.toml_path}: render.roi_shape: evaluate needs a plate (roi_shape = \"plate\")")
    for ident, m in spec.motion.items():
        if ident == roi or roi in m.attached:
            return ident, tuple(m.attached)
    return roi, ()


def with_poses(spec, times_s, offsets_m):
    """`spec` with its plate's motion replaced by keyframes (times_s, offsets_m)."""
    ident, attached = plate_motion(spec)
    motion = MotionSpec(kind="keyframes", times_s=tuple(float(t) for t in times_s),
                        offsets_m=tuple(tuple(float(v) for v in o) for o in offsets_m), attached=attached)
    others = {k: v for k, v in spec.motion.items() if k != ident}
    return dataclasses.replace(spec, motion={**others, ident: motion})


@dataclass(frozen=True)
class Calibration:
    """The plate's image geometry at its base pose: box centre (px), image px per metre of
    lateral offset, base range Z0 (m), frame width (px)."""

    centre_x_px: float
    px_per_m: float
    range_m: float
    width_px: int


def calibrate(spec, guard_px: int) -> Calibration:
    """Measure the plate's box at three probe poses (base, +1 m across, +4 m away)."""
    from poevp_optics.render.renderer import Renderer

    probe = with_poses(spec, (0.0, 1.0, 2.0), ((0, 0, 0), (1.0, 0, 0), (0, 0, 4.0)))
    r = Renderer(probe.resolved.render, guard_px=guard_px)
    boxes = []
    for t in (0.0, 1.0, 2.0):
        r.set_time(t)
        boxes.append(r.roi_box())
    if any(b is None for b in boxes):
        raise SceneError(f"{spec.toml_path}: render.roi_shape: the plate leaves the frame at the probe poses")
    cx = [(b[1] + b[3]) / 2.0 for b in boxes]
    w0, wz = boxes[0][3] - boxes[0][1], boxes[2][3] - boxes[2][1]
    z0 = 4.0 * wz / max(w0 - wz, 1e-9)           # w ~ 1/Z: w0 Z0 = wz (Z0 + 4 m)
    return Calibration(cx[0], cx[1] - cx[0], z0, spec.render.resolution[1])


def _lateral_px(seq: SequenceSpec, u: np.ndarray) -> np.ndarray:
    """Lateral image offset (px) at times u (frames, centred on the middle frame)."""
    v, d = seq.speed_px, seq.direction
    if seq.kind in ("lateral", "approaching", "receding"):
        return d * v * u
    if seq.kind == "swerve":
        period = float(seq.frames - 1)
        return d * v * period / (2 * np.pi) * np.sin(2 * np.pi * u / period)
    # reversal: speed +v until the change frame's start, ramping to -v over two frames
    uc = seq.change - (seq.frames - 1) / 2.0
    fine = np.linspace(-seq.frames, seq.frames, 4001)
    vel = np.interp(fine, [uc, uc + 2.0], [v, -v])
    x = np.concatenate([[0.0], np.cumsum((vel[1:] + vel[:-1]) / 2 * np.diff(fine))])
    return d * np.interp(u, fine, x)


def poses(seq: SequenceSpec, cal: Calibration, fps: float, t_frame_s) -> np.ndarray:
    """Plate offsets (m, (n, 3)) at absolute times `t_frame_s` (s) of the sequence."""
    t = np.asarray(t_frame_s, dtype=np.float64)
    u = t * fps - (seq.frames - 1) / 2.0
    span = _lateral_px(seq, np.linspace(-(seq.frames - 1) / 2.0, (seq.frames + 1) / 2.0, 401))
    x_px = _lateral_px(seq, u) - (span.max() + span.min()) / 2 + (cal.width_px / 2.0 - cal.centre_x_px)
    z = np.zeros_like(t)
    if seq.kind in ("approaching", "receding"):
        sign = -1.0 if seq.kind == "approaching" else 1.0
        z = sign * RANGE_SPEED_M_PER_S * (u / fps)
    return np.stack([x_px / cal.px_per_m, np.zeros_like(t), z], axis=1)


def nodes_for_speed(speed_px_per_frame: float, fps: float) -> int:
    """Radiance nodes per exposure so the plate moves <= MAX_NODE_STEP_PX between nodes
    (at least NODES): 1 + ceil(speed x EXPOSURE_S x fps / MAX_NODE_STEP_PX)."""
    blur_px = abs(float(speed_px_per_frame)) * EXPOSURE_S * float(fps)
    return max(NODES, 1 + int(np.ceil(blur_px / MAX_NODE_STEP_PX - 1e-9)))


def node_times(spec, frames: int, nodes: int = NODES) -> np.ndarray:
    """(frames, K) absolute radiance-node times: K = `nodes` uniform nodes over each exposure."""
    return np.stack([node_times_s(*spec.exposure_window_s(i), nodes) for i in range(frames)])


def render_backend(requested: str) -> str:
    """The Mitsuba variant family a render with `render.variant = requested` runs on: the name
    itself when one is requested, else the backend `core.runtime.choose_variant` prefers here
    (cuda > llvm > scalar; their random sequences and arithmetic differ)."""
    from poevp_optics.core.runtime import backend_available

    if requested != "auto":
        return requested
    return next((b for b in ("cuda", "llvm") if backend_available(b)), "scalar")


def render_fingerprint(spec, guard_px: int, frames: bool = True) -> dict:
    """Everything a render of `spec` (a SceneSpec, its poses in place) depends on, JSON-able:
    the resolved RenderScene (render settings, seeds, accuracy, motion, spectra, sheeting,
    plate, road, vehicles, weather, and with `frames` each frame's exposure window and node
    times; render/render_cache.py's `render_inputs`, without the scene's paths) with the
    SHA-256 of every file it reads and the software versions; the guard band (px); the plate
    font and the render code (render_cache.render_code_inputs, as the sweep's stored renders);
    the renderer's backend."""
    from poevp_optics.apps.sweep.bundle import scene_inputs, with_hashes
    from poevp_optics.render.render_cache import render_code_inputs, render_inputs

    files = {r.key: r.sha256 for r in with_hashes(scene_inputs(spec))}
    inputs = render_inputs(spec.resolved.render, files)
    if not frames:
        inputs.pop("frames")
    inputs["scene"] = {k: v for k, v in inputs["scene"].items() if k not in ("name", "toml_path", "xml_path")}
    return {"render": inputs, "guard_px": int(guard_px), **render_code_inputs(),
            "backend": render_backend(spec.render.variant)}


def content_key(spec, seq: SequenceSpec, times: np.ndarray, offsets: np.ndarray, guard_px: int) -> str:
    """Cache key of one test sequence's renders: the sequence, its node times (s) and poses (m),
    the shutter, and `render_fingerprint` of the scene with those poses (its frame timing left
    out: the node times stand for it, so the sequence keeps its key whatever the scene's frame
    count); CACHE_VERSION: bump on a change to what is stored."""
    posed = with_poses(spec, np.ravel(times), offsets)
    blob = [CACHE_VERSION, dataclasses.asdict(seq), np.asarray(times, np.float64).round(12).tolist(),
            np.round(offsets, 6).tolist(), EXPOSURE_S, render_fingerprint(posed, guard_px, frames=False)]
    return json_digest(blob, sort_keys=True, default=str)


def _exposures(spec, renders: dict, times: np.ndarray) -> list[RenderedExposure]:
    """RenderedExposure per frame from node renders {(frame, node): (mean, var, roi)}."""
    out = []
    for i in range(times.shape[0]):
        t0, t1 = spec.exposure_window_s(i)
        w = node_time_weights_s(t1 - t0, times[i] - t0)
        w = w / w.sum()
        subs = tuple(renders[i, k][0] for k in range(times.shape[1]))
        mean = sum(wk * s.astype(np.float64) for wk, s in zip(w, subs))
        var = sum(wk * wk * renders[i, k][1].astype(np.float64) for k, wk in enumerate(w))
        roi = None
        for k in range(times.shape[1]):
            roi = union_box(roi, renders[i, k][2])
        out.append(RenderedExposure.build(i, t0, t1, times[i], subs, mean.astype(np.float32),
                                          var.astype(np.float32), roi, rel_error(mean, var),
                                          rel_error(mean, var, roi)))
    return out


def _save(path: Path, renders: dict, n: int, k: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, mean=np.stack([np.stack([renders[i, j][0] for j in range(k)]) for i in range(n)]),
                     var=np.stack([np.stack([renders[i, j][1] for j in range(k)]) for i in range(n)]).astype(np.float32),
                     roi=np.array([[renders[i, j][2] or (0, 0, 0, 0) for j in range(k)] for i in range(n)]))


def _load(path: Path, n: int, k: int, shape: tuple[int, int]) -> dict:
    """{(frame, node): (mean, var, roi)} of a cached file, after checking its arrays: mean and var
    (n, k, H, W, ...) alike, finite, var >= 0; roi (n, k, 4) (CacheCheckError otherwise)."""
    with np.load(path) as z:
        mean, var, roi = z["mean"], z["var"], z["roi"]
    if mean.shape[:4] != (n, k, *shape) or var.shape != mean.shape or roi.shape != (n, k, 4):
        raise CacheCheckError(f"mean {mean.shape}, var {var.shape}, roi {roi.shape}: not ({n}, {k}, "
                              f"{shape[0]}, {shape[1]}) images and ({n}, {k}, 4) boxes")
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(var)) and var.min() >= 0):
        raise CacheCheckError("mean or var not finite, or a negative var")
    out = {}
    for i in range(n):
        for j in range(k):
            box = tuple(int(v) for v in roi[i, j])
            out[i, j] = (mean[i, j], var[i, j], box if box[2] > box[0] else None)
    return out


def render_sequences(spec, seqs: list[SequenceSpec], cal: Calibration, guard_px: int,
                     log=print) -> list[list[RenderedExposure]]:
    """Each sequence's exposures (same text: one renderer for all), rendered once and cached by
    `content_key` under the cache folder's eval/; a cached file that fails its check (core/cache.py:
    checksum, array shapes) is rendered again, with a note (none for one without a checksum file)."""
    from poevp_optics.render.renderer import Renderer

    acc = spec.accuracy
    shape = tuple(n + 2 * int(guard_px) for n in spec.render.resolution)
    plan, missing, loaded, damaged = [], [], {}, {}
    for j, seq in enumerate(seqs):
        times = node_times(spec, seq.frames, nodes_for_speed(seq.speed_px, spec.timing.fps))
        offs = poses(seq, cal, spec.timing.fps, times.ravel())
        path = cache_file("eval", f"{content_key(spec, seq, times, offs, guard_px)}.npz")
        plan.append((seq, times, offs, path))
        if path.is_file():
            with build_lock(path):
                try:
                    loaded[j] = load_verified(path, lambda p, n=times.shape: _load(p, *n, shape))
                except CacheCheckError as e:
                    if not isinstance(e, UncheckedFile):
                        damaged[j] = str(e)
                    discard(path)
        if j not in loaded:
            missing.append(j)
    if missing:
        # one global keyframe timeline: pose m of the missing sequences at time m (s)
        all_offs = np.concatenate([plan[j][2] for j in missing])
        r = Renderer(with_poses(spec, np.arange(len(all_offs), dtype=float), all_offs).resolved.render, guard_px=guard_px)
        m = 0
        for j in missing:
            seq, times, offs, path = plan[j]
            renders = {}
            for i in range(times.shape[0]):
                for k in range(times.shape[1]):
                    r.set_time(float(m))
                    mean, var = r.render_with_error(render_seeds(spec.render.seed, i, k, acc.mc_splits), acc.spp)
                    renders[i, k] = (mean, var.astype(np.float32), r.roi_box())
                    m += 1
            with build_lock(path):
                _save(path, renders, *times.shape)
                write_checksum(path)
            loaded[j] = _load(path, *times.shape, shape)
            if j in damaged:
                note_rebuilt(path, damaged[j])
            log(f"poevp evaluate: rendered {seq.text!r} {seq.kind} {seq.speed_px:g} px/frame "
                f"({times.size} renders)")
    return [_exposures(spec, loaded[j], times) for j, (seq, times, offs, path) in enumerate(plan)]
