"""Train the plate recogniser (analysis/plate_ocr.py) on synthetic plate crops
(apps/train/plate_ocr_data.py) and record how it was made in the weights.

Splits: train, val and test are disjoint seed streams (text, plate, optics, exposure and crop all
drawn per sample); every scene's plate text (`plate_ocr_data.scene_texts`) is left out of train
and val and makes up half of test, read at 18-40 px plate heights. CTC loss (Graves et al. 2006),
AdamW, cosine learning rate, seeded initialisation and batch order; the record (command, data
hashes, split, budget, val and test accuracy, test accuracy per plate height and on the held-out
texts alone) goes into the safetensors metadata and a JSON beside them.

    .venv/bin/python -m poevp_optics.apps.train.train_plate_ocr --out out/recogniser/plate_crnn.safetensors

The shipped assets/recogniser/plate_crnn.safetensors was written so (with `--out` naming that file).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from poevp_optics.analysis.plate_ocr import PlateCRNN, PlateOcrConfig, decode, encode, save_plate_ocr
from poevp_optics.analysis.recognition import normalise
from poevp_optics.apps.train.plate_ocr_data import dataset, plate_crop, scene_texts

SPLIT_SEEDS = {"train": 0, "val": 1_000_003, "test": 2_000_003}
TEST_HEIGHTS = (18, 22, 26, 30, 34, 40)      # px: the held-out texts' plate heights in test


def held_out_test(texts: set[str], reps: int, seed: int) -> tuple[list[np.ndarray], list[str], list[float]]:
    """Crops of every held-out text at every TEST_HEIGHTS (plate_crop's other draws random),
    `reps` each: (crops, texts, plate heights)."""
    crops, labels, heights = [], [], []
    for ti, t in enumerate(sorted(texts)):
        for hi, h in enumerate(TEST_HEIGHTS):
            for r in range(reps):
                crops.append(plate_crop(t, np.random.default_rng([seed, ti, hi, r]), height_px=h))
                labels.append(t)
                heights.append(h)
    return crops, labels, heights


def accuracy(model: PlateCRNN, x: np.ndarray, texts: list[str], batch: int = 512) -> float:
    """Fraction of crops read exactly (every character, spaces ignored)."""
    model.eval()
    ok = 0
    with torch.no_grad():
        for i in range(0, len(x), batch):
            reads = decode(model(torch.from_numpy(x[i:i + batch])[:, None]))
            ok += sum(r == normalise(t) for (r, _), t in zip(reads, texts[i:i + batch]))
    model.train()
    return ok / max(len(x), 1)


def fit(steps: int, batch: int, lr: float, seed: int, n_train: int, n_val: int, log=print):
    """Train from scratch; returns (model, record)."""
    torch.manual_seed(seed)
    held = scene_texts()
    t0 = time.perf_counter()
    x_tr, y_tr, sha_tr = dataset(SPLIT_SEEDS["train"], n_train, held)
    x_va, y_va, sha_va = dataset(SPLIT_SEEDS["val"], n_val, held)
    data_s = time.perf_counter() - t0
    log(f"data: {n_train} train + {n_val} val crops in {data_s:.0f} s")
    targets = [torch.tensor(encode(t), dtype=torch.long) for t in y_tr]
    model = PlateCRNN(PlateOcrConfig())
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps, pct_start=0.05)
    ctc = torch.nn.CTCLoss(blank=0, zero_infinity=True)
    order = np.random.default_rng([seed, 3])
    idx = order.permutation(n_train)
    pos, t1 = 0, time.perf_counter()
    for step in range(steps):
        if pos + batch > n_train:
            idx, pos = order.permutation(n_train), 0
        b = idx[pos:pos + batch]
        pos += batch
        lp = model(torch.from_numpy(x_tr[b])[:, None])
        tg = [targets[i] for i in b]
        loss = ctc(lp, torch.cat(tg), torch.full((len(b),), lp.shape[0], dtype=torch.long),
                   torch.tensor([len(t) for t in tg], dtype=torch.long))
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if (step + 1) % 500 == 0 or step + 1 == steps:
            log(f"step {step + 1}/{steps} loss {loss.item():.3f} val {accuracy(model, x_va, y_va):.3f} "
                f"({time.perf_counter() - t1:.0f} s)")
    train_s = time.perf_counter() - t1
    model.eval()
    record = {"data": {"train": {"crops": n_train, "sha256": sha_tr, "seed": SPLIT_SEEDS["train"]},
                       "val": {"crops": n_val, "sha256": sha_va, "seed": SPLIT_SEEDS["val"]}},
              "held_out_texts": sorted(held),
              "budget": {"steps": steps, "batch": batch, "lr": lr, "seed": seed, "device": "cpu",
                         "torch_threads": torch.get_num_threads(), "data_seconds": round(data_s, 1),
                         "train_seconds": round(train_s, 1)},
              "val_accuracy": round(accuracy(model, x_va, y_va), 4)}
    return model, record


def test_record(model: PlateCRNN, n_random: int, reps: int) -> dict:
    """Test accuracy: fresh random texts (their own seed stream) and the held-out scene texts at
    every TEST_HEIGHTS."""
    from poevp_optics.analysis.plate_ocr import prepare

    held = scene_texts()
    x_te, y_te, sha_te = dataset(SPLIT_SEEDS["test"], n_random, held)
    crops, labels, heights = held_out_test(held, reps, SPLIT_SEEDS["test"] + 1)
    x_ho = np.stack([prepare(c) for c in crops])
    per_h = {}
    for h in TEST_HEIGHTS:
        sel = [i for i, v in enumerate(heights) if v == h]
        per_h[str(h)] = round(accuracy(model, x_ho[sel], [labels[i] for i in sel]), 4)
    return {"test": {"random_texts": {"crops": n_random, "sha256": sha_te, "seed": SPLIT_SEEDS["test"],
                                      "accuracy": round(accuracy(model, x_te, y_te), 4)},
                     "held_out_texts": {"crops": len(crops), "reps_per_height": reps,
                                        "accuracy": round(accuracy(model, x_ho, labels), 4),
                                        "accuracy_by_plate_height_px": per_h}}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/recogniser/plate_crnn.safetensors"))
    ap.add_argument("--steps", type=int, default=7000)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--lr", type=float, default=1.5e-3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--train-crops", type=int, default=45000)
    ap.add_argument("--val-crops", type=int, default=2000)
    ap.add_argument("--test-crops", type=int, default=2000)
    ap.add_argument("--test-reps", type=int, default=8, help="held-out crops per text and height")
    a = ap.parse_args(argv)
    model, record = fit(a.steps, a.batch, a.lr, a.seed, a.train_crops, a.val_crops)
    record.update(test_record(model, a.test_crops, a.test_reps))
    argv_s = " ".join(argv if argv is not None else sys.argv[1:])
    record = {"model": "plate_crnn", "command": f"python -m poevp_optics.apps.train.train_plate_ocr {argv_s}".strip(),
              "parameters": sum(p.numel() for p in model.parameters()),
              "split": "train / val / test: disjoint seed streams; every scene's plate text is left out of "
                       "train and val and read in test at 18-40 px", **record}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    save_plate_ocr(model, a.out, {k: v for k, v in record.items() if k != "model"})
    a.out.with_suffix(".json").write_text(json.dumps(record, indent=2) + "\n")
    print(json.dumps(record["test"], indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
