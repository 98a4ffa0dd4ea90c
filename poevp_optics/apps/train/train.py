"""`poevp train-predictor`: train DMVFN(-lite) on simulator-rendered plate sequences.

Loss: multi-scale L1 (full, 1/2, 1/4 resolution; the paper's L1 loss family, Hu et al. 2023),
plus, with `saturation_weight` > 0, that weight times 1 - the soft IoU of the predicted and true
saturated regions (`saturated_iou_loss`: the pixels the mask law dims against those it must),
AdamW with a cosine learning-rate decay, batches of (x_{t-1}, x_t -> x_{t+1}) triplets. Training
is time-boxed (`--minutes`) and resumable: a checkpoint (model + AdamW moments, safetensors) and
its state JSON are written atomically every `--checkpoint-every` steps; re-running the same run
continues it. The run's identity (`run_identity`: model and its config, learning rate, batch,
seed, the data's SHA-256 and source) is stored in the checkpoint; a checkpoint of another run is
not resumed: the run starts afresh with a one-line note (its checkpoint is then overwritten).
The budget (--minutes, --max-steps) is not part of the identity: a run may be given more.
Validation on held-out sequences (other seed: other texts, speeds and directions) gives PSNR,
MS-SSIM and highlight IoU (frames with no true highlight left out) for the model and for `hold`
and `flow`.
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from poevp_optics.core.io import atomic_path, write_json
from poevp_optics.core.report import jsonable
from poevp_optics.apps.train.train_track import resolve_device
from poevp_optics.apps.train.training_data import build_dataset
from poevp_optics.control.predictors.dmvfn import FULL, LITE, DMVFN, DMVFNPredictor, count_macs, count_parameters, save_weights
from poevp_optics.control.predictors.flow import FlowExtrapolation
from poevp_optics.control.predictors.base import Hold
from poevp_optics.analysis.prediction_metrics import SATURATED_8BIT, highlight_iou, ms_ssim, psnr, tail


def multiscale_l1(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    loss = F.l1_loss(pred, target)
    p, t = pred, target
    for _ in range(2):
        p, t = F.avg_pool2d(p, 2), F.avg_pool2d(t, 2)
        loss = loss + F.l1_loss(p, t)
    return loss / 3


#: Soft saturation of a predicted value v on [0, 1]: sigmoid((v - SOFT_LEVEL) / SOFT_WIDTH); a
#: value of 1 (a warped clipped pixel) counts 0.977, 250 DN 0.24, 245 DN 0.002.
SOFT_LEVEL, SOFT_WIDTH = 0.985, 0.004
#: A true pixel is saturated at or above this: the 8-bit clip marker, on [0, 1].
TRUE_LEVEL = SATURATED_8BIT / 255.0


def saturated_iou_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """1 - soft IoU of the predicted and true saturated regions (SOFT_LEVEL, TRUE_LEVEL), per
    sample, averaged over the samples whose target has a saturated pixel (0 when none has)."""
    s_t = (target >= TRUE_LEVEL).float()
    s_p = torch.sigmoid((pred - SOFT_LEVEL) / SOFT_WIDTH)
    inter = (s_p * s_t).flatten(1).sum(1)
    union = (s_p + s_t - s_p * s_t).flatten(1).sum(1)
    has = s_t.flatten(1).sum(1) > 0
    if not bool(has.any()):
        return pred.sum() * 0.0
    return (1.0 - inter[has] / union[has].clamp_min(1e-6)).mean()


def loss_name(saturation_weight: float) -> str:
    """The training loss as the run's identity and record name it."""
    return "multiscale_l1" + (f" + {saturation_weight:g} * (1 - saturated soft IoU)" if saturation_weight else "")


def triplets(frames: np.ndarray) -> np.ndarray:
    """(N, T, H, W) -> index array (M, 2) of (sequence, t) with t-1, t, t+1 valid."""
    n, t = frames.shape[:2]
    return np.array([(i, j) for i in range(n) for j in range(1, t - 1)])


def _batch(frames, idx, c):
    x = torch.from_numpy(frames[idx[:, 0][:, None], idx[:, 1][:, None] + np.array([-1, 0, 1])].astype(np.float32) / 255.0)
    prev, cur, nxt = (x[:, k:k + 1].expand(-1, c, -1, -1) for k in range(3))
    return prev, cur, nxt


def frames_sha256(*arrays: np.ndarray) -> str:
    """SHA-256 of frame arrays (shape, dtype and bytes of each, in order)."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(json.dumps([list(a.shape), str(a.dtype)]).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def run_identity(name: str, cfg, *, lr: float, batch: int, seed: int, data_sha256: str, source: str,
                 loss: str = "multiscale_l1") -> dict:
    """What makes two training runs the same run (module docstring): a checkpoint is resumed
    only by a run with an equal identity."""
    return {"name": name, "config": jsonable(asdict(cfg)), "lr": float(lr), "batch": int(batch), "seed": int(seed),
            "data_sha256": data_sha256, "source": source, "loss": loss}


def _save_checkpoint(out: Path, model, opt, state: dict) -> None:
    from safetensors.torch import save_file

    tensors = {f"model.{k}": v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    for i, (p, st) in enumerate(zip(model.parameters(), [opt.state.get(p, {}) for p in model.parameters()])):
        for k in ("exp_avg", "exp_avg_sq"):
            if k in st:
                tensors[f"adam.{i}.{k}"] = st[k].detach().cpu().contiguous()
        if "step" in st:
            tensors[f"adam.{i}.step"] = torch.as_tensor(st["step"], dtype=torch.float32).reshape(1)
    with atomic_path(out / "checkpoint.safetensors") as tmp:
        save_file(tensors, str(tmp), metadata={"run": json.dumps(state.get("run"), sort_keys=True)})
    write_json(out / "checkpoint.json", state)


def _checkpoint_run(out: Path) -> dict | None:
    """The run identity stored in out/checkpoint.safetensors' metadata (None: none stored)."""
    from safetensors import safe_open

    with safe_open(str(out / "checkpoint.safetensors"), framework="pt") as f:
        return json.loads((f.metadata() or {}).get("run", "null"))


def _load_checkpoint(out: Path, model, opt, run: dict, log=None) -> dict | None:
    """The state of out/'s checkpoint, loaded into `model` and `opt`, when it is a checkpoint
    of the run `run`; None (start afresh) when there is none, and also, after a one-line note,
    when it is another run's or unreadable."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    if not (out / "checkpoint.safetensors").exists() or not (out / "checkpoint.json").exists():
        return None
    log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
    try:
        theirs = _checkpoint_run(out)
        state = json.loads((out / "checkpoint.json").read_text())
    except (SafetensorError, OSError, ValueError) as e:
        log(f"poevp: {out / 'checkpoint.safetensors'}: unreadable checkpoint ({' '.join(str(e).split())[:120]}); "
            "training starts afresh")
        return None
    if theirs != run or state.get("run") != run:
        differs = sorted(k for k in run if not isinstance(theirs, dict) or theirs.get(k) != run[k])
        log(f"poevp: {out / 'checkpoint.safetensors'} is another run's checkpoint (differs in "
            f"{', '.join(differs) or 'its record'}); training starts afresh and replaces it")
        return None
    tensors = load_file(str(out / "checkpoint.safetensors"))
    model.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("model.")})
    for i, p in enumerate(model.parameters()):
        if f"adam.{i}.exp_avg" in tensors:
            opt.state[p] = {"exp_avg": tensors[f"adam.{i}.exp_avg"],
                            "exp_avg_sq": tensors[f"adam.{i}.exp_avg_sq"],
                            "step": tensors[f"adam.{i}.step"].reshape(())}
    return state


def evaluate(predict, frames: np.ndarray) -> dict:
    """Mean PSNR, MS-SSIM and highlight IoU of `predict(history)` on every triplet (the IoU over
    the frames with a true highlight, their count `highlight_frames`)."""
    ps, ss, ious = [], [], []
    for i, t in triplets(frames):
        hist = [frames[i, t - 1].astype(np.float32), frames[i, t].astype(np.float32)]
        pred = np.clip(predict(hist), 0, 255)
        truth = frames[i, t + 1].astype(np.float32)
        ps.append(psnr(pred, truth))
        ss.append(ms_ssim(pred, truth))
        ious.append(highlight_iou(pred, truth))
    iou = tail(ious, higher_is_better=True)
    return {"psnr_db": float(np.mean(ps)), "ms_ssim": float(np.mean(ss)),
            "highlight_iou": iou["mean"], "highlight_frames": iou["n"]}


def _optimizer_to(opt, device, keep=()) -> None:
    """AdamW's state tensors onto `device` (those named in `keep` stay where they are)."""
    for st in opt.state.values():
        for k, v in st.items():
            if torch.is_tensor(v) and k not in keep:
                st[k] = v.to(device)


def _procedural(sequences: int, val_sequences: int, frames: int, seed: int, resolution, progress: bool):
    """highbeam_plate's procedural train and val frames (apps/train/training_data.py), cached."""
    return (build_dataset(sequences, frames, seed=1000 + seed, resolution=resolution, progress=progress),
            build_dataset(val_sequences, frames, seed=9000 + seed, resolution=resolution, progress=progress))


def _step(model, opt, triplet, routing_rng, saturation_weight: float) -> float:
    """One AdamW step on a batch of (prev, cur, next) frames; the loss (module docstring)."""
    prev, cur, nxt = triplet
    pred, _, _ = model(prev, cur, train_routing=model.cfg.routing, generator=routing_rng)
    loss = multiscale_l1(pred, nxt)
    if saturation_weight:
        loss = loss + saturation_weight * saturated_iou_loss(pred, nxt)
    opt.zero_grad()
    loss.backward()
    opt.step()
    return loss.item()


def _write_record(model, record: dict, weights_out: Path | None, float16: bool) -> dict:
    """The training record made JSON-safe; with `weights_out`, the weights (record in their
    metadata, validation apart) and the record as JSON beside them."""
    record = jsonable(record)
    if weights_out is not None:
        save_weights(model, Path(weights_out), {"training": {k: v for k, v in record.items() if k != "validation"},
                                                "validation": record["validation"]}, float16=float16)
        write_json(Path(weights_out).with_suffix(".json"), record)
    return record


def train(name: str = "dmvfn_lite", *, minutes: float = 10.0, sequences: int = 48, frames: int = 6,
          val_sequences: int = 8, batch: int = 4, lr: float = 2e-3, seed: int = 0,
          out: Path = Path("out/train"), weights_out: Path | None = None, max_steps: int | None = None,
          checkpoint_every: int = 50, resolution=(368, 640), progress: bool = True,
          frames_data: tuple | None = None, device: str = "auto", source: str | None = None, log=None, command=None,
          saturation_weight: float = 0.0, float16_weights: bool = False, data_seconds: float = 0.0) -> dict:
    """Train and save weights; returns the training record (also written as JSON). frames_data:
    (train, val) uint8 (N, T, H, W) frames of `source` instead of the procedural set, made in
    `data_seconds` s; device: cpu, cuda or auto (cuda when torch sees one); log: where the note on
    another run's checkpoint goes (default stderr); command: the command line kept; saturation_weight:
    weight of `saturated_iou_loss` beside the L1 (0: L1 alone); float16_weights: `weights_out`
    stores half floats (the checkpoint stays float32)."""
    if not np.isfinite(saturation_weight) or saturation_weight < 0:
        raise ValueError(f"saturation_weight {saturation_weight!r}: a finite weight >= 0")
    cfg = LITE if name == "dmvfn_lite" else FULL
    rng = np.random.default_rng(seed)
    routing_rng = torch.Generator().manual_seed(seed)
    out = Path(out) / name
    out.mkdir(parents=True, exist_ok=True)
    t_data = time.perf_counter()
    data, val = frames_data or _procedural(sequences, val_sequences, frames, seed, resolution, progress)
    sequences, val_sequences, frames, resolution = len(data), len(val), data.shape[1], tuple(data.shape[2:])
    data_s = time.perf_counter() - t_data + data_seconds
    device = torch.device(resolve_device(device))   # a lent GPU if any
    with torch.random.fork_rng(devices=[]):      # seeded weight init, global RNG left untouched
        torch.manual_seed(seed)
        model = DMVFN(cfg)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    source = source or "scenes/highbeam_plate, procedurally varied (apps/train/training_data.py)"
    run = run_identity(name, cfg, lr=lr, batch=batch, seed=seed, data_sha256=frames_sha256(data, val), source=source,
                       loss=loss_name(saturation_weight))
    state = _load_checkpoint(out, model, opt, run, log) or {"step": 0, "seconds": 0.0, "losses": [], "run": run}
    model.to(device)
    _optimizer_to(opt, device, keep=("step",))
    idx = triplets(data)
    budget_s = minutes * 60.0
    total_steps_est = max_steps or 10**9
    t0 = time.perf_counter() - state["seconds"]
    c = cfg.channels
    model.train()
    while True:
        elapsed = time.perf_counter() - t0
        if elapsed >= budget_s or (max_steps is not None and state["step"] >= max_steps):
            break
        frac = min(elapsed / budget_s, 1.0) if max_steps is None else state["step"] / total_steps_est
        for g in opt.param_groups:
            g["lr"] = lr * (0.1 + 0.9 * 0.5 * (1 + np.cos(np.pi * frac)))
        sel = idx[rng.integers(0, len(idx), batch)]
        state["losses"].append(_step(model, opt, (t.to(device) for t in _batch(data, sel, c)), routing_rng,
                                     saturation_weight))
        state["step"] += 1
        if state["step"] % checkpoint_every == 0:
            state["seconds"] = time.perf_counter() - t0
            _save_checkpoint(out, model, opt, state)
            if progress:
                print(f"step {state['step']}: loss {np.mean(state['losses'][-checkpoint_every:]):.4f} "
                      f"({state['seconds']:.0f} s)", flush=True)
    state["seconds"] = time.perf_counter() - t0
    model.cpu()
    _optimizer_to(opt, torch.device("cpu"))
    _save_checkpoint(out, model, opt, state)
    model.eval()
    record = {"name": name, "command": command, "config": asdict(cfg), "parameters": count_parameters(model),
              "gmac_368x640": count_macs(model, 368, 640) / 1e9, "steps": state["step"],
              "train_seconds": state["seconds"], "data_seconds": data_s, "batch": batch, "lr": lr,
              "loss": run["loss"], "weights_dtype": "float16" if float16_weights else "float32",
              "loss_first_50": float(np.mean(state["losses"][:50])) if state["losses"] else None,
              "loss_last_50": float(np.mean(state["losses"][-50:])) if state["losses"] else None,
              "dataset": {"train_sequences": sequences, "val_sequences": val_sequences,
                          "frames": frames, "resolution": list(resolution), "seed": seed,
                          "source": source, "sha256": run["data_sha256"]},
              "validation": None, "torch_threads": torch.get_num_threads(), "device": str(device)}
    _write_record(model, record, weights_out, float16_weights)  # kept even if validation is cut short
    model.to(device)  # validation runs the network where it trained
    record["validation"] = {"model": evaluate(DMVFNPredictor(model, name, None), val),
                            "hold": evaluate(Hold(), val), "flow": evaluate(FlowExtrapolation(), val)}
    model.cpu()
    record = _write_record(model, record, weights_out, float16_weights)
    write_json(out / "record.json", record)
    return record
