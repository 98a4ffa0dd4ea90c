"""Paper Table 2 like for like: the paper's own simulation (apps/evaluate/paper_camera.py) on our LDR
demo sequence, beside the physical camera, and where the difference comes from.

Protocol (paper Sec. 6): scenes/ldr_highlight_demo (8 frames, 288x512, the plate's text in its
boxes CSV), E = 9, 29, 49, R = 50 px at 720x1280, Eq. 2 with (Vs, a, b) = (200, 0.9, 0), frames
2-7 scored (18 frames per method over the three E), full ALPR on the whole frame (PP-OCRv4
detection + recognition; a frame counts when every character matches, paper Eq. 4).

Rows: LDR, the two fusions, POE-VP with each predictor, under each of Eq. 2's three readings
(control/masks.py) in the paper's camera; then the oracle and the trained predictor with one
physical effect added at a time (DMD floor, mask smoothing, sensor noise, linear light, all
three without and with linear light), then the physical camera itself (`poevp evaluate` on the
same scene: DMD PWM, IMX253, relay, sRGB-decoded radiance) with Eq. 2's third reading and with
this project's exposure controller. Pooled with and without E = 49.

How to read it: the paper's numbers need Eq. 2's third reading (the other two cannot unclip a
clipped 8-bit prediction, whatever the predictor). From the paper's camera to ours, the DMD floor,
the mask smoothing and the sensor noise cost nothing measurable here; the loss is linear light:
the paper multiplies stored 8-bit values by (E G + 1), which as light (sRGB-decoded, extended above
1) is ~(E + 1)^2.4-fold, so a tenfold dimmer leaves the plate clipped at E = 29 and 49; the paper
camera with all four effects reads as the physical camera does. Our fusions read below the
paper's; we have not isolated why (the paper's ALPR Net and test plates versus PP-OCRv4 and one
demo plate here), so that gap stays unattributed.

    .venv/bin/python -m benchmarks.table2 [--results]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from benchmarks.common import add_results_flag, machine_line, markdown_table, output_folder, save_text

SCENE = Path(__file__).resolve().parent.parent / "scenes" / "ldr_highlight_demo"
E_LEVELS = (9.0, 29.0, 49.0)
LAWS = ("threshold_linear", "threshold_ratio", "threshold_exp")
PREDICTORS = ("oracle", "hold", "flow", "track_net", "dmvfn_lite")
#: Paper Table 2 (E = 9/29/49 averaged): recognition accuracy, %.
PAPER = {"fusion_classic": 65.07, "fusion_deghost": 88.56, "POE-VP": 94.86}


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    if n == 0:
        return 0.0, 100.0
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return 100 * max(0.0, c - h), 100 * min(1.0, c + h)


def reads(images: dict, seq, first: int = 2) -> list[bool]:
    from poevp_optics.analysis.recognition import alpr_read, correct

    out = []
    for t in sorted(images):
        if t < first or t not in seq.boxes:
            continue
        out.append(correct(alpr_read(images[t], seq.boxes[t]).text, seq.texts[t]))
    return out


def cell(ok: list[bool]) -> str:
    k, n = sum(ok), len(ok)
    lo, hi = wilson(k, n)
    return f"{k}/{n} = {100 * k / max(n, 1):.0f} % [{lo:.0f}-{hi:.0f}]"


def run(predictors, laws, log=print) -> dict:
    from poevp_optics.apps.evaluate import paper_camera as pc
    from poevp_optics.camera.sensor import resolve_sensor
    from poevp_optics.control.predictors import make_predictor
    from poevp_optics.scene.load import load_scene

    results: dict[tuple, dict[float, list[bool]]] = {}
    models = {p: None if p == "oracle" else make_predictor(p) for p in predictors}
    for e in E_LEVELS:
        spec = load_scene(SCENE, [f"source.e={e!r}", 'source.e_domain="display"', "source.r_px=50.0",
                                  'mask.vs=200.0', 'mask.a=0.9', 'mask.b=0.0'])
        seq = pc.paper_sequence(spec)
        sensor = resolve_sensor(spec.sensor)
        phys = dict(contrast_ratio=spec.dmd.contrast_ratio, saturation_e=sensor.saturation_capacity_e,
                    read_noise_e=sensor.read_noise_e)
        results.setdefault(("LDR", "-", "paper camera"), {})[e] = reads(pc.ldr_captures(seq), seq)
        lin = pc.PaperEffects(linear_light=True)
        results.setdefault(("LDR", "-", lin.label), {})[e] = reads(pc.ldr_captures(seq, lin), seq)
        for name, dg in (("fusion_classic", False), ("fusion_deghost", True)):
            results.setdefault((name, "-", "paper camera"), {})[e] = reads(pc.fusion_captures(seq, dg), seq)
        for law in laws:
            mask = dataclasses.replace(spec.mask, law=law)
            for p in predictors:
                caps, _ = pc.poevp_captures(seq, models[p], mask, pc.PaperEffects(), **phys)
                results.setdefault((f"POE-VP ({p})", law, pc.PaperEffects().label), {})[e] = reads(caps, seq)
        mask = dataclasses.replace(spec.mask, law=laws[0])
        for eff in (pc.PaperEffects(dmd_floor=True), pc.PaperEffects(smoothing=True), pc.PaperEffects(noise=True),
                    pc.PaperEffects(linear_light=True), pc.PaperEffects(True, True, True),
                    pc.PaperEffects(True, True, True, True)):
            for p in ("oracle", "track_net"):
                if p not in models:
                    continue
                caps, _ = pc.poevp_captures(seq, models[p], mask, eff, **phys, seed=int(e))
                results.setdefault((f"POE-VP ({p})", laws[0], eff.label), {})[e] = reads(caps, seq)
        log(f"E = {e:g} done")
    return results


def physical(predictors, law, baselines=(), log=print) -> dict:
    """The physical camera on the same protocol (`poevp evaluate` machinery, apps/evaluate/eval_paper.py)."""
    from poevp_optics.apps.evaluate.eval_paper import run_paper
    from poevp_optics.apps.evaluate.evaluate import EvalConfig, Runner, _shift_px, score_rows

    cfg = EvalConfig(scene=SCENE, predictors=tuple(p for p in predictors), baselines=tuple(baselines),
                     paper_law=law, loop_mode="open")
    rows = run_paper(cfg, Runner, score_rows, _shift_px, log=log)
    out: dict[tuple, dict[float, list[bool]]] = {}
    for r in rows:
        m = r["method"]
        name = "LDR" if m == "ldr" else m if m.startswith("fusion") else f"POE-VP ({m})"
        out.setdefault((name, "-" if name == "LDR" or name.startswith("fusion") else law, "physical camera"), {}).setdefault(float(r["E"]), []).append(bool(r["alpr_ok"]))
    return out


def table(results: dict) -> str:
    header = ["method", "Eq. 2 reading", "camera", *[f"E = {e:g}" for e in E_LEVELS], "pooled", "pooled without E = 49",
              "paper"]
    rows = []
    for (name, law, cam), by_e in results.items():
        allr = [x for e in E_LEVELS for x in by_e.get(e, [])]
        no49 = [x for e in E_LEVELS if e != 49 for x in by_e.get(e, [])]
        paper = PAPER.get(name) if name.startswith("fusion") else (
            PAPER["POE-VP"] if name.startswith("POE-VP") and cam == "paper camera" and law == LAWS[0] else None)
        rows.append([name, law, cam, *[cell(by_e.get(e, [])) for e in E_LEVELS], cell(allr), cell(no49),
                     f"{paper:.2f} %" if paper else ""])
    return markdown_table(header, rows)


def pooled(results: dict, key: tuple, without49: bool = False) -> float:
    ok = [x for e, v in results.get(key, {}).items() if not (without49 and e == 49) for x in v]
    return 100.0 * sum(ok) / max(len(ok), 1)


def summary(results: dict) -> str:
    """The headline figures, computed from the table (no hand-written numbers)."""
    pc_, law = "paper camera", LAWS[0]
    lines = [f"- Paper camera, Eq. 2 `{law}`: oracle {pooled(results, ('POE-VP (oracle)', law, pc_)):.0f} % pooled "
             f"(paper's POE-VP {PAPER['POE-VP']:.2f} %)"]
    for p in PREDICTORS[1:]:
        k = (f"POE-VP ({p})", law, pc_)
        if k in results:
            v = pooled(results, k)
            lines.append(f"- `{p}`: {v:.0f} % pooled, {pooled(results, k, True):.0f} % without E = 49 "
                         f"({v - PAPER['POE-VP']:+.1f} points from the paper's)")
    for other in LAWS[1:]:
        k = ("POE-VP (oracle)", other, pc_)
        if k in results:
            lines.append(f"- Eq. 2 `{other}`: the oracle reads {pooled(results, k):.0f} % pooled: a clipped 8-bit "
                         "prediction is not dimmed enough (control/masks.py)")
    for eff in ("DMD floor", "smoothing", "noise", "linear light"):
        k = ("POE-VP (oracle)", law, f"{pc_} + {eff}")
        if k in results:
            lines.append(f"- + {eff}: oracle {pooled(results, k):.0f} %, track_net "
                         f"{pooled(results, ('POE-VP (track_net)', law, f'{pc_} + {eff}')):.0f} % pooled")
    k = ("POE-VP (oracle)", law, "physical camera")
    if k in results:
        lines.append(f"- Physical camera: oracle {pooled(results, k):.0f} %, track_net "
                     f"{pooled(results, ('POE-VP (track_net)', law, 'physical camera')):.0f} % pooled")
    return "\n".join(lines)


def main(argv=None):
    from poevp_optics.core import runtime

    ap = argparse.ArgumentParser()
    ap.add_argument("--predictors", default=",".join(PREDICTORS))
    ap.add_argument("--no-physical", action="store_true")
    add_results_flag(ap)
    a = ap.parse_args(argv)
    dest = output_folder(a.results)
    runtime.set_threads(2)
    preds = a.predictors.split(",")
    t0 = time.perf_counter()
    res = run(preds, LAWS)
    if not a.no_physical:
        phys_preds = [p for p in preds if p != "dmvfn_lite"]
        res.update(physical(phys_preds, LAWS[0], ("ldr", "fusion_classic", "fusion_deghost")))
        res.update(physical(phys_preds, "exposure_controller"))
    text = (f"# Paper Table 2 like for like: the paper's simulation beside the physical camera\n\n"
            f"{__doc__.split(chr(10), 2)[2].split('    .venv/bin/python')[0].strip()}\n\n"
            f"Run: {time.perf_counter() - t0:.0f} s; machine: {machine_line()}. Cells: reads/frames = % "
            f"[Wilson 95 %].\n\n{summary(res)}\n\n{table(res)}\n")
    print(text)
    save_text(dest / "table2.md", text)


if __name__ == "__main__":
    main()
