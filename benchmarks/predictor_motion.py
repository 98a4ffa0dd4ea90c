"""Predictors on motion of the training generator's kinds: where each one puts the highlight one
frame on, per motion kind, speed and direction.

Sequences: analysis/motion_paths.py (a textured car, a plate E = 9 over saturation in the paper's
Eq. 3 highlight, 368x640, 8-bit, 1 DN noise) on every kind at 4-48 px/frame and four headings
(right, left, down, up), seeds from their own stream (`BENCH_SEED`, apart from the training
splits of apps/train/train_track.py). The paths come from the generator the model was trained on
(analysis/motion_paths.py, its default shapes): a model can learn these shapes, so this table says
how well each predictor fits the training kinds, not how it does on traffic it never saw
(benchmarks/predictor_traffic.py: another generator, shapes and seeds). Each predictor gets the
four frames before frame t (the loop keeps four; two-frame predictors use the last two) and
predicts frame t; t = 4..7 are scored.

Per frame, near the true plate (a 96x160 window centred on it), on the 8-bit scale:
  centroid err   px between the saturated (>= 254.5) centroids of the prediction and of frame t
                 within 150 px of the plate: the mask's alignment; a prediction with no saturated
                 pixel there lost the highlight (a miss: infinite error, the worst frame);
  IoU            of the saturated regions in the window: the pixels the law dims against those
                 it must (0 for a miss);
  undimmed       fraction of frame t's saturated pixels in the window the prediction leaves
                 below saturation (the law leaves them white: they clip);
  PSNR           dB over the window.
A frame whose truth has no saturated pixel there is left out of every metric (counted). Cells
give median, p90 (the score 90 % of frames reach: the 10th percentile of IoU, the 90th of the
error) and worst frame over headings and frames.

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
    """{err, psnr, iou, undimmed} of one predicted frame (module docstring); NaN everywhere when
    the truth has no saturated pixel near the plate."""
    from poevp_optics.analysis.motion_paths import saturated_centroid
    from poevp_optics.analysis.prediction_metrics import psnr, saturated_iou, undimmed_fraction

    a = saturated_centroid(pred, centre, radius=150)
    b = saturated_centroid(truth, centre, radius=150)
    pw, tw = window(pred, centre), window(truth, centre)
    if not np.all(np.isfinite(b)) or not (tw >= 254.5).any():
        return {"err": float("nan"), "psnr": float("nan"), "iou": float("nan"), "undimmed": float("nan")}
    err = float(np.hypot(*(a - b))) if np.all(np.isfinite(a)) else float("inf")
    return {"err": err, "psnr": psnr(np.clip(pw, 0, 255), tw), "iou": saturated_iou(pw, tw),
            "undimmed": undimmed_fraction(pw, tw)}


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
                        rows.append({"kind": kind, "speed": v, "heading": hname, "t": t, "predictor": n,
                                     **score(pred, seq.frames[t], seq.centre_px[t])})
            log(f"{kind} {v} px/frame done")
    return rows, seconds


HIGHER_IS_BETTER = {"err": False, "psnr": True, "iou": True, "undimmed": False}


def _vals(rows, key, **sel):
    return [r[key] for r in rows if all(r[k] == v for k, v in sel.items())]


def _tail(rows, key, **sel):
    from poevp_optics.analysis.prediction_metrics import tail

    return tail(_vals(rows, key, **sel), HIGHER_IS_BETTER[key])


def _med(rows, key, **sel):
    return _tail(rows, key, **sel)["median"]


def _fmt(v: float) -> str:
    return "miss" if v == float("inf") else f"{v:.3g}"


def _cell(rows, key, **sel) -> str:
    t = _tail(rows, key, **sel)
    return "-" if t["n"] == 0 else f"{_fmt(t['median'])} / {_fmt(t['p90'])} / {_fmt(t['worst'])}"


def tables(rows, speeds, kinds, predictors, seconds):
    out = []
    header = ["kind", "frames", "left out", *[f"{n} mean / p90 / worst" for n in predictors]]
    body = []
    for kind in (*kinds, "all"):
        sel = {} if kind == "all" else {"kind": kind}
        first = _tail(rows, "iou", predictor=predictors[0], **sel)
        cells = []
        for n in predictors:
            t = _tail(rows, "iou", predictor=n, **sel)
            cells.append(f"{t['mean']:.3f} / {t['p90']:.3f} / {t['worst']:.3f}")
        body.append([kind, first["n"], first["left_out"], *cells])
    out.append("### Saturated-region IoU per kind, every speed (higher is better)\n\n"
               f"{markdown_table(header, body)}\n")
    header = ["kind", *[f"{n}" for n in predictors]]
    body = [[kind, *[f"{_tail(rows, 'undimmed', predictor=n, **({} if kind == 'all' else {'kind': kind}))['mean']:.4f}"
                     for n in predictors]] for kind in (*kinds, "all")]
    out.append("### Mean fraction of truly saturated pixels left undimmed, every speed (lower is better)\n\n"
               f"{markdown_table(header, body)}\n")
    for key, title in (("err", "centroid error, px: median / p90 / worst (lower is better; miss: the "
                               "prediction lost the highlight)"),
                       ("iou", "saturated-region IoU: median / p90 / worst (higher is better)"),
                       ("psnr", "PSNR near the highlight, dB: median / p90 / worst")):
        header = ["kind", "px/frame", *predictors]
        body = [[kind, v, *[_cell(rows, key, kind=kind, speed=v, predictor=n) for n in predictors]]
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
    """Bars of the trained model on the training kinds: on curved/accelerating/braking/swerve at
    16-48 px/frame its median error <= flow's / 1.5; straight within 1 px of flow's."""
    if "track_net" not in predictors or "flow" not in predictors:
        return ""
    lines = []
    for kind in ("curved", "accelerating", "braking", "swerve", "straight"):
        for v in sorted({r["speed"] for r in rows}):
            if v < 16 or not _vals(rows, "err", kind=kind, speed=v):
                continue
            a = _med(rows, "err", kind=kind, speed=v, predictor="track_net")
            b = _med(rows, "err", kind=kind, speed=v, predictor="flow")
            ok = a <= b / 1.5 if kind != "straight" else a <= b + 1.0
            bar = "flow / 1.5" if kind != "straight" else "flow + 1 px"
            lines.append([kind, v, a, b, bar, "yes" if ok else "NO"])
    return ("### Bars on the training kinds (track_net against flow, median centroid error)\n\n"
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
    text = (f"# Predictors on the training generator's motion kinds (analysis/motion_paths.py, 368x640, E = 9)\n\n"
            f"{__doc__.split('    .venv/bin/python')[0].split(chr(10), 2)[2].strip()}\n\n"
            f"Run: {time.perf_counter() - t0:.0f} s; machine: {machine_line()}. Plot: predictor_motion.png.\n\n"
            f"{criteria(rows, preds)}\n{tables(rows, speeds, kinds, preds, seconds)}")
    print(text)
    save_text(dest / "predictor_motion.md", text)
    plot(rows, speeds, kinds, preds, dest / "predictor_motion.png")


if __name__ == "__main__":
    main()
