"""The scene library, each scene at our default beams and at 10x them: stage timings, every plate's
MC error, every plate's white in the controller's band, and (with --alpr) whole-frame ALPR.

    .venv/bin/python -m benchmarks.scene_library [--scale 1/6] [--frames 21] [--gains 1,10] \
        [--scenes night_road,city_night] [--alpr] [--results]

Each scene runs as `poevp render` runs it (the causal loop, the scene's own predictor, mask law,
spp and region-of-interest spp), with `render.roi_shape = "plates"`: every vehicle plate gets its
own box, extra samples, MC error and record (apps/run/plates.py). `--scale S` renders the camera
at S x the scene's 1920x1080 mirrors over the same field (scene/scale.py: focal length, mask
smoothing, guard band and the attenuator's size rule follow), as `poevp render --scale S` does;
the default, 1, is the DLP6500's own 1920x1080 mirrors.

Beam gain g: our own beams' `spectra.<name>.intensity_cd` x g, re-rendered, where <name> is
`[road] highbeam` on a road scene, else the spectrum of the XML's `highbeam_left/right` emitters
(or `lowbeam_left/right` where we drive on low beams; the oncoming cars' lamps carry other ids). Where that spectrum is shared with
another emitter (toll_or_junction's oncoming SUV lights the road with the same low-beam file),
that emitter is scaled too: the page names it. A scene that sets `mask.prior_beam_cd` scales its
controller's first guess with the beams (night_road); the others keep theirs.

Per scene and gain:
- timings (wall seconds of the run, no image written: `run_frames(write_images=False)`): render
  (Mitsuba, with the scene's setup, on its own thread ahead of the loop), the loop's wait for the
  rendered frames (the part of the render the camera's work does not hide), camera (objective,
  DMD, relay, sensor, mask, reconstruction stages summed over frames), predictor (predictor +
  mask law, summed over frames), the rest of the wall time (the camera's set-up, the loop's own
  work, the temporal-error estimate and the report: the wall less the wait, camera and
  predictor), total wall and CPU seconds (this process: with other jobs on the machine, wall
  seconds grow and CPU seconds do not);
- per plate: frames in view, distance and height range, MC error (RMS MC standard error / mean
  radiance over its pixels that show it; mean and worst frame), and the fraction of the frames after the white
  initialisation frames, with the plate in view, whose encoded white (90th percentile of the
  box's pixels that show the plate, in the 8-bit capture / 255: a car ahead hiding part of it is
  left out, apps/run/plates.py) lies in [mask.band_low, mask.band_high];
- with --alpr: whole-frame ALPR (analysis/recognition.py `alpr_read`: PP-OCRv4 detection on the
  whole 8-bit capture; the detections over the plate read by the plate-font CRNN,
  analysis/plate_ocr.py, and by PP-OCRv4's own recogniser; every character must match) on the
  loop frames where the plate is in view and at least --min-height px tall, with Wilson 95 %
  intervals (analysis/statistics.py); beside each the same reading with the plate's box replaced
  by its ideal image (`ideal_plate`: the plate's texture area-averaged onto the box at the
  measured white, no blur, no noise, nothing hidden), that recogniser's own limit on that text at
  that size.

Writes scene_library.md into out/benchmarks/ (benchmarks/results/ with --results), rewritten after
every run, so a cut-off run keeps what it finished.
"""

from __future__ import annotations

import argparse
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from benchmarks.common import ROOT, add_results_flag, cpu_seconds, machine_line, markdown_table, output_folder, save_text

LIBRARY = ["night_road", "wet_night_road", "city_night", "toll_or_junction", "fog_highway"]
#: Our own beams' emitters in a scene's XML (the others are other cars' lamps).
OWN_BEAM_EMITTERS = (("highbeam_left", "highbeam_right"), ("lowbeam_left", "lowbeam_right"))
MIN_HEIGHT_PX = 20


def _intensity_refs(xml_path: Path) -> dict[str, str]:
    """{emitter id: the $name its `intensity` spectrum takes} of a scene XML."""
    out = {}
    for em in ET.parse(xml_path).getroot().iter("emitter"):
        for sp in em.iter("spectrum"):
            v = sp.get("value") or ""
            if sp.get("name") == "intensity" and v.startswith("$") and em.get("id"):
                out[em.get("id")] = v[1:]
    return out


def own_beams(spec) -> tuple[str, list[str]]:
    """(the [spectra] entry of our own beams, the other emitters sharing it) of a loaded scene: a
    road scene's `[road] highbeam`; else the spectrum of its `highbeam_left/right` emitters, or
    of its `lowbeam_left/right` where it has no high beams (the oncoming cars' lamps carry other
    ids: `oncoming_lowbeam_left`, ...)."""
    refs = _intensity_refs(Path(spec.xml_path))
    if spec.has_road:
        names = {spec.road.highbeam}
    else:
        names = set()
        for pair in OWN_BEAM_EMITTERS:
            names = {refs[e] for e in pair if e in refs}
            if names:
                break
    if len(names) != 1 or next(iter(names)) not in spec.spectra:
        raise SystemExit(f"{spec.name}: cannot tell our beams' spectrum (found {sorted(names) or 'none'})")
    name = next(iter(names))
    ours = {e for pair in OWN_BEAM_EMITTERS for e in pair if refs.get(e) == name}
    shared = sorted(e for e, n in refs.items() if n == name and e not in ours)
    return name, shared


def scene_overrides(scene: str, scale: float, frames: int, gain: float, extra: list[str]):
    """(overrides, our beams' spectrum, emitters sharing it) for one run."""
    from poevp_optics.scene.load import load_scene

    base = ['render.roi_shape="plates"', f"timing.frames={frames}", *extra]
    spec = load_scene(scene, base)
    beam, shared = own_beams(spec)
    return [*base, *scale_gain_overrides(spec, scale, gain, beam)], beam, shared


def scale_gain_overrides(spec, scale: float, gain: float, beam: str) -> list[str]:
    """The overrides that run `spec` at `scale` x its own mirrors (as `poevp render --scale`) with
    our beams' spectrum `beam` x `gain`."""
    from poevp_optics.scene.scale import scaled_resolution, scaling_for

    sets = []
    if abs(scale - 1.0) > 1e-12:
        sets += list(scaling_for(spec, scaled_resolution(spec.render.resolution, scale), f"--scale {scale:g}").sets)
    if gain != 1.0:
        sets.append(f"spectra.{beam}.intensity_cd={spec.spectra[beam].intensity_cd * gain:.9g}")
    return sets


def run_scene(scene: str, sets: list[str], alpr: bool, min_height: int) -> dict:
    """One run: timings, per-plate summary and (alpr) per-plate reads."""
    from poevp_optics.apps.run.render_run import run_frames
    from poevp_optics.scene.load import load_scene

    spec = load_scene(scene, sets)
    t0, c0 = time.perf_counter(), cpu_seconds()
    with tempfile.TemporaryDirectory() as tmp:
        report, kept = run_frames(spec, tmp, False, write_images=False,
                                  keep_frames=tuple(range(spec.timing.frames)) if alpr else ())
    wall, cpu = time.perf_counter() - t0, cpu_seconds() - c0
    stages = report["stages"]
    render_s = stages["render"]["seconds"]
    wait_s = stages["render"].get("ahead_wait_seconds") or 0.0
    predict_s = (stages.get("predict") or {}).get("total_seconds") or 0.0
    camera_s = sum(v["seconds"] for k, v in stages.items()
                   if k not in ("render", "predict") and isinstance(v, dict) and isinstance(v.get("seconds"), float))
    texts = plate_texts(spec, report)
    reads = {}
    if alpr:
        reads = plate_reads(report, kept, min_height, texts,
                            {k: v.plate_format for k, v in (getattr(spec, "vehicle", {}) or {}).items()})
    return {"spec": spec, "resolution": tuple(spec.render.resolution), "render_s": render_s, "wait_s": wait_s,
            "camera_s": camera_s,
            "predict_s": predict_s, "wall_s": wall, "cpu_s": cpu, "plates": report["metrics"]["plates"],
            "init_frames": spec.loop.init_frames, "reads": reads, "texts": texts,
            "spp": (spec.render.spp, spec.render.roi_spp)}


def plate_texts(spec, report: dict) -> dict[str, str]:
    """{plate id: its text}: the vehicle's plate_text, or on a road scene the [plate] text for
    `[road] vehicle`'s plate (the plate the scene's [plate] section draws)."""
    out = {}
    for ident, s in report["metrics"]["plates"]["per_plate"].items():
        text = s["text"] or ""
        if not text and spec.has_road and ident == spec.road.vehicle:
            text = spec.plate.text
        out[ident] = text
    return out


def plate_reads(report: dict, kept: dict, min_height: int, labels: dict[str, str],
                formats: dict[str, str] | None = None) -> dict:
    """{plate id: {recogniser: (frames read, frames tried, texts read, frames the ideal plate
    reads)}} over the loop frames where the plate is in view and >= min_height px tall: whole-frame
    ALPR with each recogniser (analysis/recognition.py RECOGNISERS) on the 8-bit encoded capture,
    and on the same capture with the plate's box replaced by its ideal image (`ideal_plate`: the
    recogniser's own limit on that text at that size, no camera)."""
    from poevp_optics.analysis.recognition import RECOGNISERS, alpr_read, correct

    out: dict = {}
    for f in report["per_frame"]:
        if f.get("init"):
            continue
        for p in f.get("plates") or []:
            per = out.setdefault(p["id"], {r: (0, 0, [], 0) for r in RECOGNISERS})
            if not (p["in_view"] and p["box"] and (p["height_px"] or 0) >= min_height):
                continue
            cap = kept[f["index"]]["capture"]
            ideal = ideal_plate(cap, tuple(p["box"]), labels[p["id"]], (formats or {}).get(p["id"], "eu"),
                                (p.get("white") or {}).get("encoded"))
            for rec in RECOGNISERS:
                k, n, texts, ki = per[rec]
                r = alpr_read(cap, tuple(p["box"]), recogniser=rec)
                ok = correct(r.text, labels[p["id"]])
                ki += correct(alpr_read(ideal, tuple(p["box"]), recogniser=rec).text, labels[p["id"]])
                per[rec] = (k + ok, n + 1, texts if ok else [*texts, r.text or "-"], ki)
    return out


def ideal_plate(capture: np.ndarray, box, text: str, plate_format: str, white: float | None) -> np.ndarray:
    """The 8-bit capture with the plate's box (y0, x0, y1, x1) replaced by the plate's ideal
    image: its texture (sources/plates.py, the scene's font and layout) area-averaged onto the
    box's pixels, its sheeting at the capture's measured white (`white`, fraction of full scale;
    0.6 when unknown) and its ink at 5 % of that; no blur, no noise, nothing hidden."""
    import cv2

    from poevp_optics.sources.plates import plate_texture

    y0, x0, y1, x1 = box
    tex = plate_texture(text, sheeting_pattern=False, plate_format=plate_format).astype(np.float32) / 255.0
    small = cv2.resize(tex, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    w8 = 255.0 * (white if white else 0.6)
    out = capture.copy()
    out[y0:y1, x0:x1] = np.clip(np.rint(w8 * (0.05 + 0.95 * small)), 0, 255).astype(np.uint8)
    return out


def _pct(v) -> str:
    return "-" if v is None else f"{v * 100:.1f} %"


def _rng(r, fmt="{:.0f}") -> str:
    if not r:
        return "-"
    return fmt.format(r[0]) if r[0] == r[1] else f"{fmt.format(r[0])}-{fmt.format(r[1])}"


def scene_section(scene: str, runs: list[tuple[float, dict]], alpr: bool, min_height: int) -> str:
    """One scene's tables (timings; plates per gain)."""
    from poevp_optics.analysis.statistics import wilson_interval

    spec = runs[0][1]["spec"]
    h, w = runs[0][1]["resolution"]
    timing = [[f"{g:g}x", f"{r['render_s']:.1f}", f"{r['wait_s']:.1f}", f"{r['camera_s']:.1f}", f"{r['predict_s']:.1f}",
               f"{r['wall_s'] - r['wait_s'] - r['camera_s'] - r['predict_s']:.1f}",
               f"{r['wall_s']:.1f}", f"{r['cpu_s']:.0f}"] for g, r in runs]
    header = ["beams", "plate", "text", "frames in view", "distance (m)", "height (px)", "MC error mean",
              "MC error worst frame", "white after init (mean)", "in band after init"]
    if alpr:
        header += [f"ALPR reads, plate recogniser (>= {min_height} px)", "Wilson 95 %", "ideal image reads",
                   "ALPR reads, PP-OCRv4", "ideal image reads, PP-OCRv4"]
    rows = []
    for g, r in runs:
        for ident, s in r["plates"]["per_plate"].items():
            band = ("-" if s["in_band_fraction_after_init"] is None else
                    f"{s['frames_in_band_after_init']}/{s['frames_after_init_in_view']} "
                    f"({s['in_band_fraction_after_init'] * 100:.1f} %)")
            row = [f"{g:g}x", ident, f"`{r['texts'][ident]}`", f"{s['frames_in_view']}/{s['frames']}",
                   _rng(s["distance_m"], "{:.1f}"), _rng(s["height_px"]), _pct(s["rel_error_mean"]),
                   _pct(s["rel_error_max"]),
                   "-" if s["white_encoded_mean"] is None else f"{s['white_encoded_mean']:.2f}", band]
            if alpr:
                reads = r["reads"].get(ident, {})
                k, n, _, ki = reads.get("plate", (0, 0, [], 0))
                kp, _, _, kip = reads.get("ppocr", (0, 0, [], 0))
                lo, hi = wilson_interval(k, n)
                row += ([f"{k}/{n}", f"{lo * 100:.0f}-{hi * 100:.0f} %", f"{ki}/{n}", f"{kp}/{n}", f"{kip}/{n}"]
                        if n else ["- (none that tall)", "-", "-", "-", "-"])
            rows.append(row)
    lo, hi = runs[0][1]["plates"]["band"]
    beam, shared = runs[0][1]["beam"], runs[0][1]["shared"]
    text = (f"## {scene}\n\n{h}x{w} mirrors, {spec.timing.frames} frames at {spec.timing.fps:g} fps, "
            f"{runs[0][1]['spp'][0]} spp + {runs[0][1]['spp'][1]} on every plate's box, predictor "
            f"`{spec.predictor.name}`, loop `{spec.loop.mode}`, mask `{spec.mask.law}` (band {lo:g}-{hi:g}, "
            f"{runs[0][1]['init_frames']} white initialisation frames). Our beams: `spectra.{beam}.intensity_cd` "
            f"= {spec.spectra[beam].intensity_cd:g} cd x the gain"
            + (f" (the same spectrum also drives {', '.join(f'`{e}`' for e in shared)}, scaled with it)" if shared else "")
            + ".\n\nSeconds (wall, no images written):\n\n"
            + markdown_table(["beams", "render (own thread)", "loop waiting for it", "camera", "predictor", "rest",
                              "total wall", "CPU s"], timing)
            + "\n\n" + markdown_table(header, rows) + "\n")
    names = {"plate": "plate recogniser", "ppocr": "PP-OCRv4"}
    misses = [f"- {g:g}x {ident}, {names[rec]}: misread as " + ", ".join(f"`{t}`" for t in got[2])
              for g, r in runs for ident, per in r["reads"].items() for rec, got in per.items() if got[2]] if alpr else []
    if misses:
        text += "\nALPR misreads (whole frame, text over the plate):\n\n" + "\n".join(misses) + "\n"
    return text


def pooled(results: dict, alpr: bool) -> list[list]:
    """Per gain over the library: plates x loop frames in band, MC error worst, reads."""
    from poevp_optics.analysis.statistics import wilson_interval

    gains = sorted({g for runs in results.values() for g, _ in runs})
    rows = []
    for g in gains:
        inb = n = k = m = kp = 0
        worst, below = 0.0, []
        for scene, runs in results.items():
            for gg, r in runs:
                if gg != g:
                    continue
                for ident, s in r["plates"]["per_plate"].items():
                    inb += s["frames_in_band_after_init"]
                    n += s["frames_after_init_in_view"]
                    worst = max(worst, s["rel_error_max"] or 0.0)
                    if s["in_band_fraction_after_init"] is not None and s["in_band_fraction_after_init"] < 0.95:
                        below.append(f"{scene}/{ident} {s['in_band_fraction_after_init'] * 100:.1f} %")
                    if alpr:
                        kk, nn, *_ = r["reads"].get(ident, {}).get("plate", (0, 0, []))
                        k, m = k + kk, m + nn
                        kp += r["reads"].get(ident, {}).get("ppocr", (0,))[0]
        row = [f"{g:g}x", f"{inb}/{n} ({inb / max(n, 1) * 100:.0f} %)", _pct(worst), "; ".join(below) or "none"]
        if alpr:
            lo, hi = wilson_interval(k, m)
            lp, hp = wilson_interval(kp, m)
            row += [f"{k}/{m}" + (f" ({lo * 100:.0f}-{hi * 100:.0f} %)" if m else ""),
                    f"{kp}/{m}" + (f" ({lp * 100:.0f}-{hp * 100:.0f} %)" if m else "")]
        rows.append(row)
    return rows


def write_page(args, results: dict, scale_label: str, started: float) -> str:
    header = ["beams", "plate-frames in band after init", "worst plate MC error (one frame)",
              "plates below 95 % in band"]
    if args.alpr:
        header += [f"ALPR reads, plate recogniser (>= {args.min_height} px), Wilson 95 %",
                   "ALPR reads, PP-OCRv4, Wilson 95 %"]
    sections = "\n".join(scene_section(s, runs, args.alpr, args.min_height) for s, runs in results.items())
    text = (f"# The scene library at our beams and at 10x them\n\n"
            f"Scale: **{scale_label}**. Every library scene as `poevp render` runs it, with every vehicle plate its "
            f"own region of interest (`render.roi_shape = \"plates\"`), {args.frames} frames, at our default "
            f"beams and at {', '.join(g for g in args.gains.split(',') if g != '1')}x them (re-rendered). "
            f"In band: the plate's encoded white (90th percentile of its box's pixels that show the plate, in the "
            f"8-bit capture / 255; a car ahead hiding part of it is left out) within "
            f"the controller's band, over the frames after the white initialisation frames with the plate in "
            f"view. MC error: RMS Monte Carlo standard error / mean radiance over the plate's pixels in its box. "
            + ("ALPR: PP-OCRv4 text detection on the whole 8-bit capture, the detections over the plate read "
               "by the recogniser trained on the plate font (a CRNN, as in the paper's protocol; its texts "
               "never include a scene's) as one crop, every character must match; beside it PP-OCRv4's own "
               "general-text recogniser on each detection, joined. Counted on the loop frames where the plate "
               f"is in view and at least {args.min_height} px tall. Ideal plate image: the same reading with the "
               "plate's box replaced by its texture area-averaged onto the box at the measured white (no blur, "
               "no noise, nothing hidden): what each recogniser reads of that text at that size without a camera. "
               if args.alpr else "ALPR not run (`--alpr`). ")
            + f"Machine: {machine_line()}; other jobs shared it. This page took "
              f"{(time.perf_counter() - started) / 60:.1f} min.\n\n"
            f"Command: `.venv/bin/python -m benchmarks.scene_library {' '.join(args.argv) or ''}`\n\n"
            f"## Over the library\n\n{markdown_table(header, pooled(results, args.alpr))}\n\n{sections}")
    save_text(output_folder(args.results) / args.out, text)
    return text


def main(argv=None):
    from poevp_optics.core import runtime
    from poevp_optics.scene.scale import parse_scale, scale_text

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default=",".join(LIBRARY))
    ap.add_argument("--scale", default="1", help="x the scenes' 1920x1080 mirrors (1/6, 1/2, 1)")
    ap.add_argument("--frames", type=int, default=21)
    ap.add_argument("--gains", default="1,10", help="x our own beams' intensity")
    ap.add_argument("--alpr", action="store_true", help="whole-frame ALPR on every plate >= --min-height px tall")
    ap.add_argument("--min-height", type=int, default=MIN_HEIGHT_PX)
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--out", default="scene_library.md")
    add_results_flag(ap)
    args = ap.parse_args(argv)
    import sys

    args.argv = list(argv if argv is not None else sys.argv[1:])
    scale = parse_scale(args.scale)
    runtime.set_threads(2)
    started = time.perf_counter()
    label = ("the scenes' own mirrors, the DLP6500's 1920x1080" if scale_text(scale) == "full"
             else f"{scale_text(scale)} of the scenes' mirrors (the DLP6500's 1920x1080)")
    results: dict = {}
    for name in args.scenes.split(","):
        scene = str(ROOT / "scenes" / name)
        for gain in (float(g) for g in args.gains.split(",")):
            sets, beam, shared = scene_overrides(scene, scale, args.frames, gain, args.set)
            r = run_scene(scene, sets, args.alpr, args.min_height)
            r.update(beam=beam, shared=shared)
            results.setdefault(name, []).append((gain, r))
            per = {k: (_pct(s["in_band_fraction_after_init"]), _pct(s["rel_error_max"]))
                   for k, s in r["plates"]["per_plate"].items()}
            print(f"{name} {gain:g}x: wall {r['wall_s']:.0f} s, render {r['render_s']:.0f} s; in band, worst MC: {per}",
                  flush=True)
            write_page(args, results, label, started)
    print(write_page(args, results, label, started))


if __name__ == "__main__":
    main()
