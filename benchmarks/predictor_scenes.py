"""Predictors on the physically rendered scene library: the whole frame's highlights one frame on,
in scenes no shipped predictor was trained on.

Scenes: the scene library (benchmarks/scene_library.py LIBRARY), each rendered by Mitsuba to
absolute spectral radiance and taken by the camera with every mirror white (the loop's LDR twin:
what a predictor sees in loop mode `open`), 21 frames, at --scale x the scenes' 1920x1080 mirrors
and at our own beams x 1 and x 10 (re-rendered, as benchmarks/scene_library.py scales them).
None of these scenes is in a shipped predictor's training data: `track_net` learns from the
image-space paths of analysis/motion_paths.py, the DMVFNs from renders of scenes/highbeam_plate
(their records say so; tests/unit/test_predictor_scenes.py reads them). Each predictor gets the
four frames before frame t and predicts frame t; t = 4..20 are scored, over the whole frame:

  IoU        of the saturated (>= 254.5) regions of prediction and truth, and
  undimmed   the fraction of the truly saturated pixels the prediction leaves below saturation,
             as in benchmarks/predictor_traffic.py (a frame with no true highlight left out);
  switched   of the pixels whose saturation changed from frame t-1 to t (a light moving,
             appearing or going out), the fraction the prediction gets right: 0 for `hold` by
             construction; a frame where nothing switched is left out.
Standing lights (street lamps, a queue's lamps at rest, fog's glow) weigh in the IoU as much as
moving ones, so a scene of standing lights scores every predictor near 1 and `hold` best; the
switched column is the motion alone.

    .venv/bin/python -m benchmarks.predictor_scenes [--scale 1/3] [--gains 1,10] [--scenes ...] [--predictors ...] [--results]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.common import ROOT, add_results_flag, machine_line, markdown_table, output_folder, save_text
from benchmarks.scene_library import LIBRARY

PREDICTORS = ("hold", "flow", "dmvfn_lite", "dmvfn", "track", "track_net")
CONTEXT = 4
FRAMES = 21
METRICS = (("iou", True), ("undimmed", False), ("switched", True))


def scene_frames(name: str, scale: float, gain: float, frames: int = FRAMES) -> tuple[np.ndarray, float]:
    """((frames, H, W) uint8 LDR-twin captures of a library scene at `scale` x its mirrors with
    our beams x `gain`, render and capture seconds)."""
    from benchmarks.loop_alpr import scene_sets
    from poevp_optics.analysis.metrics import to_8bit
    from poevp_optics.apps.run.render_run import capture_inputs
    from poevp_optics.camera.camera import Camera
    from poevp_optics.core.seeds import LDR_STREAM, capture_seed
    from poevp_optics.render.radiance import open_source
    from poevp_optics.scene.load import load_scene

    scene = str(ROOT / "scenes" / name)
    sets, _, _, _ = scene_sets(scene, scale, frames, gain, 0, "open")
    spec = load_scene(scene, sets)
    t0 = time.perf_counter()
    cam = Camera.from_params(spec.resolved.camera)
    out = []
    for ex in open_source(spec.resolved.render, cam.guard_px).exposures(False):
        subs, timing = capture_inputs(spec, ex)
        seed = capture_seed(spec.sensor.seed, spec.render.seed, ex.index, LDR_STREAM)
        ldr = cam.capture(subs, cam.white_mask(), ex.index, seed, **timing)
        out.append(to_8bit(ldr.dn, cam.params.max_dn).astype(np.uint8))
    return np.stack(out), time.perf_counter() - t0


def score(frames: np.ndarray, models: dict, cell: str, context: int = CONTEXT) -> tuple[list[dict], dict]:
    """Per-frame rows {cell, t, predictor, iou, undimmed, switched} of every model on one
    sequence, and prediction wall seconds {predictor: [s, ...]}."""
    from poevp_optics.analysis.prediction_metrics import saturated_iou, switched_right, undimmed_fraction

    rows, seconds = [], {n: [] for n in models}
    seq = frames.astype(np.float32)
    for t in range(context, len(seq)):
        hist, truth = list(seq[t - context:t]), seq[t]
        for n, m in models.items():
            t0 = time.perf_counter()
            pred = m(hist)
            seconds[n].append(time.perf_counter() - t0)
            rows.append({"cell": cell, "t": t, "predictor": n, "iou": saturated_iou(pred, truth),
                         "undimmed": undimmed_fraction(pred, truth), "switched": switched_right(pred, hist[-1], truth)})
    return rows, seconds


def summary(rows: list[dict], cells: list[str], predictors: list[str]) -> dict:
    """{predictor: {cell or 'all': {metric: tail}}} (analysis/prediction_metrics.py `tail`)."""
    from poevp_optics.analysis.prediction_metrics import tail

    out = {}
    for n in predictors:
        out[n] = {}
        for c in (*cells, "all"):
            sel = [r for r in rows if r["predictor"] == n and (c == "all" or r["cell"] == c)]
            out[n][c] = {k: tail([r[k] for r in sel], hi) for k, hi in METRICS}
    return out


def tables(summ: dict, cells: list[str], predictors: list[str]) -> str:
    """The page's tables: mean IoU, p90 / worst IoU, undimmed and switched per cell."""
    header = ["predictor", *cells, "all"]
    out = []
    for key, title, fmt in (("iou", "Mean saturated-region IoU (higher is better)", "{:.3f}"),
                            ("undimmed", "Mean fraction of truly saturated pixels left undimmed (lower is better)", "{:.4f}"),
                            ("switched", "Mean fraction of the switched pixels predicted right (higher is better)", "{:.3f}")):
        body = [[n, *[fmt.format(summ[n][c][key]["mean"]) for c in (*cells, "all")]] for n in predictors]
        out.append(f"### {title}\n\n{markdown_table(header, body)}\n")
        if key == "iou":
            body = [[n, *[f"{summ[n][c]['iou']['p90']:.3f} / {summ[n][c]['iou']['worst']:.3f}" for c in (*cells, "all")]]
                    for n in predictors]
            out.append(f"### Saturated-region IoU: p90 / worst frame\n\n{markdown_table(header, body)}\n")
    first = summ[predictors[0]]
    out.append("Frames scored per cell, IoU (left out: no true highlight) and switched (left out: nothing "
               "switched): " + ", ".join(f"{c} {first[c]['iou']['n']} ({first[c]['iou']['left_out']}) and "
                                         f"{first[c]['switched']['n']} ({first[c]['switched']['left_out']})"
                                         for c in cells) + ".\n")
    best = {key: max(predictors, key=lambda n: summ[n]["all"][key]["mean"]) for key in ("iou", "switched")}
    low = min(predictors, key=lambda n: summ[n]["all"]["undimmed"]["mean"])
    out.append(f"Over every cell: highest mean IoU `{best['iou']}`, lowest undimmed fraction `{low}`, most "
               f"switched pixels right `{best['switched']}`.\n")
    return "\n".join(out)


def main(argv=None):
    from poevp_optics.analysis.prediction_metrics import SATURATED_8BIT
    from poevp_optics.control.predictors import make_predictor
    from poevp_optics.core import runtime
    from poevp_optics.scene.scale import parse_scale, scale_text

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default=",".join(LIBRARY))
    ap.add_argument("--scale", default="1/3", help="x the scenes' 1920x1080 mirrors")
    ap.add_argument("--gains", default="1,10", help="x our own beams' intensity")
    ap.add_argument("--predictors", default=",".join(PREDICTORS))
    add_results_flag(ap)
    a = ap.parse_args(argv)
    dest = output_folder(a.results)
    runtime.set_threads(2)
    scale = parse_scale(a.scale)
    preds = a.predictors.split(",")
    models = {n: make_predictor(n) for n in preds}
    doc = __doc__.split("    .venv/bin/python")[0].split("\n", 2)[2].strip()
    t0 = time.perf_counter()
    rows, cells, runs, seconds = [], [], [], {n: [] for n in preds}
    for name in a.scenes.split(","):
        for gain in (float(g) for g in a.gains.split(",")):
            frames, render_s = scene_frames(name, scale, gain)
            cell = f"{name} x{gain:g}"
            r, s = score(frames, models, cell)
            rows += r
            for n in preds:
                seconds[n] += s[n]
            cells.append(cell)
            sat = frames >= SATURATED_8BIT
            runs.append([cell, f"{frames.shape[1]}x{frames.shape[2]}", len(frames), f"{render_s:.0f}",
                         f"{100 * float(np.mean(sat[CONTEXT:])):.2f}",
                         f"{float(np.mean((sat[CONTEXT:] != sat[CONTEXT - 1:-1]).sum(axis=(1, 2)))):.0f}"])
            print(f"{cell}: rendered in {render_s:.0f} s", flush=True)
            text = (f"# Predictors on the rendered scene library ({scale_text(scale)} of the scenes' mirrors)\n\n"
                    f"{doc}\n\nRun: {time.perf_counter() - t0:.0f} s; machine: {machine_line()}.\n\n"
                    + markdown_table(["cell", "frame size", "frames", "render + capture s", "saturated pixels %",
                                      "switched pixels a frame"],
                                     runs) + "\n\n" + tables(summary(rows, cells, preds), cells, preds)
                    + "\nPrediction wall time a frame, median over every cell (this machine, other jobs may share it): "
                    + ", ".join(f"{n} {1e3 * float(np.median(seconds[n])):.3g} ms" for n in preds) + ".\n")
            save_text(dest / "predictor_scenes.md", text)
    print(text)


if __name__ == "__main__":
    main()
