"""Train `track_net` (control/predictors/track_net.py): the motion model over region tracks.

Data: highlight sequences on image-space paths of every motion kind (analysis/motion_paths.py:
straight, curved, accelerating, braking, swerve, lane change, reversal; speed 4-48 px/frame, any
heading, E 5-50 over saturation, 0-2 DN noise), each sample the tracker's measured displacement
chain at frame t (track.py `region_tracks` on frames t-3..t, as the loop runs it) and the true
next displacement of the plate's highlight. Optionally sequences rendered by the simulator
(apps/training_data.py `build_split`): there the target is the tracker's own measurement from
frame t to t+1 (no truth is needed).

Splits: train, val and test differ by seeds, plate texts and paths (every parameter drawn
afresh from its own seed stream: `SPLIT_SEEDS`). Loss: L1 of the predicted displacement (px),
i.e. the centroid error of the highlight the mask must cover. AdamW, cosine learning rate,
deterministic (seeded init and batches). The record (command, data hash, split, budget, val and
test metrics beside `flow`'s constant velocity and `track`'s closed form) goes into the weights'
metadata and a JSON beside them.

    python -m poevp_optics.apps.train_track --out assets/predictor/track_net.safetensors
"""

from __future__ import annotations

import argparse
import hashlib
import json
import string
import sys
import time
from pathlib import Path

import numpy as np
import torch

from poevp_optics.analysis.motion_paths import KINDS, PathSpec, render_sequence
from poevp_optics.control.predictors.track import RegionTrack, closed_form_displacement, region_tracks
from poevp_optics.control.predictors.track_net import (TrackNet, TrackNetConfig, chain_arrays,
                                                        save_track_net)

#: Seed offsets of the three splits (disjoint seed streams: texts, paths and noise all differ).
SPLIT_SEEDS = {"train": 0, "val": 1_000_000, "test": 2_000_000}
LETTERS = string.ascii_uppercase.replace("I", "").replace("O", "")


def random_path(rng: np.random.Generator, frames: int) -> tuple[PathSpec, dict]:
    """A path of a random kind, speed, heading and turn; plus the sequence's other draws."""
    kind = KINDS[int(rng.integers(len(KINDS)))]
    turn = float(rng.uniform(0.04, 0.25)) * (1 if rng.random() < 0.5 else -1)
    path = PathSpec(kind, float(rng.uniform(4.0, 48.0)), float(rng.uniform(0.0, 360.0)), frames, turn)
    text = f"{''.join(rng.choice(list(LETTERS), 2))} {''.join(rng.choice(list(string.digits), 4))}"
    return path, {"text": text, "e_over": float(np.exp(rng.uniform(np.log(5.0), np.log(50.0)))),
                  "noise_dn": float(rng.uniform(0.0, 2.0))}


def _match(tracks: list[RegionTrack], labels: np.ndarray, centre: np.ndarray) -> RegionTrack | None:
    """The track whose region holds (or lies nearest to) `centre` (px, x and y)."""
    if not tracks:
        return None
    x, y = int(round(centre[0])), int(round(centre[1]))
    h, w = labels.shape
    if 0 <= y < h and 0 <= x < w:
        for t in tracks:
            if labels[y, x] == t.label:
                return t
    d = [np.hypot((t.box[1] + t.box[3]) / 2 - centre[0], (t.box[0] + t.box[2]) / 2 - centre[1]) for t in tracks]
    best = int(np.argmin(d))
    return tracks[best] if d[best] < 40.0 else None


def sequence_samples(frames: np.ndarray, centres: np.ndarray, context: int = 4) -> list[tuple]:
    """(track, target displacement) per frame t >= 1 with a next frame: the plate's region's
    measured chain on frames t-3..t and its true next displacement (centres: (T, 2) px)."""
    out = []
    for t in range(1, len(frames) - 1):
        hist = [frames[j] for j in range(max(0, t - context + 1), t + 1)]
        tracks, labels = region_tracks(hist)
        tr = _match(tracks, labels, centres[t])
        if tr is None or not tr.displacements:
            continue
        target = centres[t + 1] - centres[t]
        out.append((tr, np.asarray(target, np.float64), None))
    return out


def synthetic_split(split: str, n_sequences: int, frames: int = 10, resolution=(368, 640),
                    progress: bool = True) -> tuple[list[tuple], list[dict]]:
    """Samples and per-sequence metadata of one split of synthetic path sequences."""
    from tqdm import tqdm

    samples, meta = [], []
    for i in tqdm(range(n_sequences), desc=f"track_net {split} sequences", disable=not progress or None):
        seed = SPLIT_SEEDS[split] + i
        rng = np.random.default_rng(seed)
        path, draws = random_path(rng, frames)
        seq = render_sequence(path, resolution, draws["e_over"], draws["text"], seed, draws["noise_dn"])
        got = sequence_samples(seq.frames, seq.centre_px)
        samples += [(tr, tgt, path.kind) for tr, tgt, _ in got]
        meta.append({"seed": seed, "kind": path.kind, "speed_px": path.speed_px,
                     "heading_deg": path.heading_deg, "turn_rad": path.turn_rad, **draws, "samples": len(got)})
    return samples, meta


def to_tensors(samples) -> dict[str, torch.Tensor]:
    disp, valid, resp = chain_arrays([s[0] for s in samples])
    target = np.stack([s[1] for s in samples]).astype(np.float32)
    return {"disp": torch.from_numpy(disp), "valid": torch.from_numpy(valid), "resp": torch.from_numpy(resp),
            "target": torch.from_numpy(target)}


def data_hash(t: dict[str, torch.Tensor]) -> str:
    h = hashlib.sha256()
    for k in sorted(t):
        h.update(k.encode())
        h.update(np.ascontiguousarray(t[k].numpy()).tobytes())
    return h.hexdigest()


def errors_px(samples, predict) -> np.ndarray:
    return np.array([np.hypot(*(predict(s[0]) - s[1])) for s in samples])


def metrics(samples, model: TrackNet | None) -> dict:
    """Median displacement error (px) per kind and pooled: constant velocity (`flow`'s model on
    the same measured chain), `track`'s closed form, and the model."""
    def net(tr):
        d, v, r = chain_arrays([tr])
        with torch.inference_mode():
            return model(torch.from_numpy(d), torch.from_numpy(v), torch.from_numpy(r))[0].numpy()

    preds = {"constant_velocity": lambda tr: np.asarray(tr.displacements[0]),
             "track": lambda tr: closed_form_displacement(tr.displacements)}
    if model is not None:
        preds["track_net"] = net
    out = {}
    for kind in (*KINDS, "all"):
        sub = [s for s in samples if kind == "all" or s[2] == kind]
        if sub:
            out[kind] = {n: float(np.median(errors_px(sub, p))) for n, p in preds.items()}
            out[kind]["n"] = len(sub)
    return out


def train_track_net(*, train_sequences: int = 1200, val_sequences: int = 200, test_sequences: int = 300,
                    frames: int = 10, steps: int = 20000, batch: int = 256, lr: float = 3e-3, seed: int = 0,
                    weights_out: Path | None = None, progress: bool = True, command: str = "") -> dict:
    """Build the splits, train, evaluate; save weights with the record when `weights_out`."""
    from tqdm import tqdm

    torch.set_num_threads(max(1, torch.get_num_threads()))
    t0 = time.perf_counter()
    cpu0 = time.process_time()
    splits = {name: synthetic_split(name, n, frames, progress=progress)
              for name, n in (("train", train_sequences), ("val", val_sequences), ("test", test_sequences))}
    data_s, data_cpu_s = time.perf_counter() - t0, time.process_time() - cpu0
    tensors = {name: to_tensors(s) for name, (s, _) in splits.items()}
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = TrackNet(TrackNetConfig())
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    gen = torch.Generator().manual_seed(seed)
    tr = tensors["train"]
    n = tr["target"].shape[0]
    t1 = time.perf_counter()
    bar = tqdm(range(steps), desc="train track_net", disable=not progress or None)
    losses = []
    for step in bar:
        for g in opt.param_groups:
            g["lr"] = lr * (0.02 + 0.98 * 0.5 * (1 + np.cos(np.pi * step / steps)))
        idx = torch.randint(0, n, (batch,), generator=gen)
        pred = model(tr["disp"][idx], tr["valid"][idx], tr["resp"][idx])
        loss = (pred - tr["target"][idx]).norm(dim=-1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
        if step % 200 == 199:
            with torch.inference_mode():
                v = tensors["val"]
                val = float((model(v["disp"], v["valid"], v["resp"]) - v["target"]).norm(dim=-1).median())
            bar.set_postfix(loss=f"{np.mean(losses[-200:]):.3f} px", val_median=f"{val:.3f} px")
    train_s = time.perf_counter() - t1
    model.eval()
    record = {"model": "track_net", "command": command, "config": {"hidden": model.cfg.hidden, "chain": model.cfg.chain},
              "parameters": sum(p.numel() for p in model.parameters()),
              "data": {name: {"sequences": len(m), "samples": int(tensors[name]["target"].shape[0]),
                              "sha256": data_hash(tensors[name]), "seed_offset": SPLIT_SEEDS[name]}
                       for name, (_, m) in splits.items()},
              "split": "train / val / test: disjoint seed streams (texts, paths, E, noise all drawn per seed), "
                       "frames 368x640, analysis/motion_paths.py kinds " + ", ".join(KINDS),
              "budget": {"steps": steps, "batch": batch, "lr": lr, "seed": seed, "device": "cpu",
                         "train_seconds": train_s, "data_seconds": data_s, "data_cpu_seconds": data_cpu_s,
                         "torch_threads": torch.get_num_threads()},
              "loss_first_200": float(np.mean(losses[:200])), "loss_last_200": float(np.mean(losses[-200:])),
              "val": metrics(splits["val"][0], model), "test": metrics(splits["test"][0], model)}
    if weights_out is not None:
        save_track_net(model, Path(weights_out), record)
        from poevp_optics.core.io import write_json

        write_json(Path(weights_out).with_suffix(".json"), record)
    return record


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="weights file (.safetensors); a .json record beside it")
    ap.add_argument("--train-sequences", type=int, default=1200)
    ap.add_argument("--val-sequences", type=int, default=200)
    ap.add_argument("--test-sequences", type=int, default=300)
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    rec = train_track_net(train_sequences=a.train_sequences, val_sequences=a.val_sequences,
                          test_sequences=a.test_sequences, steps=a.steps, seed=a.seed, weights_out=a.out,
                          command="python -m poevp_optics.apps.train_track " + " ".join(argv or sys.argv[1:]))
    print(json.dumps({k: rec[k] for k in ("test", "budget")}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
