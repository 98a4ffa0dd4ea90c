"""Train `track_net` (control/predictors/track_net.py): the motion model over region tracks.

Data: highlight sequences on image-space paths of every motion kind (analysis/motion_paths.py:
straight, curved, accelerating, braking, swerve, lane change, reversal, stop, go, standing; speed
4-48 px/frame, any heading, each kind's shape (event time, ramps, widths, periods) and half the
cars' growth drawn from motion_paths.TRAINING_SHAPES, E 5-50 over saturation, 0-2 DN noise),
each sample the tracker's measured displacement
chain at frame t (track.py `region_tracks` on frames t-3..t, as the loop runs it) and the true
next displacement of the plate's highlight. Or (`train_track_net_scene`, `poevp train-predictor
SCENE --name track_net`) sequences rendered from a scene (apps/train/train_data.py): there the target
is the displacement of the saturated region's centroid near the plate's rendered box from frame
t to t+1, the quantity the mask's alignment is scored on.

Training (`fit`): checkpoints (model, AdamW moments, the batch generator's state, the run's state)
in safetensors every `checkpoint_every` steps; `--resume` continues bit for bit (a killed run
resumed ends with the uninterrupted run's weights); a tqdm bar shows the loss and the validation
median centroid error and region IoU; `--device auto` trains on CUDA when torch sees it.

Splits: train, val and test differ by seeds, plate texts and paths (every parameter drawn
afresh from its own seed stream: `SPLIT_SEEDS`). Loss (`mask_loss`): 1 - the IoU of the
region's box with itself moved by the displacement error (the saturated pixels the mask would
dim wrongly or leave white), plus 0.01 per px of centroid error. AdamW, cosine learning rate,
deterministic (seeded init and batches). The record (command, data hash, split, budget, val and
test metrics beside `flow`'s constant velocity and `track`'s closed form) goes into the weights'
metadata and a JSON beside them.

    .venv/bin/python -m poevp_optics.apps.train.train_track --out out/predictor/track_net.safetensors

The shipped assets/predictor/track_net.safetensors was written so (with `--out` naming that file).
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

from poevp_optics.analysis.motion_paths import KINDS, TRAINING_SHAPES, PathSpec, render_sequence
from poevp_optics.core.exceptions import UserError
from poevp_optics.control.predictors.track import RegionTrack, closed_form_displacement, region_tracks
from poevp_optics.control.predictors.track_net import TrackNetConfig, chain_arrays
from poevp_optics.control.predictors.track_net_model import TrackNet, save_track_net

#: Seed offsets of the three splits (disjoint seed streams: texts, paths and noise all differ).
SPLIT_SEEDS = {"train": 0, "val": 1_000_000, "test": 2_000_000}
LETTERS = string.ascii_uppercase.replace("I", "").replace("O", "")


def _log_uniform(rng: np.random.Generator, lo_hi: tuple[float, float]) -> float:
    return float(np.exp(rng.uniform(np.log(lo_hi[0]), np.log(lo_hi[1]))))


def random_path(rng: np.random.Generator, frames: int) -> tuple[PathSpec, dict]:
    """A path of a random kind, speed, heading and shape (each shape parameter drawn from
    motion_paths.TRAINING_SHAPES); plus the sequence's other draws."""
    kind = KINDS[int(rng.integers(len(KINDS)))]
    turn = float(rng.uniform(*TRAINING_SHAPES["turn_rad"])) * (1 if rng.random() < 0.5 else -1)
    speed, heading = float(rng.uniform(4.0, 48.0)), float(rng.uniform(0.0, 360.0))
    shape = {"event_frac": float(rng.uniform(*TRAINING_SHAPES["event_frac"])),
             "ramp_frames": _log_uniform(rng, TRAINING_SHAPES["reversal_ramp_frames" if kind == "reversal"
                                                             else "stop_ramp_frames"]),
             "width_frames": float(rng.uniform(*TRAINING_SHAPES["width_frames"])),
             "lane_per_v": float(rng.uniform(*TRAINING_SHAPES["lane_per_v"])),
             "period_frames": float(rng.uniform(*TRAINING_SHAPES["period_frames"])),
             "growth_per_frame": 1.0 if rng.random() < 0.5 else float(rng.uniform(*TRAINING_SHAPES["growth_per_frame"]))}
    path = PathSpec(kind, speed, heading, frames, turn, **shape)
    text = f"{''.join(rng.choice(list(LETTERS), 2))} {''.join(rng.choice(list(string.digits), 4))}"
    return path, {"text": text, "e_over": float(np.exp(rng.uniform(np.log(5.0), np.log(50.0)))),
                  "noise_dn": float(rng.uniform(0.0, 2.0)), **shape}


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
    """SHA-256 of a split's tensors (the region sizes, an evaluation aid, left out)."""
    h = hashlib.sha256()
    for k in sorted(t):
        if k == "size":
            continue
        h.update(k.encode())
        h.update(np.ascontiguousarray(t[k].numpy()).tobytes())
    return h.hexdigest()


def errors_px(samples, predict) -> np.ndarray:
    return np.array([np.hypot(*(predict(s[0]) - s[1])) for s in samples])


def metrics(samples, model: TrackNet | None, kinds=KINDS) -> dict:
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
    for kind in (*kinds, "all"):
        sub = [s for s in samples if kind == "all" or s[2] == kind]
        if sub:
            out[kind] = {n: float(np.median(errors_px(sub, p))) for n, p in preds.items()}
            out[kind]["n"] = len(sub)
    return out


def resolve_device(device: str = "auto") -> str:
    """'cpu', 'cuda', or 'auto': cuda when torch.cuda.is_available(), else cpu."""
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device not in ("cpu", "cuda"):
        raise UserError(f"--device {device!r}: choose cpu, cuda or auto")
    if device == "cuda" and not torch.cuda.is_available():
        raise UserError("--device cuda: torch sees no CUDA device here (use cpu or auto)")
    return device


def box_iou_after_error(sizes: torch.Tensor, err: torch.Tensor) -> torch.Tensor:
    """IoU of a region's box (sizes (N, 2): w, h px) with itself moved by err (N, 2) px: the
    saturated-region IoU a translation error of the mask leaves (closed form for two equal
    boxes: overlap (w - |dx|)+ (h - |dy|)+ over 2 w h - overlap)."""
    w, h = sizes[:, 0].clamp_min(1.0), sizes[:, 1].clamp_min(1.0)
    ov = (w - err[:, 0].abs()).clamp_min(0.0) * (h - err[:, 1].abs()).clamp_min(0.0)
    return ov / (2 * w * h - ov)


def validation_metric(model: TrackNet, v: dict[str, torch.Tensor]) -> dict[str, float]:
    """Median centroid error (px) of the predicted next displacement, and the mean IoU of the
    region moved by that error (`box_iou_after_error`), over a split's tensors."""
    with torch.inference_mode():
        err = model(v["disp"], v["valid"], v["resp"]) - v["target"]
    out = {"median_centroid_error_px": float(err.norm(dim=-1).median())}
    if "size" in v:
        out["mean_region_iou"] = float(box_iou_after_error(v["size"], err).mean())
    return out


#: Weight of the centroid error (per px) beside the region IoU in `mask_loss`: 10 px cost 0.1.
L1_WEIGHT_PER_PX = 0.01


def mask_loss(err: torch.Tensor, sizes: torch.Tensor | None) -> torch.Tensor:
    """What the mask needs from a predicted displacement with error err (N, 2) px: 1 - the
    IoU of the region's box with itself moved by err (`box_iou_after_error`: the saturated
    pixels the law dims that it should not, and those it leaves white), plus L1_WEIGHT_PER_PX x
    the centroid error (px; it keeps a gradient where the boxes no longer overlap). Without the
    regions' sizes: the centroid error alone (px)."""
    dist = err.norm(dim=-1)
    if sizes is None:
        return dist.mean()
    return (1.0 - box_iou_after_error(sizes, err)).mean() + L1_WEIGHT_PER_PX * dist.mean()


_CKPT = "checkpoint.safetensors"


def _save_checkpoint(folder: Path, model: TrackNet, opt, gen: torch.Generator, state: dict) -> None:
    """Model, AdamW moments and steps, the batch generator's state, and the run's state (JSON
    in the safetensors metadata): everything a resumed run needs to continue bit for bit."""
    from safetensors.torch import save_file

    from poevp_optics.core.io import atomic_path

    t = {f"model.{k}": v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    for i, p in enumerate(model.parameters()):
        for k, v in opt.state.get(p, {}).items():
            t[f"adam.{i}.{k}"] = torch.as_tensor(v).detach().cpu().reshape(-1).contiguous()
    t["generator"] = gen.get_state().contiguous()
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_path(folder / _CKPT) as tmp:
        save_file(t, str(tmp), metadata={"state": json.dumps(state)})


def _load_checkpoint(folder: Path, model: TrackNet, opt, gen: torch.Generator, device: str) -> dict:
    from safetensors import safe_open
    from safetensors.torch import load_file

    path = folder / _CKPT
    with safe_open(str(path), framework="pt") as f:
        state = json.loads(f.metadata()["state"])
    t = load_file(str(path))
    model.load_state_dict({k[6:]: v for k, v in t.items() if k.startswith("model.")})
    for i, p in enumerate(model.parameters()):
        st = {}
        for k in ("exp_avg", "exp_avg_sq"):
            if f"adam.{i}.{k}" in t:
                st[k] = t[f"adam.{i}.{k}"].reshape(p.shape).to(device)
        if f"adam.{i}.step" in t:
            st["step"] = t[f"adam.{i}.step"].reshape(())
        if st:
            opt.state[p] = st
    gen.set_state(t["generator"])
    return state


def fit(train: dict[str, torch.Tensor], val: dict[str, torch.Tensor], *, steps: int, batch: int = 256,
        lr: float = 3e-3, seed: int = 0, device: str = "cpu", checkpoint_dir: Path | None = None,
        resume: bool = False, checkpoint_every: int = 500, run_id: dict | None = None,
        progress: bool = True, stop_after: int | None = None) -> tuple[TrackNet, dict]:
    """Train a TrackNet: AdamW, cosine learning rate over `steps`, batches drawn by a seeded CPU
    generator (the same batches on any device), loss `mask_loss` (region IoU and centroid error
    where `train` holds the regions' sizes, else the centroid error). Every `checkpoint_every` steps (and at the end) the whole state goes
    to checkpoint_dir/checkpoint.safetensors; `resume` continues from it (refused when its
    `run_id`, the data hash and budget, differs), so a killed run resumed ends with the weights
    an uninterrupted one would. stop_after: stop (as a kill would) after that many steps,
    without a final checkpoint (tests). Returns (model on the CPU, in eval mode; state)."""
    from tqdm import tqdm

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = TrackNet(TrackNetConfig())
    model.to(device)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    gen = torch.Generator().manual_seed(seed)
    run_id = run_id or {}
    state = {"step": 0, "losses": [], "train_seconds": 0.0, "train_cpu_seconds": 0.0, "run": run_id,
             "resumed_at": []}
    if resume and checkpoint_dir is not None and (Path(checkpoint_dir) / _CKPT).is_file():
        state = _load_checkpoint(Path(checkpoint_dir), model, opt, gen, device)
        if state.get("run") != run_id:
            raise UserError(f"{Path(checkpoint_dir) / _CKPT}: a checkpoint of another run "
                             f"({state.get('run')} vs {run_id}); remove it or drop --resume")
        state["resumed_at"].append(state["step"])
    tr = {k: v.to(device) for k, v in train.items()}
    vd = {k: v.to(device) for k, v in val.items()}
    n = tr["target"].shape[0]
    t0, c0 = time.perf_counter() - state["train_seconds"], time.process_time() - state["train_cpu_seconds"]
    losses = state["losses"]
    bar = tqdm(range(state["step"], steps), desc="train track_net", initial=state["step"], total=steps,
               disable=not progress or None)
    for step in bar:
        if stop_after is not None and step >= stop_after:
            return model, state                            # killed: the last checkpoint stands
        for g in opt.param_groups:
            g["lr"] = lr * (0.02 + 0.98 * 0.5 * (1 + np.cos(np.pi * step / steps)))
        idx = torch.randint(0, n, (batch,), generator=gen).to(device)
        pred = model(tr["disp"][idx], tr["valid"][idx], tr["resp"][idx])
        loss = mask_loss(pred - tr["target"][idx], tr["size"][idx] if "size" in tr else None)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
        state["step"] = step + 1
        if step % 200 == 199:
            vm = validation_metric(model, vd)
            state["val"] = vm
            post = {"loss": f"{np.mean(losses[-200:]):.3f} px",
                    "val_median": f"{vm['median_centroid_error_px']:.3f} px"}
            if "mean_region_iou" in vm:
                post["val_iou"] = f"{vm['mean_region_iou']:.3f}"
            bar.set_postfix(**post)
        if checkpoint_dir is not None and state["step"] % checkpoint_every == 0 and state["step"] < steps:
            state["train_seconds"], state["train_cpu_seconds"] = time.perf_counter() - t0, time.process_time() - c0
            _save_checkpoint(Path(checkpoint_dir), model, opt, gen, state)
    state["train_seconds"], state["train_cpu_seconds"] = time.perf_counter() - t0, time.process_time() - c0
    state["val"] = validation_metric(model, vd)
    if checkpoint_dir is not None:
        _save_checkpoint(Path(checkpoint_dir), model, opt, gen, state)
    model.cpu().eval()
    return model, state


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
    tensors = {name: {**to_tensors(s), "size": region_sizes(s)} for name, (s, _) in splits.items()}
    model, state = fit(tensors["train"], tensors["val"], steps=steps, batch=batch, lr=lr, seed=seed,
                       progress=progress)
    train_s, losses = state["train_seconds"], state["losses"]
    model.eval()
    record = {"model": "track_net", "command": command, "config": {"hidden": model.cfg.hidden, "chain": model.cfg.chain},
              "parameters": sum(p.numel() for p in model.parameters()),
              "data": {name: {"sequences": len(m), "samples": int(tensors[name]["target"].shape[0]),
                              "sha256": data_hash(tensors[name]), "seed_offset": SPLIT_SEEDS[name]}
                       for name, (_, m) in splits.items()},
              "split": "train / val / test: disjoint seed streams (texts, paths, shapes, E, noise all drawn per "
                       "seed), frames 368x640, analysis/motion_paths.py kinds " + ", ".join(KINDS)
                       + ", shapes from motion_paths.TRAINING_SHAPES",
              "loss": "1 - region box IoU after the displacement error + 0.01 / px x centroid error",
              "budget": {"steps": steps, "batch": batch, "lr": lr, "seed": seed, "device": "cpu",
                         "train_seconds": train_s, "data_seconds": data_s, "data_cpu_seconds": data_cpu_s,
                         "torch_threads": torch.get_num_threads()},
              "loss_first_200": float(np.mean(losses[:200])), "loss_last_200": float(np.mean(losses[-200:])),
              "val_metric": state.get("val"), "test_metric": validation_metric(model, tensors["test"]),
              "val": metrics(splits["val"][0], model), "test": metrics(splits["test"][0], model)}
    if weights_out is not None:
        save_track_net(model, Path(weights_out), record)
        from poevp_optics.core.io import write_json

        write_json(Path(weights_out).with_suffix(".json"), record)
    return record


def region_sizes(samples) -> torch.Tensor:
    """(N, 2) width and height (px) of each sample's region box."""
    return torch.tensor([[s[0].box[3] - s[0].box[1], s[0].box[2] - s[0].box[0]] for s in samples],
                        dtype=torch.float32).reshape(-1, 2)


def scene_samples(split: dict, context: int = 4) -> list[tuple]:
    """(track, target, kind) samples of a rendered split (apps/train/train_data.py): per frame t the
    plate's region's measured chain on frames t-3..t, and its target, the displacement of the
    saturated region's centroid near the plate (the roi box the renderer reports) from t to t+1:
    the quantity the mask's alignment is scored on."""
    from poevp_optics.analysis.motion_paths import saturated_centroid

    out = []
    for frames, boxes, d in zip(split["frames"], split["boxes"], split["draws"]):
        f = frames.astype(np.float32)
        cs = []
        for img, b in zip(f, boxes):
            if b[2] <= b[0]:
                cs.append(np.array([np.nan, np.nan]))
                continue
            near = np.array([(b[1] + b[3]) / 2.0, (b[0] + b[2]) / 2.0])
            cs.append(saturated_centroid(img, near, radius=0.5 * float(np.hypot(b[2] - b[0], b[3] - b[1])) + 8.0))
        cs = np.asarray(cs)
        for t in range(1, len(f) - 1):
            if not (np.all(np.isfinite(cs[t])) and np.all(np.isfinite(cs[t + 1]))):
                continue
            tracks, labels = region_tracks([f[j] for j in range(max(0, t - context + 1), t + 1)])
            tr = _match(tracks, labels, cs[t])
            if tr is not None and tr.displacements:
                out.append((tr, cs[t + 1] - cs[t], d.kind))
    return out


def train_track_net_scene(scene: str, data_cfg=None, *, steps: int = 3000, batch: int = 128, lr: float = 3e-3,
                          seed: int = 0, device: str = "auto", checkpoint_dir: Path | None = None,
                          resume: bool = False, checkpoint_every: int = 500, weights_out: Path | None = None,
                          cluster=None, progress: bool = True, command: str = "", log=print,
                          stop_after: int | None = None) -> dict:
    """`poevp train-predictor SCENE --name track_net`: build (or reuse) the scene's data
    (apps/train/train_data.py), train with checkpoints, evaluate on the held-out test split beside
    constant velocity (`flow`'s model) and `track`'s closed form; save weights + record."""
    from poevp_optics.apps.train.train_data import DATA_KINDS, DataConfig, build_data

    dev = resolve_device(device)
    cfg = data_cfg or DataConfig()
    t0, c0 = time.perf_counter(), time.process_time()
    data = build_data(scene, cfg, cluster=cluster, progress=progress, log=log)
    samples = {s: scene_samples(data.splits[s]) for s in ("train", "val", "test")}
    if not samples["train"] or not samples["val"]:
        raise UserError(f"{scene}: no tracked plate region in the rendered {'train' if not samples['train'] else 'val'} "
                         "split (plate unsaturated or too small at this --resolution)")
    data_s, data_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    tensors = {s: {**to_tensors(v), "size": region_sizes(v)} for s, v in samples.items() if v}
    hashes = {s: data_hash(t) for s, t in tensors.items()}
    run_id = {"data_sha256": data.sha256, "train_sha256": hashes["train"], "steps": steps, "batch": batch,
              "lr": lr, "seed": seed}
    model, state = fit(tensors["train"], tensors["val"], steps=steps, batch=batch, lr=lr, seed=seed, device=dev,
                       checkpoint_dir=checkpoint_dir, resume=resume, checkpoint_every=checkpoint_every,
                       run_id=run_id, progress=progress, stop_after=stop_after)
    n_train = int(tensors["train"]["target"].shape[0])
    test = tensors.get("test")
    record = {"model": "track_net", "command": command, "scene": data.manifest["scene"],
              "config": {"hidden": model.cfg.hidden, "chain": model.cfg.chain},
              "parameters": sum(p.numel() for p in model.parameters()),
              "data": {"content_sha256": data.sha256, "folder": str(data.folder),
                       "config": data.manifest["config"],
                       **{s: {"sequences": len(data.splits[s]["draws"]), "samples": len(samples[s]),
                              "sha256": hashes.get(s)} for s in ("train", "val", "test")}},
              "split": data.manifest["split"],
              "budget": {"steps": state["step"], "epochs": state["step"] * batch / max(n_train, 1), "batch": batch,
                         "lr": lr, "seed": seed, "device": dev, "train_seconds": state["train_seconds"],
                         "train_cpu_seconds": state["train_cpu_seconds"], "resumed_at_steps": state["resumed_at"],
                         "data_seconds": data_s, "data_cpu_seconds": data_cpu_s,
                         "render_seconds": data.manifest["timing"]["render_seconds"],
                         "data_from_cache": not data.rendered, "torch_threads": torch.get_num_threads()},
              "loss_first_200": float(np.mean(state["losses"][:200])) if state["losses"] else None,
              "loss_last_200": float(np.mean(state["losses"][-200:])) if state["losses"] else None,
              "val_metric": state.get("val"),
              "val": metrics(samples["val"], model, DATA_KINDS),
              "test": metrics(samples["test"], model, DATA_KINDS) if samples["test"] else {},
              "test_metric": validation_metric(model, test) if test is not None else {}}
    if weights_out is not None and stop_after is None:
        from poevp_optics.core.io import write_json

        save_track_net(model, Path(weights_out), record)
        write_json(Path(weights_out).with_suffix(".json"), record)
    return record


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/predictor/track_net.safetensors"),
                    help="weights file (.safetensors; default %(default)s); a .json record beside it")
    ap.add_argument("--train-sequences", type=int, default=1200)
    ap.add_argument("--val-sequences", type=int, default=200)
    ap.add_argument("--test-sequences", type=int, default=300)
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    rec = train_track_net(train_sequences=a.train_sequences, val_sequences=a.val_sequences,
                          test_sequences=a.test_sequences, steps=a.steps, seed=a.seed, weights_out=a.out,
                          command="python -m poevp_optics.apps.train.train_track " + " ".join(argv or sys.argv[1:]))
    print(json.dumps({k: rec[k] for k in ("test", "budget")}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
