"""Full-ALPR reads in the closed loop: the learned predictor (`track_net`) against flow, track,
the oracle (ceiling) and hold (floor), every predictor on the same render of the scene.

    .venv/bin/python -m benchmarks.loop_alpr [--scenes night_road@1/2:1,city_night@1/2,highbeam_plate] \
        [--predictors oracle,hold,flow,track,track_net] [--gains 1,10] [--texts 2] [--frames 21] [--results]

Per scene (`name@scale:texts`: the camera at scale x the scene's own mirrors, as `poevp render
--scale`, no @: --scale; `texts` text sets, none given: --texts), beam gain g (our own beams'
spectrum x g, as benchmarks/scene_library.py scales them) and plate text set (set 0: the scene's
own texts; set j > 0: each plate's own text with its letters and digits substituted, no I, O or Q:
`alt_text`), the scene is rendered once (render/radiance.py `open_source`) and each predictor runs
the causal loop over those exposures (`run_frames`, as `poevp compare` does), in the loop mode
--mode (demodulated: the predictor sees the camera's reconstructions). Scenes with vehicles record
every plate (`render.roi_shape = "plates"`); a scene with one [plate] keeps its own region of
interest, that plate.

Read: whole-frame ALPR (analysis/recognition.py `alpr_read`: PP-OCRv4 detection + recognition on
the whole 8-bit capture, the detections over the plate joined, every character must match) on each
loop frame after the white initialisation frames where the plate is in view and >= --min-height
px tall (`eligible`). The frames counted are the same for every predictor (the plate's geometry
does not depend on the mask). A cell (scene x plate x gain, pooled over the text sets) gives
reads/frames and the Wilson 95 % interval (analysis/statistics.py) per predictor, and the verdict
(`verdict`): track_net's read rate at or above the lower end of flow's interval (not below flow
within the interval), and whether it is higher than flow's.

Writes loop_alpr.md (and loop_alpr_examples.png: the frames where track_net and flow disagree)
into out/benchmarks/ (benchmarks/results/ with --results), rewritten after every render.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from benchmarks.common import ROOT, add_results_flag, cpu_seconds, machine_line, markdown_table, output_folder, save_text

SCENES = ["highbeam_plate@1", "city_night@1/2", "night_road@1/2:1", "toll_or_junction@2/3:1",
          "heldout_swerve@1:1", "heldout_receding@1:1"]
PREDICTORS = ["oracle", "hold", "flow", "track", "track_net"]
LEARNED, CLASSICAL = "track_net", "flow"
MIN_HEIGHT_PX = 20


# ----------------------------------------------------------------------------------------------
# Counting and verdict (pure: tests/unit/test_loop_alpr.py)

def eligible(per_frame: list[dict], min_height: int, single_id: str = "plate") -> list[tuple[int, str, tuple]]:
    """(frame index, plate id, sensor box (y0, x0, y1, x1)) of every plate to read in a run's
    report.json `per_frame`: frames after the white initialisation frames (`init` false), plate
    in view with a box >= min_height px tall. Frames with per-plate records (`plates`, from
    render.roi_shape = "plates") give each plate; otherwise the frame's region of interest
    (`roi`) is the one plate, named `single_id`."""
    out = []
    for f, plates in loop_plates(per_frame, single_id):
        for p in plates:
            if p.get("in_view") and p.get("box") and (p.get("height_px") or 0) >= min_height:
                out.append((int(f["index"]), p["id"], tuple(int(v) for v in p["box"])))
    return out


def loop_plates(per_frame: list[dict], single_id: str = "plate") -> list[tuple[dict, list[dict]]]:
    """(frame, its plate records) for each loop frame (after the white initialisation frames):
    the per-plate records where the run made them, else the region of interest as one plate
    named `single_id`."""
    out = []
    for f in per_frame:
        if f.get("init"):
            continue
        plates = f.get("plates")
        if plates is None:
            roi = f.get("roi")
            plates = [{"id": single_id, "in_view": roi is not None, "box": roi,
                       "height_px": (roi[2] - roi[0]) if roi else None}]
        out.append((f, plates))
    return out


def tally(reads: list[tuple[str, bool]]) -> dict[str, tuple[int, int]]:
    """{plate id: (frames read, frames counted)} from (plate id, read?) pairs."""
    out: dict[str, tuple[int, int]] = {}
    for ident, ok in reads:
        k, n = out.get(ident, (0, 0))
        out[ident] = (k + bool(ok), n + 1)
    return out


def verdict(learned: tuple[int, int], classical: tuple[int, int]) -> tuple[bool, bool]:
    """(not below, higher) of the learned predictor's reads (k, n) against the classical one's:
    not below = its read rate k/n is at or above the lower end of the classical rate's Wilson 95 %
    interval; higher = its rate exceeds the classical rate. n = 0 on either side: (True, False)
    (nothing to compare)."""
    from poevp_optics.analysis.statistics import wilson_interval

    (k1, n1), (k2, n2) = learned, classical
    if n1 == 0 or n2 == 0:
        return True, False
    lo, _ = wilson_interval(k2, n2)
    return k1 / n1 >= lo, k1 * n2 > k2 * n1


#: Letters of the substituted texts: A-Z without I, O and Q, which the plate font draws like 1, 0
#: and O (German plates leave them out of the serial for that reason), so that a substituted text
#: tests the loop's exposure, not the recogniser's confusion of look-alike glyphs.
ALT_LETTERS = "ABCDEFGHJKLMNPRSTUVWXYZ"


def alt_text(text: str, j: int) -> str:
    """Text set j's plate text: each letter (index a in A-Z) -> ALT_LETTERS[(a + 7 j) mod 23],
    each digit d -> (d + 3 j) mod 10, spaces and the layout kept, so every set has the scene's
    plate format and length; j = 0: `text` itself."""
    if j == 0:
        return text
    out = []
    for c in text:
        if "A" <= c <= "Z":
            out.append(ALT_LETTERS[(ord(c) - ord("A") + 7 * j) % len(ALT_LETTERS)])
        elif "0" <= c <= "9":
            out.append(chr(ord("0") + (ord(c) - ord("0") + 3 * j) % 10))
        else:
            out.append(c)
    return "".join(out)


# ----------------------------------------------------------------------------------------------
# Runs

def scene_sets(scene_dir: str, scale: float, frames: int, gain: float, text_set: int, mode: str):
    """(overrides, {plate id: label}, our beams' spectrum, multi) of one render: frames, loop mode,
    scale, beam gain and plate texts."""
    from benchmarks.scene_library import own_beams, scale_gain_overrides
    from poevp_optics.scene.load import load_scene

    base = [f"timing.frames={frames}", f'loop.mode="{mode}"']
    spec = load_scene(scene_dir, base)
    multi = bool(spec.vehicle)
    if multi:
        base.append('render.roi_shape="plates"')
    labels, texts = {}, []
    if multi:
        for ident, v in spec.vehicle.items():
            own = v.plate_text or (spec.plate.text if spec.has_road and ident == spec.road.vehicle else "")
            if not own:
                continue
            labels[ident] = alt_text(own, text_set)
            if v.plate_text:
                texts.append(f'vehicle.{ident}.plate_text="{labels[ident]}"')
            else:
                texts.append(f'plate.text="{labels[ident]}"')
    else:
        labels["plate"] = alt_text(spec.plate.text, text_set)
        texts.append(f'plate.text="{labels["plate"]}"')
    beam, _ = own_beams(spec)
    sets = base + (texts if text_set else []) + scale_gain_overrides(spec, scale, gain, beam)
    return sets, labels, beam, multi


def run_render(scene_dir: str, sets: list[str], labels: dict, predictors: list[str], min_height: int, log=print):
    """One render, every predictor's loop over it, whole-frame ALPR on the eligible plates.
    Returns {spec, render_s, loops_s, alpr_s, cpu_s, targets, reads: {pred: [(frame, id, ok, text)]},
    kept: {pred: {frame: capture}}}."""
    import tempfile

    from poevp_optics.analysis.recognition import alpr_read, correct
    from poevp_optics.apps.run.render_run import run_frames
    from poevp_optics.camera.camera import Camera
    from poevp_optics.render.radiance import open_source
    from poevp_optics.scene.load import load_scene

    spec = load_scene(scene_dir, sets)
    t0, c0 = time.perf_counter(), cpu_seconds()
    renderer = open_source(spec.resolved.render, Camera.from_params(spec.resolved.camera).guard_px)
    exposures = list(renderer.exposures(False))
    render_s = time.perf_counter() - t0
    out = {"spec": spec, "render_s": render_s, "loops_s": 0.0, "alpr_s": 0.0, "reads": {}, "kept": {},
           "targets": None, "heights": {}}
    everything = tuple(range(spec.timing.frames))
    for pred in predictors:
        ps = dataclasses.replace(spec, predictor=dataclasses.replace(spec.predictor, name=pred))
        tl = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            rep, kept = run_frames(ps, Path(tmp) / pred, progress=False, renderer=renderer, exposures=exposures,
                                   write_images=False, keep_frames=everything)
        out["loops_s"] += time.perf_counter() - tl
        targets = [t for t in eligible(rep["per_frame"], min_height) if t[1] in labels]   # plates with a text
        if out["targets"] is None:
            out["targets"] = targets
            out["heights"] = _heights(rep["per_frame"])
        elif targets != out["targets"]:
            raise RuntimeError(f"{spec.name}: {pred}'s plate boxes differ from {predictors[0]}'s on the same render")
        ta = time.perf_counter()
        rows = []
        for i, ident, box in targets:
            r = alpr_read(kept[i]["capture"], box)
            rows.append((i, ident, correct(r.text, labels[ident]), r.text))
        out["alpr_s"] += time.perf_counter() - ta
        out["reads"][pred] = rows
        out["kept"][pred] = {i: kept[i]["capture"] for i, _, _ in targets}
        k = sum(ok for *_, ok, _ in rows)
        log(f"  {pred}: {k}/{len(rows)} plate-frames read", flush=True)
    out["cpu_s"] = cpu_seconds() - c0
    return out


def _heights(per_frame: list[dict]) -> dict[str, tuple[int, int]]:
    """{plate id: (min, max) height in px over the loop frames it is in view}."""
    hs: dict[str, list[int]] = {}
    for _, plates in loop_plates(per_frame):
        for p in plates:
            if p.get("in_view") and p.get("height_px") is not None:
                hs.setdefault(p["id"], []).append(int(p["height_px"]))
    return {k: (min(v), max(v)) for k, v in hs.items()}


# ----------------------------------------------------------------------------------------------
# Page

def _cell(k: int, n: int) -> str:
    from poevp_optics.analysis.statistics import wilson_interval

    lo, hi = wilson_interval(k, n)
    return f"{k}/{n} [{lo * 100:.0f}-{hi * 100:.0f} %]"


def cells(results: list[dict], predictors: list[str]) -> tuple[list[list], list[str]]:
    """Table rows (scene, plate, gain, texts, heights, each predictor's reads, verdict) pooled over
    the text sets, and the lines for plates never >= the min height."""
    groups: dict = {}
    for r in results:
        for ident in r["labels"]:
            g = groups.setdefault((r["scene"], ident, r["gain"]), {"texts": [], "heights": [], "reads": {}})
            g["texts"].append(r["labels"][ident])
            if ident in r["heights"]:
                g["heights"].append(r["heights"][ident])
            for pred in predictors:
                g["reads"].setdefault(pred, []).extend((ident_, ok) for _, ident_, ok, _ in r["reads"][pred]
                                                       if ident_ == ident)
    rows, small = [], []
    for (scene, ident, gain), g in groups.items():
        counts = {p: tally(g["reads"][p]).get(ident, (0, 0)) for p in predictors}
        hs = g["heights"]
        lo, hi = (min(h[0] for h in hs), max(h[1] for h in hs)) if hs else (None, None)
        hrange = "-" if lo is None else str(lo) if lo == hi else f"{lo}-{hi}"
        if all(n == 0 for _, n in counts.values()):
            small.append(f"{scene} / {ident} at {gain:g}x: " + ("out of view in every loop frame" if lo is None else
                         f"under the minimum height in every loop frame ({hrange} px)"))
            continue
        row = [scene, ident, f"{gain:g}x", ", ".join(f"`{t}`" for t in g["texts"]), hrange]
        row += [_cell(*counts[p]) for p in predictors]
        if LEARNED in counts and CLASSICAL in counts:
            ok, higher = verdict(counts[LEARNED], counts[CLASSICAL])
            row.append(("yes" if ok else "**no**") + (", higher" if higher else ""))
        rows.append(row)
    return rows, small


def write_page(args, results: list[dict], started: float, dest: Path) -> str:
    preds = args.predictors.split(",")
    rows, small = cells(results, preds)
    header = ["scene", "plate", "beams", "texts", "height (px)"] + preds
    if LEARNED in preds and CLASSICAL in preds:
        header.append(f"{LEARNED} >= {CLASSICAL} within the interval; higher?")
    verdicts = [(r[-1].startswith("yes"), "higher" in r[-1]) for r in rows] if header[-1].startswith(LEARNED) else []
    bar = ("" if not verdicts else
           f"**The bar** (track_net >= flow within the interval in every cell, higher in at least one): "
           f"{'holds' if all(v for v, _ in verdicts) and any(h for _, h in verdicts) else 'does not hold'} "
           f"({sum(v for v, _ in verdicts)}/{len(verdicts)} cells not below, {sum(h for _, h in verdicts)} higher).\n\n")
    runs = [[r["scene"], r["scale"], r["resolution"], f"{r['gain']:g}x", r["text_set"], f"{r['render_s']:.0f}",
             f"{r['loops_s']:.0f}", f"{r['alpr_s']:.0f}", f"{r['cpu_s']:.0f}"] for r in results]
    pooled = []
    for pred in preds:
        k = sum(ok for r in results for *_, ok, _ in r["reads"][pred])
        n = sum(len(r["reads"][pred]) for r in results)
        pooled.append(_cell(k, n))
    misses = _disagreements(results)
    text = (
        "# Full-ALPR reads in the closed loop: learned predictor against flow\n\n"
        f"Every predictor runs the causal loop (loop mode `{args.mode}`: the predictor sees the camera's "
        "reconstructions) over the same render of the scene; whole-frame ALPR (PP-OCRv4 detection + recognition "
        "on the whole 8-bit capture, the detections over the plate joined, every character must match) is "
        f"counted on the loop frames after the white initialisation frames where the plate is in view and at "
        f"least {args.min_height} px tall, per plate; the frames counted are the same for every predictor. "
        "Cells pool the text sets (the scene's own plate texts and each with its letters and digits substituted, "
        "same layout, no I, O or Q: the font draws them like 1, 0 and O). Beams: our own beams' intensity x the gain, re-rendered. Interval: Wilson 95 %. "
        f"`oracle` reads the frame it masks (the ceiling of where the mask sits, not of ALPR: its dimmed "
        "surround hugs the plate, so the car's bright body comes closer to the plate's edge, and the detector "
        "can drop an edge character there, city_night's leading J), `hold` repeats the last frame (the floor). "
        f"Verdict: `{LEARNED}`'s read rate at or above the lower end of `{CLASSICAL}`'s interval; "
        f"higher: its rate above `{CLASSICAL}`'s.\n\n"
        f"Scale: each scene's camera at the scale given (x its own mirrors: 1920x1080 for the road "
        f"scenes, 640x368 for highbeam_plate and the held-out sequences), resolution in the runs table. "
        f"Machine: {machine_line()}; other jobs shared it. This page took "
        f"{(time.perf_counter() - started) / 60:.1f} min.\n\n"
        f"Command: `.venv/bin/python -m benchmarks.loop_alpr {' '.join(args.argv)}`\n\n"
        + bar
        + markdown_table(header, rows) + "\n\n"
        + (("Plates under the minimum height in every loop frame (no cell):\n\n"
            + "\n".join(f"- {s}" for s in small) + "\n\n") if small else "")
        + "All cells pooled: " + ", ".join(f"{p} {c}" for p, c in zip(preds, pooled)) + ".\n\n"
        + (("Frames where `track_net` and `flow` disagree (text read over the plate, `-`: nothing):\n\n"
            + "\n".join(misses) + "\n\n") if misses else "")
        + "Runs (seconds wall: render, every predictor's loop, ALPR; CPU seconds of this process):\n\n"
        + markdown_table(["scene", "scale", "mirrors", "beams", "text set", "render", "loops", "ALPR", "CPU s"], runs)
        + "\n")
    save_text(dest / args.out, text)
    return text


def disagreements(results: list[dict]):
    """(run, frame, plate id, box, track_net's read, flow's read) of every plate-frame where one
    predictor's capture reads and the other's does not."""
    for r in results:
        if LEARNED in r["reads"] and CLASSICAL in r["reads"]:
            for a, b, (i, ident, box) in zip(r["reads"][LEARNED], r["reads"][CLASSICAL], r["targets"]):
                if a[2] != b[2]:
                    yield r, i, ident, box, a, b


def _disagreements(results: list[dict]) -> list[str]:
    return [f"- {r['scene']} {r['gain']:g}x `{r['labels'][ident]}` frame {i} {ident}: "
            f"track_net `{a[3] or '-'}`, flow `{b[3] or '-'}`" for r, i, ident, _, a, b in disagreements(results)]


def save_examples(results: list[dict], dest: Path, name: str, limit: int = 6) -> Path | None:
    """Crops (the plate's vehicle-sized search window) of up to `limit` frames where track_net and
    flow disagree: flow's capture above, track_net's below."""
    from benchmarks.common import save_figure
    from poevp_optics.analysis.recognition import search_window
    from poevp_optics.core.runtime import pyplot

    cases = list(disagreements(results))
    if not cases:
        (dest / name).unlink(missing_ok=True)          # no disagreement: no figure from an older run
        return None
    cases = cases[:limit]
    plt = pyplot()
    fig, axes = plt.subplots(2, len(cases), figsize=(2.6 * len(cases), 3.4), squeeze=False)
    for j, (r, i, ident, box, a, b) in enumerate(cases):
        for row, (pred, rd) in enumerate(((CLASSICAL, b), (LEARNED, a))):
            img = r["kept"][pred][i]
            y0, x0, y1, x1 = search_window(box, img.shape)
            ax = axes[row, j]
            ax.imshow(img[y0:y1, x0:x1], cmap="gray", vmin=0, vmax=255)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{pred}: {rd[3] or '-'}" + (" (read)" if rd[2] else ""), fontsize=7)
        axes[0, j].set_ylabel(f"{r['scene']} {r['gain']:g}x t={i}", fontsize=7)
    fig.tight_layout()
    return save_figure(fig, dest / name)


def main(argv=None):
    from poevp_optics.core import runtime
    from poevp_optics.scene.scale import parse_scale

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default=",".join(SCENES),
                    help="name[@scale][:texts],...: scale x the scene's own mirrors, text sets (default --texts)")
    ap.add_argument("--scale", default="1", help="the scale of a scene given without @")
    ap.add_argument("--predictors", default=",".join(PREDICTORS))
    ap.add_argument("--mode", default="demodulated", choices=("raw", "demodulated"), help="closed-loop mode")
    ap.add_argument("--gains", default="1,10", help="x our own beams' intensity")
    ap.add_argument("--texts", type=int, default=2, help="plate text sets per scene (set 0: the scene's own)")
    ap.add_argument("--frames", type=int, default=0, help="frames per run (0: the scene's own)")
    ap.add_argument("--min-height", type=int, default=MIN_HEIGHT_PX)
    ap.add_argument("--out", default="loop_alpr.md")
    add_results_flag(ap)
    args = ap.parse_args(argv)
    args.argv = list(argv if argv is not None else sys.argv[1:])
    runtime.set_threads(2)
    dest = output_folder(args.results)
    started = time.perf_counter()
    results: list[dict] = []
    preds = args.predictors.split(",")
    for item in args.scenes.split(","):
        item, _, nt = item.partition(":")
        name, _, sc = item.partition("@")
        n_texts = int(nt) if nt else args.texts
        scale = parse_scale(sc or args.scale)
        scene_dir = str(ROOT / "scenes" / name)
        if not Path(scene_dir, "scene.toml").is_file():
            raise SystemExit(f"--scenes: no scene {name!r} under scenes/")
        for gain in (float(g) for g in args.gains.split(",")):
            for j in range(n_texts):
                from poevp_optics.scene.load import load_scene

                frames = args.frames or load_scene(scene_dir).timing.frames
                sets, labels, beam, _ = scene_sets(scene_dir, scale, frames, gain, j, args.mode)
                print(f"{name} @{sc or args.scale} {gain:g}x texts {list(labels.values())}", flush=True)
                r = run_render(scene_dir, sets, labels, preds, args.min_height)
                h, w = r["spec"].render.resolution
                r.update(scene=name, scale=sc or args.scale, gain=gain, text_set=j, labels=labels,
                         resolution=f"{w}x{h}")
                print(f"  render {r['render_s']:.0f} s, loops {r['loops_s']:.0f} s, ALPR {r['alpr_s']:.0f} s",
                      flush=True)
                results.append(r)
                save_examples(results, dest, Path(args.out).stem + "_examples.png")
                write_page(args, results, started, dest)
    print(write_page(args, results, started, dest))


if __name__ == "__main__":
    main()
