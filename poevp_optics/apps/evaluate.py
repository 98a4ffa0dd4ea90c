"""`poevp evaluate`: recognising highlighted moving plates, LDR vs exposure fusion vs POE-VP.

Test set (fixed, `TEXTS` x `MOTIONS`, seeded): the default road scene with other plate texts and
motions, rendered once per sequence and cached (`~/.cache/poevp_optics/eval`, or
$POEVP_CACHE_DIR/eval). Highlight strengths as the paper's over-exposure rates E = 9, 29, 49:
radiance is linear in the beams' intensity, so each sequence is scaled until the plate's peak
reaches (E + 1) x the LDR saturation level (the paper adds an artificial Gaussian highlight
H = O (E G + 1); here the beams themselves are the highlight).

Methods, one 8-bit image per frame t (frames 0-1 are the loop's white initialisation; t >= 2):
  ldr             the DMD all white
  fusion_classic  captures t-2, t-1, t at global exposures 1/8, 1/5, 1, Mertens fusion
                  (OpenCV `createMergeMertens`; Mertens, Kautz & Van Reeth 2007)
  fusion_deghost  the same after median-threshold-bitmap alignment (OpenCV `createAlignMTB`;
                  Ward 2003)
  hold, flow, dmvfn, oracle   POE-VP single shot, open loop, target mask law
Deep optics (the paper's third baseline) is out of scope: it needs a learned optical element.
Recognition: recognize.py (RapidOCR PP-OCRv4); accuracy per paper Eq. 4, entropy of the plate
box per Eq. 5, local entropy maps per Sec. 5C; run time = each method's own processing per
output frame (fusion: alignment + merge; POE-VP: predictor + mask law).
"""

from __future__ import annotations

import csv
import hashlib
import io as _io
import json
import time
from pathlib import Path

import numpy as np

from poevp_optics import __version__
from poevp_optics.camera.camera import Camera
from poevp_optics.core.frame import Frame, Quantity
from poevp_optics.core.io import atomic_path, write_json, write_png
import dataclasses

from poevp_optics.apps.render_run import run_frames
from poevp_optics.core.runtime import cache_dir
from poevp_optics.core.seeds import FUSION_STREAM, capture_seed
from poevp_optics.render.exposures import RenderedExposure, render_exposures
from poevp_optics.analysis.metrics import crop, entropy_8bit, local_entropy, to_8bit
from poevp_optics.analysis.recognition import correct, read_plate
from poevp_optics.render.renderer import Renderer
from poevp_optics.scene.load import load_scene
from poevp_optics.core.units import PHOTON_RADIANCE_UNIT
from poevp_optics.core.paths import SCENES_DIR

BASE = SCENES_DIR / "highbeam_plate"
TEXTS = ("KA 7391", "MH 20DV", "TN 09BX", "DL 3CAF", "GJ 5RT8", "HR 26QZ")
MOTIONS = ((1.0, 0.0, -1.5), (-1.0, 0.0, -1.5))          # m/s: drift across, closing in
E_LEVELS = (9, 29, 49)
FUSION_EXPOSURES = (1 / 8, 1 / 5, 1.0)
POEVP = ("hold", "flow", "dmvfn", "oracle")
METHODS = ("ldr", "fusion_classic", "fusion_deghost", *POEVP)
#: Paper Table 2 (accuracy %, ms per frame); E-averaged, its own data and hardware.
PAPER = {"fusion_classic": (65.07, 135.0), "fusion_deghost": (88.56, 425.0),
         "deep_optics": (21.64, 1161.0), "poevp": (94.86, 16.9)}


def sequence_overrides(text: str, motion, frames: int) -> list[str]:
    dur = frames / 30.0
    start = [-motion[0] * dur / 2, 0.0, -motion[2] * dur / 2]
    return [f"plate.text={json.dumps(text)}", f"motion.plate.velocity_m_per_s={list(motion)}",
            f"motion.plate.start_offset_m={start}", f"timing.frames={frames}",
            "render.subframes=2", "render.spp=16", "outputs.previews=false",
            "outputs.contact_sheet=false", "outputs.radiance_exr=false"]


def load_or_render(overrides: list[str], renderer: Renderer, progress: bool) -> list[RenderedExposure]:
    """The sequence's radiance (sub-frames, ROI per frame), rendered once by `renderer` (the
    loaded scene of these overrides) and cached."""
    key = hashlib.sha1(json.dumps([overrides, __version__, BASE.name, "radiance-mean-v2"]).encode()).hexdigest()[:16]
    path = cache_dir("eval") / f"{key}.npz"
    if path.is_file():
        z = np.load(path)
        out = []
        for i in range(len(z["roi"])):
            subs = tuple(z["subs"][i])
            mean = z["mean"][i]
            t0, dt = float(z["t"][i, 0]), float(z["t"][i, 1])
            out.append(RenderedExposure(i, t0, dt, z["times"][i], subs,
                                        Frame(mean, Quantity.RADIANCE, PHOTON_RADIANCE_UNIT, t0, dt, i),
                                        z["var"][i], tuple(int(v) for v in z["roi"][i]), None, None))
        return out
    exps = list(render_exposures(renderer.spec, renderer, progress))
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, subs=np.stack([np.stack(e.subframes) for e in exps]).astype(np.float32),
                     mean=np.stack([e.radiance.data for e in exps]).astype(np.float32),
                     var=np.stack([e.variance for e in exps]).astype(np.float32),
                     roi=np.array([e.roi for e in exps]), times=np.stack([e.subframe_times_s for e in exps]),
                     t=np.array([[e.t_start_s, e.exposure_s] for e in exps]))
    return exps


def scaled(exps: list[RenderedExposure], s: float) -> list[RenderedExposure]:
    out = []
    for e in exps:
        mean = (e.radiance.data.astype(np.float64) * s).astype(np.float32)
        out.append(RenderedExposure(e.index, e.t_start_s, e.exposure_s, e.subframe_times_s,
                                    tuple((x.astype(np.float64) * s).astype(np.float32) for x in e.subframes),
                                    Frame(mean, Quantity.RADIANCE, PHOTON_RADIANCE_UNIT, e.t_start_s,
                                          e.exposure_s, e.index),
                                    e.variance * s * s, e.roi, e.rel_error, e.rel_error_roi))
    return out


def overexposure(cam: Camera, exps) -> float:
    """Peak plate signal over the sequence with the DMD white, in units of saturation."""
    k = cam.electrons_per_radiance() * cam.white_exposure_s(0) / cam.params.saturation_capacity_e
    return max(float(np.max(crop(cam.to_sensor(e.radiance.data), cam.box_to_sensor(e.roi)))) * k for e in exps)


def _fusion(cam, exps, t, deghost: bool, seeds: tuple[int, int]):
    """Mertens fusion of captures t-2, t-1, t at 1/8, 1/5, 1 (seeds: sensor and render seed)."""
    import cv2

    imgs = []
    for j, f in zip((t - 2, t - 1, t), FUSION_EXPOSURES):
        e = exps[j]
        cap = cam.capture([x * np.float32(f) for x in e.subframes], cam.white_mask(), j,
                          capture_seed(seeds[0], seeds[1], j, FUSION_STREAM), times_s=e.subframe_times_s)
        imgs.append(cv2.cvtColor(to_8bit(cap.dn, cam.params.max_dn).astype(np.uint8), cv2.COLOR_GRAY2BGR))
    t0 = time.perf_counter()
    if deghost:
        cv2.createAlignMTB().process(imgs, imgs)
    fused = cv2.createMergeMertens().process(imgs)
    dt = time.perf_counter() - t0
    gray = cv2.cvtColor(np.clip(fused * 255.0, 0, 255).astype(np.float32), cv2.COLOR_BGR2GRAY)
    return np.rint(gray).astype(np.uint8), dt


def evaluate(out: Path, quick: bool = False, progress: bool = True, log=print) -> dict:
    texts, motions, frames = (TEXTS[:2], MOTIONS[:1], 5) if quick else (TEXTS, MOTIONS, 8)
    out = Path(out)
    rows, examples, shifts = [], {}, []
    t_start = time.perf_counter()
    for si, (text, motion) in enumerate((t, m) for t in texts for m in motions):
        ov = sequence_overrides(text, motion, frames)
        base_spec = load_scene(BASE, ov)
        cam = Camera.from_scene(base_spec)
        renderer = Renderer(base_spec, guard_px=cam.guard_px)
        exps = load_or_render(ov, renderer, progress)
        r0 = overexposure(cam, exps)
        shifts += [abs(a.roi[1] - b.roi[1]) + abs(a.roi[0] - b.roi[0]) for a, b in zip(exps[1:], exps)]
        for e_level in E_LEVELS:
            ex = scaled(exps, (e_level + 1) / r0)
            images = {m: {} for m in METHODS}
            secs = {m: [] for m in METHODS}
            for pred in POEVP:
                spec = dataclasses.replace(base_spec, predictor=dataclasses.replace(base_spec.predictor, name=pred),
                                           loop=dataclasses.replace(base_spec.loop, mode="open"))
                rep, kept = run_frames(spec, out / "runs" / f"s{si}_E{e_level}_{pred}", progress=False,
                                       renderer=renderer, exposures=ex, write_images=False,
                                       keep_frames=tuple(range(frames)))
                for i, k in kept.items():
                    images[pred][i] = k["capture"]
                    if pred == "oracle":
                        images["ldr"][i] = k["ldr"]
                st = rep["stages"]
                per = (st["predict"]["seconds"] if "predict" in st else st["mask"]["seconds"] / frames)
                secs[pred] = [per]
            secs["ldr"] = [0.0]
            for t in range(2, frames):
                for deghost, name in ((False, "fusion_classic"), (True, "fusion_deghost")):
                    images[name][t], dt = _fusion(cam, ex, t, deghost, (base_spec.sensor.seed, base_spec.render.seed))
                    secs[name].append(dt)
            for m in METHODS:
                for t in range(2, frames):
                    img = images[m][t]
                    box = cam.box_to_sensor(ex[t].roi)
                    read, conf, ocr_s = read_plate(img, box)
                    rows.append({"sequence": si, "text": text, "E": e_level, "method": m, "frame": t,
                                 "read": read, "confidence": conf, "correct": correct(read, text),
                                 "entropy": entropy_8bit(crop(img, box)),
                                 "method_ms": float(np.median(secs[m])) * 1e3, "ocr_ms": ocr_s * 1e3})
            if si == 0 and e_level == max(E_LEVELS):
                t = frames // 2 + (frames % 2 == 0)
                examples = {m: (images[m][t], cam.box_to_sensor(ex[t].roi)) for m in METHODS}
        log(f"poevp evaluate: sequence {si + 1}/{len(texts) * len(motions)} ({text}) done "
            f"({time.perf_counter() - t_start:.0f} s)")
    summary = _summarise(rows)
    summary["test_set"] = {"sequences": len(texts) * len(motions), "frames": frames,
                           "plate_shift_px_per_frame": float(np.median(shifts))}
    _write(out, rows, summary, examples, quick, time.perf_counter() - t_start)
    return summary


def _summarise(rows) -> dict:
    out = {}
    for m in METHODS:
        out[m] = {}
        for e in (*E_LEVELS, "all"):
            sel = [r for r in rows if r["method"] == m and (e == "all" or r["E"] == e)]
            if not sel:
                continue
            out[m][str(e)] = {"accuracy_pct": 100.0 * float(np.mean([r["correct"] for r in sel])),
                              "entropy_bits": float(np.mean([r["entropy"] for r in sel])),
                              "method_ms": float(np.median([r["method_ms"] for r in sel])),
                              "frames": len(sel)}
    strong = str(max(E_LEVELS))
    ldr = out["ldr"][strong]
    for m in METHODS:
        d = out[m][strong]
        d["accuracy_x_ldr"] = (d["accuracy_pct"] / ldr["accuracy_pct"]) if ldr["accuracy_pct"] > 0 else None
        # a fully clipped LDR plate has 0 bits: the gain is unbounded (reported as None + flag)
        d["entropy_gain_pct_over_ldr"] = (100.0 * (d["entropy_bits"] / ldr["entropy_bits"] - 1)
                                          if ldr["entropy_bits"] > 0 else None)
        d["ldr_entropy_zero"] = ldr["entropy_bits"] == 0
    return out


def _write(out: Path, rows, summary, examples, quick, seconds):
    strong = str(max(E_LEVELS))
    buf = _io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]))
    w.writeheader()
    w.writerows(rows)
    with atomic_path(out / "frames.csv") as tmp:
        Path(tmp).write_text(buf.getvalue())
    paper_of = {"fusion_classic": PAPER["fusion_classic"], "fusion_deghost": PAPER["fusion_deghost"],
                **{m: PAPER["poevp"] for m in ("dmvfn",)}}
    header = (["method"] + [f"acc % E={e}" for e in E_LEVELS] + ["acc % all", f"entropy E={strong}",
              f"entropy gain vs LDR E={strong}", "ms/frame", "paper acc %", "paper ms"])
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    csv_rows = []
    for m in METHODS:
        s = summary[m]
        p = paper_of.get(m)
        row = [m] + [f"{s[str(e)]['accuracy_pct']:.1f}" for e in E_LEVELS] + [
            f"{s['all']['accuracy_pct']:.1f}", f"{s[strong]['entropy_bits']:.2f}",
            (f"{s[strong]['entropy_gain_pct_over_ldr']:.0f} %" if s[strong]["entropy_gain_pct_over_ldr"] is not None
             else ("unbounded (LDR plate 0 bits)" if m != "ldr" and s[strong]["entropy_bits"] > 0 else "-")),
            f"{s['all']['method_ms']:.1f}", f"{p[0]}" if p else "-", f"{p[1]}" if p else "-"]
        lines.append("| " + " | ".join(row) + " |")
        csv_rows.append(dict(zip(header, row)))
    lines.append(f"| deep_optics | out of scope (needs a learned optical element) | | | | | | | | "
                 f"{PAPER['deep_optics'][0]} | {PAPER['deep_optics'][1]} |")
    text = (f"# Plate recognition: LDR vs exposure fusion vs POE-VP\n\n"
            f"{'Quick' if quick else 'Default'} set: {len(set(r['sequence'] for r in rows))} sequences x "
            f"E = {', '.join(map(str, E_LEVELS))}, frames 2+ of each; RapidOCR PP-OCRv4 recognition on the "
            f"plate box; a frame counts if every character matches (paper Eq. 4). Paper numbers: its "
            f"Table 2 (its own data; POE-VP row = its DMVFN predictor, 16.9 ms on an RTX 3090). "
            f"Total {seconds:.0f} s.\n\n" + "\n".join(lines) + "\n\n" + _explain(summary) + "\n")
    with atomic_path(out / "evaluation.md") as tmp:
        Path(tmp).write_text(text)
    buf = _io.StringIO()
    w = csv.DictWriter(buf, fieldnames=header)
    w.writeheader()
    w.writerows(csv_rows)
    with atomic_path(out / "evaluation.csv") as tmp:
        Path(tmp).write_text(buf.getvalue())
    write_json(out / "report.json", {"summary": summary, "paper": PAPER, "quick": quick, "seconds": seconds,
                                     "explanation": _explain(summary),
                                     "deep_optics": "out of scope: needs a learned optical element"})
    if examples:
        _figure(out / "examples.png", examples)


def _explain(summary) -> str:
    strong = str(max(E_LEVELS))
    acc = {m: summary[m][strong]["accuracy_pct"] for m in METHODS}
    ms = {m: summary[m]["all"]["method_ms"] for m in METHODS}
    order = sorted(METHODS, key=lambda m: -acc[m])
    shift = summary.get("test_set", {}).get("plate_shift_px_per_frame", float("nan"))
    return (f"At E = {strong}, accuracy order: " + " > ".join(f"{m} {acc[m]:.0f} %" for m in order) + ". "
            f"Fusion merges three captures taken 1/30 s apart while the plate moves ~{shift:.0f} px per "
            "frame: the merge blends shifted characters (ghosts) and is an image of t-2 ... t, not of t; "
            "MTB alignment (translation only, on a clipped plate) removes little of it at extra cost; "
            "and the 1/8 ... 1 bracket spans 18 dB while E = 29 and 49 need 30 and 34 dB, so even the "
            "shortest capture clips the plate's white. Every fused output needs three captures. POE-VP needs "
            "one capture per output (the predictor reads the two previous ones) and dims the plate in "
            "the frame it arrives. Run time per output frame: "
            + ", ".join(f"{m} {ms[m]:.1f} ms" for m in METHODS if m != "ldr") + " (this 2-core CPU).")


def _figure(path: Path, examples):
    from poevp_optics.core.runtime import pyplot

    plt = pyplot()

    n = len(examples)
    fig, axes = plt.subplots(2, n, figsize=(2.6 * n, 3.2))
    for j, (m, (img, box)) in enumerate(examples.items()):
        y0, x0, y1, x1 = box
        pad = 12
        c = img[max(0, y0 - pad):y1 + pad, max(0, x0 - pad):x1 + pad]
        axes[0, j].imshow(c, cmap="gray", vmin=0, vmax=255)
        axes[0, j].set_title(m, fontsize=8)
        axes[1, j].imshow(local_entropy(c), cmap="magma", vmin=0, vmax=6)
        for a in axes[:, j]:
            a.axis("off")
    axes[1, 0].set_title("local entropy", fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
    write_png(path.with_name("examples_ldr.png"), examples["ldr"][0])
