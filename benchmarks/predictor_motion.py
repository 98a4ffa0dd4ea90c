"""Predictors on held-out motion: where each one puts the highlight one frame on, per motion kind,
speed and direction (issue 26).

Sequences: analysis/motion_paths.py (a textured car, a plate E = 9 over saturation in the paper's
Eq. 3 highlight, 368x640, 8-bit, 1 DN noise) on every kind at 4-48 px/frame and four headings
(right, left, down, up), seeds from their own stream (`BENCH_SEED`, apart from the training
splits of apps/train/train_track.py), so neither the paths nor the texts were seen in training. Each
predictor gets the four frames before frame t (the loop keeps four; two-frame predictors use the
last two) and predicts frame t; t = 4..7 are scored.

Per cell (median over headings and frames):
  centroid err   px between the saturated (>= 254.5) centroids of the prediction and of frame t,
                 both within 150 px of the true plate: the mask's alignment;
  PSNR           dB over a 96x160 window centred on the true plate (8-bit scale);
  mask IoU       IoU of the saturated regions in that window: the pixels the law dims.

    .venv/bin/python -m benchmarks.predictor_motion [--speeds 4,16,32,48] [--kinds ...] [--predictors ...] [--results]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.common import add_results_flag, machine_line, markdown_table, output_folder, save_figure, save_text

PREDICTORS = ("hold", "flow", "dmvfn_lite", "track", "track_net")
HEADINGS = {"right": 0.0, "down": 90.0, "left": 180.0, "up": 270.0}
BENCH_SEED = 5_000_000
FRAMES = 8
SCORED = range(4, FRAMES)


def window(img, centre, hw=(48, 80)):
    h, w = img.shape
    cx, cy = int(round(centre[0])), int(round(centre[1]))
    y0, y1 = max(0, cy - hw[0]), min(h, cy + hw[0])
    x0, x1 = max(0, cx - hw[1]), min(w, cx + hw[1])
    return img[y0:y1, x0:x1]


def score(pred, truth, centre):
    from poevp_optics.analysis.motion_paths import saturated_centroid
    from poevp_optics.analysis.prediction_metrics import psnr

    a = saturated_centroid(pred, centre, radius=150)
    b = saturated_centroid(truth, centre, radius=150)
    err = float(np.hypot(*(a - b))) if np.all(np.isfinite(a)) else float("nan")
    pw, tw = window(pred, centre), window(truth, centre)
    sa, sb = pw >= 254.5, tw >= 254.5
    union = np.logical_or(sa, sb).sum()
    iou = float(np.logical_and(sa, sb).sum() / union) if union else 1.0
    return err, psnr(np.clip(pw, 0, 255), tw), iou


def run(speeds, kinds, predictors, log=print):
    from poevp_optics.analysis.motion_paths import PathSpec, render_sequence
    from poevp_optics.control.predictors import make_predictor

    models = {n: make_predictor(n) for n in predictors}
    rows, seconds = [], {n: [] for n in predictors}
    k = 0
    for kind in kinds:
        for v in speeds:
            for hname, hdeg in HEADINGS.items():
                k += 1
                seq = render_sequence(PathSpec(kind, float(v), hdeg, FRAMES), (368, 640), 9.0,
                                      text="QX 4821", seed=BENCH_SEED + k, noise_dn=1.0)
                for t in SCORED:
                    hist = [seq.frames[j] for j in range(t - 4, t)]
                    for n, m in models.items():
                        t0 = time.perf_counter()
                        pred = m(hist)
                        seconds[n].append(time.perf_counter() - t0)
                        err, p, iou = score(pred, seq.frames[t], seq.centre_px[t])
                        rows.append({"kind": kind, "speed": v, "heading": hname, "t": t, "predictor": n,
                                     "err": err, "psnr": p, "iou": iou})
            log(f"{kind} {v} px/frame done")
    return rows, seconds


def _med(rows, key, **sel):
    vals = [r[key] for r in rows if all(r[k] == v for k, v in sel.items())]
    vals = np.asarray(vals, dtype=np.float64)
    if np.all(np.isnan(vals)):
        return float("nan")
    return float(np.nanmedian(vals))


def tables(rows, speeds, kinds, predictors, seconds):
    out = []
    for key, title in (("err", "median centroid error, px (lower is better)"),
                       ("iou", "median mask IoU of the saturated region (higher is better)"),
                       ("psnr", "median PSNR near the highlight, dB")):
        header = ["kind", "px/frame", *predictors]
        body = [[kind, v, *[_med(rows, key, kind=kind, speed=v, predictor=n) for n in predictors]]
                for kind in kinds for v in speeds]
        out.append(f"### {title}\n\n{markdown_table(header, body)}\n")
    header = ["predictor", *HEADINGS, "max/min"]
    body = []
    for n in predictors:
        e = [_med([r for r in rows if r["speed"] >= 16 and r["kind"] != "reversal"], "err", heading=h, predictor=n)
             for h in HEADINGS]
        body.append([n, *e, max(e) / max(min(e), 1e-9)])
    out.append("### Direction bias: median centroid error (px) by heading, speeds >= 16, every kind but "
               f"reversal\n\n{markdown_table(header, body)}\n")
    header = ["predictor", "median ms at 368x640", "fps"]
    body = [[n, float(np.median(seconds[n]) * 1e3), 1.0 / float(np.median(seconds[n]))] for n in predictors]
    out.append(f"### Prediction time per frame on this machine (all cells' calls)\n\n{markdown_table(header, body)}\n")
    return "\n".join(out)


def criteria(rows, predictors):
    """The issue's bars: on curved/accelerating/braking/swerve at 16-48 px/frame the trained
    model's median error <= flow's / 1.5; straight within 1 px of flow's."""
    if "track_net" not in predictors or "flow" not in predictors:
        return ""
    lines = []
    for kind in ("curved", "accelerating", "braking", "swerve", "straight"):
        for v in sorted({r["speed"] for r in rows}):
            if v < 16:
                continue
            a = _med(rows, "err", kind=kind, speed=v, predictor="track_net")
            b = _med(rows, "err", kind=kind, speed=v, predictor="flow")
            ok = a <= b / 1.5 if kind != "straight" else a <= b + 1.0
            bar = "flow / 1.5" if kind != "straight" else "flow + 1 px"
            lines.append([kind, v, a, b, bar, "yes" if ok else "NO"])
    return ("### The issue's bars (track_net against flow)\n\n"
            + markdown_table(["kind", "px/frame", "track_net px", "flow px", "bar", "met"], lines) + "\n")


def plot(rows, speeds, kinds, predictors, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(kinds), figsize=(3.0 * len(kinds), 3.0), sharey=True, squeeze=False)
    for ax, kind in zip(axes[0], kinds):
        for n in predictors:
            ax.plot(speeds, [_med(rows, "err", kind=kind, speed=v, predictor=n) for v in speeds], marker="o", label=n)
        ax.set_title(kind)
        ax.set_xlabel("px/frame")
        ax.set_yscale("symlog", linthresh=1.0)
    axes[0][0].set_ylabel("median centroid error (px)")
    axes[0][-1].legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main(argv=None):
    from poevp_optics.analysis.motion_paths import KINDS
    from poevp_optics.core import runtime

    ap = argparse.ArgumentParser()
    ap.add_argument("--speeds", default="4,8,16,24,32,48")
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--predictors", default=",".join(PREDICTORS))
    add_results_flag(ap)
    a = ap.parse_args(argv)
    dest = output_folder(a.results)
    runtime.set_threads(2)
    speeds = [int(s) for s in a.speeds.split(",")]
    kinds = a.kinds.split(",")
    preds = a.predictors.split(",")
    t0 = time.perf_counter()
    rows, seconds = run(speeds, kinds, preds)
    text = (f"# Predictors on held-out motion (analysis/motion_paths.py, 368x640, E = 9)\n\n"
            f"{__doc__.split('Per cell')[0].split(chr(10), 2)[2].strip()}\n\n"
            f"Run: {time.perf_counter() - t0:.0f} s; machine: {machine_line()}. Plot: predictor_motion.png.\n\n"
            f"{criteria(rows, preds)}\n{tables(rows, speeds, kinds, preds, seconds)}")
    print(text)
    save_text(dest / "predictor_motion.md", text)
    plot(rows, speeds, kinds, preds, dest / "predictor_motion.png")


if __name__ == "__main__":
    main()
