"""Where each predictor puts the plate's highlight, frame by frame, at the speeds where `poevp
evaluate` stops reading: lateral motion at E = 9 on `highbeam_plate`, the evaluation's
own sequences (rendered once, cached by content), loop modes `open` and `demodulated`, the
scene's mask law (`exposure_controller`).

Per frame t and predictor, x positions on the sensor grid (px), each the centroid over the
plate's rows (its box grown by half its height):
  true     the highlight of what the predictor sees of frame t itself (what an exact predictor
           would predict): pixels >= 254.5 and >= half the brightest over the plate's rows, i.e.
           the clipped car in the open loop, the plate and car in the demodulated one;
  pred     the same of the prediction for t (the oracle: the truth itself);
  mask     the mask's dimming, weight 1 - level / top;
  err      pred - true (px; the signed error along the motion);
  sat %    plate-box pixels saturated in the encoded capture;
  read     full ALPR (PP-OCRv4 detection + recognition on the frame, paper Eq. 4).

    .venv/bin/python -m benchmarks.predictor_alignment [--speeds 24,32] [--E 9] [--loop-modes open,demodulated] [--results]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from benchmarks.common import add_results_flag, markdown_table, output_folder, save_text


class Recorder:
    """A predictor that keeps each prediction it makes (the loop step's model)."""

    def __init__(self, inner):
        self.inner, self.preds = inner, []
        self.name, self.needs_frames = inner.name, inner.needs_frames
        self.min_input_px = inner.min_input_px

    def __call__(self, history):
        p = self.inner(history)
        self.preds.append(np.asarray(p, dtype=np.float32))
        return p


def centroid_x(weight: np.ndarray, rows: slice) -> float:
    """x centroid (px) of `weight` over `rows`; NaN where the weight is all zero."""
    w = np.clip(np.asarray(weight, dtype=np.float64)[rows], 0, None)
    s = w.sum()
    return float((w.sum(0) * np.arange(w.shape[1])).sum() / s) if s > 0 else float("nan")


def hot(img: np.ndarray, rows: slice) -> np.ndarray:
    """The highlight of a frame on the 8-bit scale: pixels >= 254.5 (clipped, or above it in the
    demodulated loop) and >= half the brightest value over the plate's rows."""
    img = np.asarray(img, dtype=np.float64)
    return (img >= 254.5) & (img >= 0.5 * img[rows].max())


def plate_rows(box, shape) -> slice:
    y0, _, y1, _ = box
    m = (y1 - y0) // 2
    return slice(max(0, y0 - m), min(shape[0], y1 + m))


def run_cell(runner, ex, name: str, mode: str = "open") -> list[dict]:
    """One predictor over one scaled sequence: per-frame alignment rows."""
    from poevp_optics.analysis.metrics import to_8bit
    from poevp_optics.analysis.recognition import alpr_read
    from poevp_optics.control.loop_step import LoopStep, resize_to
    from poevp_optics.control.predictors import PREDICTORS, make_predictor
    from poevp_optics.core.seeds import ENCODED_STREAM, LDR_STREAM, capture_seed

    spec, cam = runner.spec, runner.cam
    seeds = (spec.sensor.seed, spec.render.seed)
    pspec = dataclasses.replace(spec.predictor, name=name)
    model = None if PREDICTORS[name].needs_truth else Recorder(make_predictor(name, pspec.weights, pspec.resolution))
    step = LoopStep(cam, spec.resolved.loop.mask, dataclasses.replace(spec.loop, mode=mode), pspec, model=model)
    top, rows = float(cam.top_level), []
    for e in ex:
        ldr = cam.capture(list(e.subframes), cam.white_mask(), e.index, capture_seed(*seeds, e.index, LDR_STREAM),
                          **e.capture_timing())
        n_pred = len(model.preds) if model else 0
        dec = step.next_mask(e.index, e.radiance.data)
        enc = cam.capture(list(e.subframes), dec.levels, e.index,
                          capture_seed(*seeds, e.index, ENCODED_STREAM), **e.capture_timing())
        est, flags, _ = cam.reconstruct(enc, e.index)
        step.observe(e.index, ldr, enc, est, flags)
        if dec.init:
            continue
        box = cam.box_to_sensor(e.roi)
        seen = resize_to(step.history[-1].array, cam.shape) if model else to_8bit(ldr.dn, cam.params.max_dn)
        rs = plate_rows(box, seen.shape)
        if model is not None and len(model.preds) > n_pred:
            pred = resize_to(model.preds[-1], cam.shape)
        else:
            pred = seen                                 # the oracle's law reads the true frame
        mask = cam.to_sensor(dec.levels)
        enc8 = to_8bit(enc.dn, cam.params.max_dn).astype(np.uint8)
        y0, x0, y1, x1 = box
        sat = float(np.mean(enc.dn[y0:y1, x0:x1] >= cam.params.max_dn)) * 100
        true_x = centroid_x(hot(seen, rs), rs)           # what the predictor sees of t itself
        pred_x = centroid_x(hot(pred, rs), rs)
        a = alpr_read(enc8, box)
        rows.append({"frame": e.index, "box_x": (x0 + x1) / 2, "true_x": true_x, "pred_x": pred_x,
                     "mask_x": centroid_x(1 - mask / top, rs), "err": pred_x - true_x, "sat": sat,
                     "text": a.text})
    return rows


def cell_rows(a, modes, speeds, es, preds, log=print):
    """Every per-frame row: (mode, speed, E, text, direction, predictor, row dict, read)."""
    from poevp_optics.analysis.recognition import correct
    from poevp_optics.apps.evaluate.eval_sequences import SequenceSpec, calibrate, peak_gain, render_sequences
    from poevp_optics.apps.evaluate.evaluate import EvalConfig, Runner, load_eval_scene, overexposure, scaled
    from poevp_optics.camera.camera import Camera

    cfg = EvalConfig(frames=a.frames)
    out = []
    for ti, text in enumerate(a.texts.split(",")):
        d = 1 if ti % 2 == 0 else -1                  # as apps/evaluate/evaluate.py plan()
        seqs = [SequenceSpec(text, "lateral", v, cfg.frames, d) for v in speeds]
        spec = load_eval_scene(cfg, text, cfg.frames)
        runner = Runner(cfg, spec, Camera.from_params(spec.resolved.camera))
        cal = calibrate(spec, runner.cam.guard_px)
        for seq, exps in zip(seqs, render_sequences(spec, seqs, cal, runner.cam.guard_px, log=log)):
            r0 = overexposure(runner.cam, exps)
            for e_level in es:
                ex = scaled(exps, peak_gain(e_level, cfg.e_reading) / r0)
                for mode in modes:
                    for name in preds:
                        for r in run_cell(runner, ex, name, mode):
                            out.append((mode, seq.speed_px, e_level, text, d, name, r, correct(r["text"], text)))
                            log(f"{mode} {seq.speed_px:g} {e_level:g} {text} {name} t={r['frame']} "
                                f"err {r['err']:+.1f} px sat {r['sat']:.0f} % read {out[-1][-1]}")
    return cfg, out


def plot(rows, path):
    """Signed error of the predicted highlight (px) per frame, one panel per (mode, speed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from benchmarks.common import save_figure

    panels = sorted({(m, v) for m, v, *_ in rows})
    fig, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 3.2), squeeze=False, sharey=True)
    for ax, (mode, v) in zip(axes[0], panels):
        for name in dict.fromkeys(r[5] for r in rows):
            pts = [(r[6]["frame"] + 0.08 * (r[4] > 0), r[6]["err"] * r[4], r[7]) for r in rows
                   if r[0] == mode and r[1] == v and r[5] == name]
            line = ax.plot([p[0] for p in pts], [p[1] for p in pts], "o", ms=4, label=name, alpha=0.8)[0]
            ax.plot([p[0] for p in pts if not p[2]], [p[1] for p in pts if not p[2]], "x", ms=9,
                    color=line.get_color())
        ax.axhline(-v, color="0.6", lw=0.8, ls="--")
        ax.set_title(f"loop {mode}, {v:g} px/frame")
        ax.set_xlabel("frame (x: not read)")
    axes[0][0].set_ylabel("predicted - true position along the motion (px)")
    axes[0][0].legend(fontsize=7)
    return save_figure(fig, path)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--speeds", default="24,32")
    ap.add_argument("--E", default="9")
    ap.add_argument("--predictors", default="hold,flow,track_net,dmvfn_lite,oracle")
    ap.add_argument("--texts", default="KA 7391,MH 2046")
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--loop-modes", default="open,demodulated")
    ap.add_argument("--out", default="predictor_alignment")
    add_results_flag(ap)
    a = ap.parse_args(argv)
    dest = output_folder(a.results)
    t0 = time.perf_counter()
    cfg, rows = cell_rows(a, a.loop_modes.split(","), [float(s) for s in a.speeds.split(",")],
                         [float(s) for s in a.E.split(",")], a.predictors.split(","))
    summary = {}
    for mode, v, e, text, d, name, r, ok in rows:
        s = summary.setdefault((mode, v, e, name), [0, 0, [], []])
        s[0], s[1] = s[0] + ok, s[1] + 1
        s[2].append(abs(r["err"]))
        s[3].append(r["sat"])
    summ = [[m, f"{v:g}", f"{e:g}", p, f"{n}/{k}", f"{np.nanmedian(err):.1f}", f"{np.mean(sat):.0f}"]
            for (m, v, e, p), (n, k, err, sat) in summary.items()]
    table = [[m, f"{v:g}", f"{e:g}", text, d, name, r["frame"], f"{r['box_x']:.1f}", f"{r['true_x']:.1f}",
              f"{r['pred_x']:.1f}", f"{r['err']:+.1f}", f"{r['mask_x']:.1f}", f"{r['sat']:.0f}", "yes" if ok else "no"]
             for m, v, e, text, d, name, r, ok in rows]
    png = plot(rows, dest / f"{a.out}.png")
    text = (f"# Predictor alignment: where each predictor puts the highlight (lateral motion)\n\n"
            f"{__doc__.split(chr(10) + chr(10))[1]}\n\n"
            f"`highbeam_plate` at {cfg.resolution[0]}x{cfg.resolution[1]}, {cfg.spp} spp, the evaluation's "
            f"sequences and seeds, frames >= 2 scored; the scene's mask law; {time.perf_counter() - t0:.0f} s. "
            f"Plot: {png.name} (error x direction: negative = behind the plate).\n\n"
            f"## Reads per cell (full ALPR), median |err|, mean plate saturation\n\n"
            + markdown_table(["loop", "px/frame", "E", "predictor", "read", "median abs err px", "sat %"], summ)
            + "\n\n## Per frame\n\n"
            + markdown_table(["loop", "px/frame", "E", "text", "dir", "predictor", "t", "box x", "true x",
                              "pred x", "err px", "mask x", "sat %", "read"], table) + "\n")
    print(save_text(dest / f"{a.out}.md", text))


if __name__ == "__main__":
    main()
