"""What the default scene `night_road` must show, measured on one run of the scene as `make demo`
runs it (the causal loop): per frame the plate's distance, observation and entrance angles, R_A,
peak over saturation, the LDR twin's and the encoded capture's whole-frame OCR (RapidOCR PP-OCRv4
detection + recognition on the raw 8-bit frame, no crop: analysis/recognition.py frame_reads),
the encoded plate white (p90 of the plate box / 255, band 40-90 %), the plate's MC error; then the
scene's DR demand beside the DMD floor and the objective's glare floor, with which binds.

    .venv/bin/python -m benchmarks.night_road_check [--scale S] [--set key=value ...] [--results]

`--scale S` runs the camera at S x the scene's mirrors over the same field, as `poevp render --scale S`
(scene/scale.py); the default, 1, is the scene's own 1920x1080.

Writes night_road.md and night_road.png (peak over saturation vs distance) into out/benchmarks/
(benchmarks/results/ with --results).
"""

from __future__ import annotations

import argparse
import tempfile
import time

from benchmarks.common import add_results_flag, cpu_seconds, machine_line, markdown_table, output_folder, save_text


def run(scene: str, sets: list[str]):
    """(spec, report, kept frames, wall s, CPU s) of one run of `scene` with every frame kept."""
    from poevp_optics.apps.run.render_run import run_frames
    from poevp_optics.scene.load import load_scene

    spec = load_scene(scene, sets)
    t0, c0 = time.perf_counter(), cpu_seconds(children=True)
    with tempfile.TemporaryDirectory() as tmp:
        report, kept = run_frames(spec, tmp, False, write_images=False,
                                  keep_frames=tuple(range(spec.timing.frames)))
    return spec, report, kept, time.perf_counter() - t0, cpu_seconds(children=True) - c0


def scaled_sets(scene: str, scale: str, sets: list[str]) -> list[str]:
    """`sets` preceded by the overrides of `--scale` (scene/scale.py; none at 1)."""
    from poevp_optics.scene.load import load_scene
    from poevp_optics.scene.scale import parse_scale, scaled_resolution, scaling_for

    k = parse_scale(scale)
    if abs(k - 1.0) < 1e-12:
        return list(sets)
    spec = load_scene(scene, sets)
    return [*scaling_for(spec, scaled_resolution(spec.render.resolution, k), f"--scale {scale}").sets, *sets]


def frame_rows(report: dict, kept: dict, label: str) -> list[list]:
    """One table row per frame (module docstring)."""
    from poevp_optics.analysis.metrics import plate_white_fraction
    from poevp_optics.analysis.recognition import frame_reads

    rows = []
    for f in report["per_frame"]:
        k, p = kept[f["index"]], f["plate"]
        near = min(p["lamps"].values(), key=lambda lamp: lamp["observation_deg"])
        ldr_read = frame_reads(k["ldr"], label)[0]
        enc_read, texts = frame_reads(k["capture"], label)
        rows.append([f["index"], "init" if f.get("init") else "loop", p["distance_m"], near["observation_deg"],
                     near["entrance_deg"], near["r_a"], p["peak_over_saturation"],
                     "yes" if ldr_read else "no", "yes" if enc_read else f"no ({texts or '-'})",
                     plate_white_fraction(k["capture"], k["roi"]), f["saturated_fraction_roi"]["encoded"],
                     f.get("attenuator", {}).get("transmission", 1.0), f["rel_error_roi"]])
    return rows


def summary(rows: list[list], lo: float, hi: float) -> dict:
    loop = [r for r in rows if r[1] == "loop"]
    return {"loop": len(loop), "ldr_read": sum(r[7] == "yes" for r in rows),
            "enc_read": sum(r[8] == "yes" for r in loop),
            "in_band": sum(lo <= r[9] <= hi for r in loop), "frames": len(rows)}


def main(argv=None):
    from poevp_optics.apps.run import night_road
    from poevp_optics.core import runtime

    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="scenes/night_road")
    ap.add_argument("--scale", default="1", help="x the scene's mirrors over the same field (1/6, 0.5, 1)")
    ap.add_argument("--set", action="append", default=[])
    add_results_flag(ap)
    args = ap.parse_args(argv)
    dest = output_folder(args.results)
    runtime.set_threads(2)
    spec, report, kept, wall, cpu = run(args.scene, scaled_sets(args.scene, args.scale, args.set))
    label = spec.plate.text
    rows = frame_rows(report, kept, label)
    s = summary(rows, spec.mask.band_low, spec.mask.band_high)
    nr = report["night_road"]
    night_road.plot(dest / "night_road.png", nr, f"{spec.name}: plate peak over saturation vs distance")
    header = ["frame", "", "distance (m)", "observation (deg)", "entrance (deg)", "R_A (cd/lx/m2)",
              "plate peak / saturation", "LDR read", "encoded read", "encoded white p90/255",
              "encoded saturated plate", "attenuator transmission", "plate MC error"]
    dr = [["plate demand", nr["plate_demand_db"]], ["frame demand", nr["frame_demand_db"]],
          [f"DMD floor ({nr['dmd_binding_part']} binds it)", nr["dmd_floor_db"]],
          ["objective glare floor (veil on the plate)", nr["glare_floor_db"]],
          ["ink below sheeting", nr["ink_over_sheeting_db"]]]
    text = (f"# night_road: what the default scene must show\n\n"
            f"Scene `{args.scene}` {' '.join(args.set) or '(as `make demo` runs it)'}"
            f"{'' if args.scale == '1' else f' at --scale {args.scale}'}: "
            f"{spec.timing.frames} frames at {spec.timing.fps:g} fps, "
            f"{spec.render.resolution[0]}x{spec.render.resolution[1]}, {spec.render.spp} spp, "
            f"predictor `{spec.predictor.name}`, loop `{spec.loop.mode}`, mask `{spec.mask.law}`, "
            f"plate `{label}`. Angles and R_A for the lamp nearer the camera (smaller observation "
            f"angle; the report has both). Read = whole-frame detection + recognition on the raw "
            f"8-bit frame, every character. Run: {wall:.0f} s wall, {cpu:.0f} CPU-s "
            f"(this script; OCR not included). Machine: {machine_line()}.\n\n"
            f"{markdown_table(header, rows)}\n\n"
            f"- LDR twin read: {s['ldr_read']} of {s['frames']} frames\n"
            f"- encoded capture read: {s['enc_read']} of {s['loop']} loop frames (after "
            f"{spec.loop.init_frames} white init frames)\n"
            f"- encoded plate white in {spec.mask.band_low:.0%}-{spec.mask.band_high:.0%}: "
            f"{s['in_band']} of {s['loop']} loop frames\n\n"
            f"## Dynamic range (dB of attenuation)\n\n{markdown_table(['', 'dB'], dr)}\n\n"
            f"Binding: **{nr['binding']}**. {nr['statement']}\n")
    print(text)
    save_text(dest / "night_road.md", text)


if __name__ == "__main__":
    main()
