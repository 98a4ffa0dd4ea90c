"""The default loop on six plate texts at the default and 10x high beams: the plate's
white per frame (90th percentile of the plate box in the raw 8-bit capture / 255) against the
40-90 % band, and whole-frame PP-OCRv4 detection + recognition (no crop from the known box).

    .venv/bin/python -m benchmarks.plate_band [--texts "JN F9H28,..."] [--gains 1,10] [--frames 16]
    .venv/bin/python -m benchmarks.plate_band --scene scenes/night_road --frames 21 \
        --set "render.resolution=[736,1280]" --set objective.focal_length_m=0.04604 \
        --set mask.smooth_px=16 --set attenuator.serve_min_mirrors=384 --set render.spp=8 \
        --out plate_band_night_road.md      # the overrides that page records: 2/3 of the mirrors
    .venv/bin/python -m benchmarks.plate_band --scene scenes/night_road --frames 21 --gains 1,10 \
        --out plate_band_night_road_1920.md                     # night_road as it is: 1920x1080

Writes plate_band.md (or --out NAME) into out/benchmarks/ (benchmarks/results/ with --results). One render per (gain, text). On a road scene (night_road)
a beam gain g renders with our high beams' intensity_cd x g (the oncoming car's lamps and the tail
lamps unchanged); elsewhere the render at the scene's beams is scaled by g (exact for all light
from the beams, which is all the plate gets; the 0.005 cd/m^2 sky glow is scaled too). Gains run in the order given, each over every text,
and the table is rewritten after every row, so a cut-off run keeps what it finished.
`--scale s` renders s x the scene's resolution with s x its objective focal length: the same field
(the XML's fov) over s x as many mirrors of the same pitch (dmd / objective pixel_pitch_m), the
same f-number, as a camera with s x the DLP6500 columns the scene's resolution stands in for;
sizes in mirrors scale too (mask.smooth_px by s, attenuator.serve_min_mirrors by s^2). The
third command is the same at s = 6 with the DMD's own 1080 rows (1104 would exceed them).
A beam gain also scales the exposure controller's prior `mask.first_guess` where the scene
sets `mask.prior_beam_cd` (night_road does; `--fixed-prior` keeps the scene's value). `--save-captures DIR` keeps each run's raw 8-bit captures,
masks and plate boxes as one .npz per (gain, text), to read them again without rendering.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.common import add_results_flag, cpu_seconds, machine_line, markdown_table, output_folder, save_text

TEXTS = ["JN F9H28", "KA 7731", "B4 713X", "MU 55RT", "HZ 2048", "TX 96QW"]


def render_once(scene: str, overrides: list[str]):
    """(spec, renderer, exposures) of a scene with overrides, rendered once."""
    from poevp_optics.camera.camera import Camera
    from poevp_optics.render.exposures import render_exposures
    from poevp_optics.render.renderer import Renderer
    from poevp_optics.scene.load import load_scene

    spec = load_scene(scene, overrides)
    renderer = Renderer(spec.resolved.render, guard_px=Camera.from_params(spec.resolved.camera).guard_px)
    return spec, renderer, list(render_exposures(spec.resolved.render, renderer, progress=False))


def scaled(exposures, gain: float):
    """Rendered exposures with every radiance sample x gain (variances x gain^2)."""
    import dataclasses

    if gain == 1.0:
        return exposures
    return [dataclasses.replace(
        ex, subframes=tuple(s * gain for s in ex.subframes),
        radiance=dataclasses.replace(ex.radiance, data=ex.radiance.data * gain),
        variance=ex.variance * gain ** 2,
        subframe_variances=tuple(v * gain ** 2 for v in ex.subframe_variances)) for ex in exposures]


def run_loop(spec, renderer, exposures) -> tuple[dict, dict]:
    """(report, kept frames) of the camera loop of `spec` on rendered exposures, every frame
    kept (captures, masks, plate box), nothing written."""
    import tempfile

    from poevp_optics.apps.run.render_run import run_frames

    with tempfile.TemporaryDirectory() as tmp:
        return run_frames(spec, tmp, False, renderer=renderer, exposures=exposures, write_images=False,
                          keep_frames=tuple(range(spec.timing.frames)))


def loop_frames(spec, renderer, exposures, label: str, ocr: bool = True, save_npz: str | None = None) -> list[dict]:
    """Run the camera loop of `spec` on rendered exposures; per frame: init flag, plate white
    (LDR twin and encoded), saturated plate fraction, whole-frame OCR read of the capture.
    save_npz: also write the raw 8-bit captures, masks, plate boxes and distances there."""
    from poevp_optics.analysis.metrics import plate_white_fraction
    from poevp_optics.analysis.recognition import frame_reads

    report, kept = run_loop(spec, renderer, exposures)
    out = []
    for f in report["per_frame"]:
        k = kept[f["index"]]
        read, texts = frame_reads(k["capture"], label) if ocr else (None, "")
        out.append({"index": f["index"], "init": bool(f.get("init")),
                    "white_ldr": plate_white_fraction(k["ldr"], k["roi"]),
                    "white": plate_white_fraction(k["capture"], k["roi"]),
                    "saturated": f["saturated_fraction_roi"]["encoded"], "read": read, "texts": texts,
                    "late": bool(f.get("timing_budget", {}).get("late")),
                    "distance_m": f.get("plate", {}).get("distance_m"), "mc_error": f.get("rel_error_roi"),
                    "box_px": None if k["roi"] is None else int(k["roi"][3] - k["roi"][1])})
    if save_npz:
        idx = sorted(kept)
        np.savez_compressed(save_npz, label=label, index=np.array(idx),
                            capture=np.stack([kept[i]["capture"] for i in idx]).astype(np.uint8),
                            ldr=np.stack([kept[i]["ldr"] for i in idx]).astype(np.uint8),
                            mask=np.stack([np.full(kept[i]["capture"].shape, 255, np.uint8) if kept[i]["mask"] is None
                                           else np.asarray(kept[i]["mask"], dtype=np.uint8) for i in idx]),
                            roi=np.array([[-1] * 4 if kept[i]["roi"] is None else list(kept[i]["roi"]) for i in idx]),
                            init=np.array([r["init"] for r in out]),
                            distance_m=np.array([np.nan if r["distance_m"] is None else r["distance_m"] for r in out]))
    return out


def summarise(rows: list[dict], lo=0.4, hi=0.9) -> dict:
    loop = [r for r in rows if not r["init"]]
    whites = np.array([r["white"] for r in loop])
    return {"frames": len(loop), "read": float(np.mean([bool(r["read"]) for r in loop])),
            "in_band": float(np.mean((whites >= lo) & (whites <= hi))),
            "white_p10": float(np.percentile(whites, 10)), "white_median": float(np.median(whites)),
            "white_p90": float(np.percentile(whites, 90)),
            "saturated": float(np.mean([r["saturated"] for r in loop]))}


def beam_overrides(scene: str, gain: float, fixed_prior: bool = False) -> list[str]:
    """On a road scene, the high beams' own intensity x gain (rendered again: only our beams
    change, the oncoming car's lamps and the tail lamps do not); elsewhere [] (the radiance is
    scaled: module docstring). A scene with mask.prior_beam_cd scales its controller prior with
    the beams itself (scene/validate.controller_prior); fixed_prior turns that off."""
    from poevp_optics.scene.load import load_scene

    spec = load_scene(scene, [])
    if gain == 1.0 or not spec.has_road:
        return []
    name = spec.road.highbeam
    return [f"spectra.{name}.intensity_cd={spec.spectra[name].intensity_cd * gain:.9g}",
            *(["mask.prior_beam_cd=0"] if fixed_prior else [])]


def scale_overrides(scene: str, scale: int) -> list[str]:
    """--set overrides for `scale` x the scene's resolution and objective focal length (module
    docstring): the field stays the XML's, the mirror pitch the DMD's; the mask's smoothing
    (mask.smooth_px, in mirrors, hence the controller's motion radius 3 smooth_px) scales with
    them, so it spans the same angle."""
    from poevp_optics.scene.load import load_scene

    if scale == 1:
        return []
    spec = load_scene(scene, [])
    h, w = spec.render.resolution
    return [f"render.resolution=[{h * scale},{w * scale}]",
            f"objective.focal_length_m={spec.objective.focal_length_m * scale:.9g}",
            f"mask.smooth_px={spec.mask.smooth_px * scale:g}",
            f"attenuator.serve_min_mirrors={spec.attenuator.serve_min_mirrors * scale * scale}"]


def _frame_line(g: float, t: str, fr: list[dict]) -> str:
    def one(r):
        d = f"{r['distance_m']:.0f} m " if r.get("distance_m") is not None else ""
        return f"{d}{r['white']:.2f}{'*' if r['init'] else ''}{'' if r['read'] or r['init'] else ' (miss)'}"

    return f"- {g:g}x `{t}`: white per frame " + ", ".join(one(r) for r in fr)


def write_results(args, sets: list[str], rows: list[list], per_frame: list, extra: str = "") -> str:
    header = ["beam gain", "plate", "loop frames", "read (whole frame)", "white in 40-90 %",
              "white p10", "white median", "white p90", "saturated plate", "plate MC error (median)",
              "seconds", "CPU seconds"]
    detail = "\n".join(_frame_line(g, t, fr) for g, t, fr in per_frame)
    text = (f"# Plate white and whole-frame OCR on the default loop\n\nScene `{args.scene}` with "
            f"{' '.join(sets) or 'its defaults'}, {args.frames} frames (the first "
            f"init_frames white, marked *). White = 90th percentile of the plate box in the raw "
            f"8-bit capture / 255. Read = RapidOCR PP-OCRv4 detection + recognition on the whole "
            f"frame, every character (paper Eq. 4). Beam gain g on a road scene: our high beams' "
            f"intensity_cd x g, re-rendered{'; the controller prior mask.first_guess x g where the scene sets mask.prior_beam_cd' if not args.fixed_prior else ', the controller prior kept at the scene value (--fixed-prior)'}. "
            f"Seconds: wall per row (render + loop + OCR). "
            f"Machine: {machine_line()}.\n\n"
            f"{markdown_table(header, sorted(rows, key=lambda r: r[0]))}\n\n## Per frame\n\n{detail}\n{extra}")
    save_text(output_folder(args.results) / args.out, text)
    return text


def main(argv=None):
    from poevp_optics.core import runtime

    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="scenes/highbeam_plate")
    ap.add_argument("--texts", default=",".join(TEXTS))
    ap.add_argument("--gains", default="1,10")       # x the scene's high beams
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--scale", type=int, default=1)  # x the scene's resolution and focal length
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--fixed-prior", action="store_true", help="keep the scene's mask.first_guess at every "
                    "beam gain (mask.prior_beam_cd=0; by default a scene that sets it scales the prior with the beams)")
    ap.add_argument("--out", default="plate_band.md")
    ap.add_argument("--save-captures", default=None, help="folder for one .npz per (gain, text): raw 8-bit "
                    "captures, masks, plate boxes (for reading them again without rendering)")
    add_results_flag(ap)
    args = ap.parse_args(argv)
    runtime.set_threads(2)
    rows, per_frame = [], []
    sets = [*scale_overrides(args.scene, args.scale), *args.set]
    for gain in (float(g) for g in args.gains.split(",")):
        for text in args.texts.split(","):
            t0, c0 = time.perf_counter(), cpu_seconds()
            ov = [f'plate.text="{text}"', f"timing.frames={args.frames}", *sets,
                  *beam_overrides(args.scene, gain, args.fixed_prior)]
            spec, renderer, ex = render_once(args.scene, ov)
            npz = None
            if args.save_captures:
                import os
                os.makedirs(args.save_captures, exist_ok=True)
                npz = os.path.join(args.save_captures, f"{gain:g}x_{text.replace(' ', '_')}.npz")
            fr = loop_frames(spec, renderer, ex if spec.has_road else scaled(ex, gain), text, save_npz=npz)
            del ex
            s = summarise(fr, spec.mask.band_low, spec.mask.band_high)
            mc = [r["mc_error"] for r in fr if r.get("mc_error") is not None]
            rows.append([gain, text, s["frames"], s["read"], s["in_band"], s["white_p10"], s["white_median"],
                         s["white_p90"], s["saturated"], float(np.median(mc)) if mc else float("nan"),
                         time.perf_counter() - t0, cpu_seconds() - c0])
            per_frame.append((gain, text, fr))
            print(rows[-1], flush=True)
            write_results(args, sets, rows, per_frame)
    print(write_results(args, sets, rows, per_frame))


if __name__ == "__main__":
    main()
