"""Predictors on held-out traffic: the whole frame's highlights one frame on, on motion drawn by a
generator the learned predictor never saw.

Scenes: analysis/traffic_paths.py (a dark road at 368x640, 8-bit, 1-2 DN noise; several vehicles
with two headlamps 200-600x and a plate 55-70x over saturation each, a street lamp and a parked
car; families approach (growth), turn, stop_and_go (intelligent driver model), lane_change,
entering (from the frame's edge), crossing (two vehicles), shake (camera pitch bounce and yaw
drift); the main vehicle at 8-48 px/frame). Its generator, its shape parameters (ranges outside
the training's: `check_disjoint`) and its seeds (`BENCH_SEED`) are disjoint from the training
set's (apps/train/train_track.py on analysis/motion_paths.py), and no benchmark displacement
chain is a training chain (tests/unit/test_traffic_paths.py). Each predictor gets the four frames
before frame t and predicts frame t; t = 4..11 are scored, over the whole frame:

  IoU        of the saturated (>= 254.5) regions of prediction and truth: the pixels the mask
             law dims against those it must; a prediction that loses a highlight scores that
             highlight's pixels as misses (IoU 0 when it loses all);
  undimmed   fraction of the truly saturated pixels the prediction leaves below saturation
             (the law leaves those mirrors white: they clip).
A frame with no saturated pixel in the truth is left out of every metric (counted). Tables give
mean, p90 (the IoU 90 % of frames reach: its 10th percentile) and worst frame.

    .venv/bin/python -m benchmarks.predictor_traffic [--per-cell 2] [--families ...] [--predictors ...] [--results]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from benchmarks.common import add_results_flag, machine_line, markdown_table, output_folder, save_text

PREDICTORS = ("hold", "flow", "dmvfn_lite", "dmvfn", "track", "track_net")
CLASSICAL = ("flow", "track")
CONTEXT = 4
#: Frame rate the learned predictor must reach at 368x640 on the CPU: the camera's 30 fps video.
TARGET_FPS = 30.0


#: Names of the bounds' rows (not causal predictors: they read the scene's true motion):
#: the true step for the regions followed back three frames, and for every region.
BOUND = "true_chains"
BOUND_ALL = "true_motion"


def true_chain_predictor(every_region: bool = False):
    """`track_net` with the true next displacement (the nearest light's, analysis/traffic_paths.py
    `light_tracks`) for every region it followed back the full three frames, its own prediction
    for the rest (new regions, short chains): what a perfect extrapolation of the chains the
    tracker measures would score. every_region: the true step for new regions and short chains
    too (what knowing every light's next step would score, with the tracker's regions, growth
    and pixel moves). Set `.lights` (per scene) and `.t` (the frame predicted)."""
    from poevp_optics.control.predictors import make_predictor
    from poevp_optics.control.predictors.track import MAX_CHAIN
    from poevp_optics.control.predictors.track_net import TrackNetPredictor

    base = make_predictor("track_net")

    class TrueChains(TrackNetPredictor):
        def next_displacement(self, tracks):
            own = super().next_displacement(tracks)
            out = []
            for tr, d in zip(tracks, own):
                y0, x0, y1, x1 = tr.box
                c = np.array([(x0 + x1) / 2.0, (y0 + y1) / 2.0])
                near = min(self.lights, key=lambda p: float(np.hypot(*(p[self.t - 1] - c))))
                full = every_region or len(tr.displacements) == MAX_CHAIN
                out.append(near[self.t] - near[self.t - 1] if full else d)
            return out

    return TrueChains(base.layers, base.weights_path, base.meta)


def run(cases, predictors, log=print):
    """Per-frame rows {family, speed, seed, t, predictor, iou, undimmed} and prediction times
    {predictor: [(wall s, CPU s of this process), ...]}; with track_net, rows of `BOUND` too
    (`true_chain_predictor`)."""
    from poevp_optics.analysis.prediction_metrics import saturated_iou, undimmed_fraction
    from poevp_optics.analysis.traffic_paths import draw_scene, light_tracks
    from poevp_optics.control.predictors import make_predictor

    models = {n: make_predictor(n) for n in predictors}
    bounds = {BOUND: true_chain_predictor(), BOUND_ALL: true_chain_predictor(every_region=True)} \
        if "track_net" in predictors else {}
    rows, seconds = [], {n: [] for n in predictors}
    for i, (family, v, seed) in enumerate(cases):
        scene = draw_scene(family, v, seed)
        for bound in bounds.values():
            bound.lights = light_tracks(scene)
        for t in range(CONTEXT, len(scene.frames)):
            hist = list(scene.frames[t - CONTEXT:t])
            truth = scene.frames[t]
            for n, m in models.items():
                t0, c0 = time.perf_counter(), time.process_time()
                pred = m(hist)
                seconds[n].append((time.perf_counter() - t0, time.process_time() - c0))
                rows.append({"family": family, "speed": v, "seed": seed, "t": t, "predictor": n,
                             "iou": saturated_iou(pred, truth), "undimmed": undimmed_fraction(pred, truth)})
            for name, bound in bounds.items():
                bound.t = t
                pred = bound(hist)
                rows.append({"family": family, "speed": v, "seed": seed, "t": t, "predictor": name,
                             "iou": saturated_iou(pred, truth), "undimmed": undimmed_fraction(pred, truth)})
        if (i + 1) % 10 == 0 or i + 1 == len(cases):
            log(f"{i + 1}/{len(cases)} scenes")
    return rows, seconds


def _tail(rows, key, higher=True, **sel):
    from poevp_optics.analysis.prediction_metrics import tail

    return tail([r[key] for r in rows if all(r[k] == v for k, v in sel.items())], higher)


def summary(rows, families, predictors) -> dict:
    """{predictor: {family or 'all': {iou: tail, undimmed: tail}}}."""
    out = {}
    for n in predictors:
        out[n] = {}
        for fam in (*families, "all"):
            sel = {"predictor": n, **({} if fam == "all" else {"family": fam})}
            out[n][fam] = {"iou": _tail(rows, "iou", True, **sel), "undimmed": _tail(rows, "undimmed", False, **sel)}
    return out


def bars(summ, families, predictors) -> str:
    """The learned predictor's bars: mean IoU >= best classical + 0.05; >= hold's in every
    family; the lowest undimmed fraction of the causal predictors."""
    if "track_net" not in predictors or not set(CLASSICAL) <= set(predictors) or "hold" not in predictors:
        return ""
    mean = {n: summ[n]["all"]["iou"]["mean"] for n in predictors}
    best = max(CLASSICAL, key=lambda n: mean[n])
    lines = [["mean IoU >= best classical + 0.05", f"{mean['track_net']:.3f}",
              f"{best} {mean[best]:.3f} + 0.05", "yes" if mean["track_net"] >= mean[best] + 0.05 else "NO"]]
    for fam in families:
        a, b = summ["track_net"][fam]["iou"]["mean"], summ["hold"][fam]["iou"]["mean"]
        lines.append([f"{fam}: mean IoU >= hold's", f"{a:.3f}", f"{b:.3f}", "yes" if a >= b else "NO"])
    und = {n: summ[n]["all"]["undimmed"]["mean"] for n in predictors}
    low = min(und, key=und.get)
    lines.append(["lowest undimmed fraction", f"{und['track_net']:.4f}", f"{low} {und[low]:.4f}",
                  "yes" if low == "track_net" else "NO"])
    text = ("### Bars for the learned predictor (track_net)\n\n"
            + markdown_table(["bar", "track_net", "against", "met"], lines) + "\n")
    leads = {BOUND: "\nWhat a perfect extrapolation of the measured chains would score (not a predictor: it "
                    "reads the true motion): track_net with each light's true next displacement wherever it was "
                    "followed back the full three frames, ",
             BOUND_ALL: "With the true next displacement for every region, new ones and short chains too (a light "
                        "entering, appearing beside another, or parting from a merge: what no past frame shows), "}
    for name, lead in leads.items():
        if name in summ:
            b = summ[name]
            text += (f"{lead}{b['all']['iou']['mean']:.3f} mean IoU ("
                     + ", ".join(f"{f} {b[f]['iou']['mean']:.3f}" for f in families) + ").\n")
    return text


def tables(rows, summ, families, predictors, speeds, seconds) -> str:
    out = []
    header = ["predictor", *families, "mean"]
    body = [[n, *[f"{summ[n][f]['iou']['mean']:.3f}" for f in families], f"{summ[n]['all']['iou']['mean']:.3f}"]
            for n in predictors]
    out.append(f"### Mean saturated-region IoU per family (higher is better)\n\n{markdown_table(header, body)}\n")
    body = [[n, *[f"{summ[n][f]['iou']['p90']:.3f} / {summ[n][f]['iou']['worst']:.3f}" for f in families],
             f"{summ[n]['all']['iou']['p90']:.3f} / {summ[n]['all']['iou']['worst']:.3f}"] for n in predictors]
    out.append("### Saturated-region IoU: p90 / worst frame per family\n\n"
               f"{markdown_table(header, body)}\n")
    body = [[n, *[f"{summ[n][f]['undimmed']['mean']:.4f}" for f in families], f"{summ[n]['all']['undimmed']['mean']:.4f}"]
            for n in predictors]
    out.append("### Mean fraction of truly saturated pixels left undimmed (lower is better)\n\n"
               f"{markdown_table(header, body)}\n")
    header = ["predictor", *[f"{v:g} px/frame" for v in speeds]]
    body = [[n, *[f"{_tail(rows, 'iou', True, predictor=n, speed=v)['mean']:.3f}" for v in speeds]] for n in predictors]
    out.append(f"### Mean saturated-region IoU per speed of the main vehicle, every family\n\n{markdown_table(header, body)}\n")
    first = summ[predictors[0]]
    out.append("Frames scored per family (left out: no true highlight): "
               + ", ".join(f"{f} {first[f]['iou']['n']} ({first[f]['iou']['left_out']})" for f in families) + ".\n")
    header = ["predictor", "median wall ms at 368x640", "fps (wall)", "median CPU ms (both threads)"]
    body = []
    for n in predictors:
        wall, cpu = np.median(np.asarray(seconds[n]), axis=0)
        body.append([n, float(wall * 1e3), 1.0 / float(wall), float(cpu * 1e3)])
    out.append("### Prediction time per frame on this machine (all calls; several lights per frame)\n\n"
               "Wall time on a shared 2-core machine varies with its other load; CPU time is this "
               f"process's own.\n\n{markdown_table(header, body)}\n")
    if "track_net" in predictors:
        wall, cpu = np.median(np.asarray(seconds["track_net"]), axis=0)
        fps = 1.0 / float(cpu)
        out.append(f"track_net at 368x640 on this CPU: {fps:.1f} frames per second by its own CPU time "
                   f"({cpu * 1e3:.1f} ms a frame, median; what the predictor costs a core it has to itself: on "
                   f"an idle machine wall and CPU time agree to a few per cent), {1.0 / float(wall):.1f} by the "
                   f"wall clock of this run (load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores while "
                   f"it ran); target {TARGET_FPS:g} fps: {'met' if fps >= TARGET_FPS else 'NOT met'}.\n")
    return "\n".join(out)


def main(argv=None):
    from poevp_optics.analysis.motion_paths import TRAINING_SHAPES
    from poevp_optics.analysis.traffic_paths import FAMILIES, SCENES_PER_CELL, SPEEDS_PX, bench_cases, check_disjoint
    from poevp_optics.core import runtime

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-cell", type=int, default=SCENES_PER_CELL, help="scenes per family and speed")
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--predictors", default=",".join(PREDICTORS))
    add_results_flag(ap)
    a = ap.parse_args(argv)
    dest = output_folder(a.results)
    runtime.set_threads(2)
    families, preds = a.families.split(","), a.predictors.split(",")
    overlap = check_disjoint(TRAINING_SHAPES)
    if overlap:
        raise SystemExit("predictor_traffic: the benchmark's shapes overlap the training's: " + "; ".join(overlap))
    cases = bench_cases(SPEEDS_PX, a.per_cell, families)
    t0 = time.perf_counter()
    rows, seconds = run(cases, preds)
    summ = summary(rows, families, preds + ([BOUND, BOUND_ALL] if "track_net" in preds else []))
    doc = __doc__.split("    .venv/bin/python")[0].split("\n", 2)[2].strip()
    text = (f"# Predictors on held-out traffic (analysis/traffic_paths.py, 368x640)\n\n{doc}\n\n"
            f"Disjoint from training: generator analysis/traffic_paths.py (training: analysis/motion_paths.py), "
            f"shape ranges checked apart ({len(check_disjoint(TRAINING_SHAPES))} overlaps), seeds from "
            f"{cases[0][2]} on (training: 0-2,300,000). {len(cases)} scenes ({a.per_cell} per family and speed), "
            f"{sum(r['predictor'] == preds[0] for r in rows)} frames per predictor.\n\n"
            f"Run: {time.perf_counter() - t0:.0f} s; machine: {machine_line()}.\n\n"
            f"{bars(summ, families, preds)}\n{tables(rows, summ, families, preds, SPEEDS_PX, seconds)}")
    print(text)
    save_text(dest / "predictor_traffic.md", text)


if __name__ == "__main__":
    main()
