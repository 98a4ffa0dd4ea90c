"""Frame sequences for DMVFN training from the motion-path generator: several highlights at once.

Each sequence is 1-3 layers drawn by analysis/motion_paths.py `render_sequence` (a car body with a
plate over saturation on a road texture, moving along one path of every kind it knows: straight,
curved, accelerating, braking, swerve, lane change, reversal, stop, go, standing; 4-48 px/frame,
any heading, half the cars growing), each layer with its own path, text, over-exposure and noise
(apps/train/train_track.py `random_path`, the draws track_net trains on), composited by the
per-pixel maximum so every layer's highlight shows. So the network sees several highlights that
move, stop, grow and appear at once, on the generator the held-out traffic benchmark
(analysis/traffic_paths.py) never uses.

Split: layer seeds are `train_track.SPLIT_SEEDS[split] + LAYERS * i + j` (sequence i, layer j),
so train, val and test draw from the same disjoint streams as track_net's. The frames are a
pure function of (split, n, frames, resolution): no cache is needed (about 50 ms a sequence
on one core) and `frames_sha256` of the result is recorded with the weights.
"""

from __future__ import annotations

import numpy as np

#: Most layers (highlighted cars) composited into one sequence.
LAYERS = 3
#: Generator version: raised whenever what a sequence holds changes.
GENERATOR_VERSION = 1


def path_sequence(split: str, index: int, frames: int, resolution=(368, 640)) -> np.ndarray:
    """(frames, H, W) uint8: sequence `index` of `split` (module docstring)."""
    from poevp_optics.analysis.motion_paths import render_sequence
    from poevp_optics.apps.train.train_track import SPLIT_SEEDS, random_path

    base = SPLIT_SEEDS[split] + LAYERS * index
    layers = 1 + int(np.random.default_rng(base).integers(LAYERS))
    out = None
    for j in range(layers):
        seed = base + j
        path, draws = random_path(np.random.default_rng(seed), frames)
        seq = render_sequence(path, tuple(resolution), draws["e_over"], draws["text"], seed, draws["noise_dn"])
        out = seq.frames if out is None else np.maximum(out, seq.frames)
    return out.astype(np.uint8)


def _one(job):
    return path_sequence(*job)


def path_frames(split: str, n_sequences: int, frames: int = 8, resolution=(368, 640),
                workers: int = 1) -> np.ndarray:
    """(N, T, H, W) uint8 sequences 0..N-1 of `split`; `workers` processes draw them (the
    result does not depend on how many)."""
    if split not in ("train", "val", "test"):
        raise ValueError(f"split {split!r}: choose train, val or test")
    if n_sequences < 1 or frames < 3:
        raise ValueError(f"need >= 1 sequence of >= 3 frames, got {n_sequences} of {frames}")
    jobs = [(split, i, frames, tuple(resolution)) for i in range(n_sequences)]
    out = np.empty((n_sequences, frames, *resolution), np.uint8)
    if workers > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(workers) as ex:
            for i, seq in enumerate(ex.map(_one, jobs, chunksize=8)):
                out[i] = seq
    else:
        for i, job in enumerate(jobs):
            out[i] = _one(job)
    return out


def source_line(n_train: int, n_val: int, frames: int, resolution) -> str:
    """The data's description as the weights' record keeps it."""
    return (f"motion paths, 1-{LAYERS} highlighted cars per sequence (apps/train/path_frames.py v{GENERATOR_VERSION} "
            f"on analysis/motion_paths.py): {n_train} train sequences (seeds from train_track.SPLIT_SEEDS['train']), "
            f"{n_val} validation ('val'), {frames} frames, {resolution[0]}x{resolution[1]}")
