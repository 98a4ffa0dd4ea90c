"""Rendering one predictor training sequence (apps/train/train_data.py): the scene's renderer and
camera, frame by frame; also the `train_sequence` job a sweep point runs (apps/run/runner.py JOBS)
when the data render on Dask. Kept apart from train_data.py, which drives the sweep machinery,
so that the job registry does not import the sweep."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

JOB = "train_sequence"


_CAMERAS: dict = {}


def _camera(spec):
    """The scene's camera, built once per process and setting (text, motion, beam and the
    render seed do not change it; its sensor keeps the scene's sensor.seed, i.e. one camera's
    fixed-pattern noise, while each capture's temporal noise takes the sequence's seed):
    night_road's prescription objective costs seconds to build."""
    from poevp_optics.camera.camera import Camera

    key = (str(spec.toml_path), tuple(spec.render.resolution), spec.timing.exposure_s, spec.sensor.seed)
    if key not in _CAMERAS:
        _CAMERAS.clear()
        _CAMERAS[key] = Camera.from_params(spec.resolved.camera)
    return _CAMERAS[key]


def render_frames(spec) -> tuple[np.ndarray, np.ndarray]:
    """(frames (T, H, W) uint8 LDR captures through an all-white mask, plate boxes (T, 4) as
    (y0, x0, y1, x1) in the frame's pixels, clipped to it, -1 where out of view) of a sequence
    spec."""
    from poevp_optics.analysis.metrics import to_8bit
    from poevp_optics.render.renderer import Renderer

    cam = _camera(spec)
    r = Renderer(spec.resolved.render, guard_px=cam.guard_px)
    white = cam.white_mask()
    frames, boxes = [], []
    for i in range(spec.timing.frames):
        r.set_time(float(sum(spec.exposure_window_s(i)) / 2.0))
        rad = r.render_once(spec.render.seed * 1000 + i, spec.render.spp)
        cap = cam.capture([rad], white, i, spec.render.seed * 1000 + i)
        frames.append(np.rint(to_8bit(cap.dn, cam.params.max_dn)).astype(np.uint8))
        b = r.roi_box()                               # in the rendered grid, guard band included
        if b is not None:
            g, (h, w) = cam.guard_px, frames[-1].shape
            b = (max(b[0] - g, 0), max(b[1] - g, 0), min(b[2] - g, h), min(b[3] - g, w))
        boxes.append(b if b is not None and b[2] > b[0] and b[3] > b[1] else (-1, -1, -1, -1))
    return np.stack(frames), np.asarray(boxes, dtype=np.int32)


def run_sequence_job(spec, folder: Path, progress: bool = False) -> dict:
    """The `train_sequence` job (apps/run/runner.py JOBS): one sequence into folder/frames.npz."""
    t0 = time.perf_counter()
    frames, boxes = render_frames(spec)
    with open(Path(folder) / "frames.npz", "wb") as f:
        np.savez_compressed(f, frames=frames, boxes=boxes)
    return {"frames": int(frames.shape[0]), "saturated_px": [int((f >= 255).sum()) for f in frames],
            "seconds": time.perf_counter() - t0}


