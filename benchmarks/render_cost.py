"""Render cost of the default scene: where the CPU time of a frame goes, how it grows
with the resolution, what each region's Monte Carlo error costs, and the ROI box render.

Scene `scenes/night_road`, at resolutions from 184x320 to its own (the DLP6500's) 1080x1920, each
with the objective's focal length, its guard cap, the mask's smoothing and the attenuator's size in
mirrors scaled by k = columns / the scene's columns, as `poevp render --resolution HxW` scales them
(scene/scale.py `scaling_for`: the field of view kept; `scaled_sets`). All times are process CPU
seconds (all threads; less sensitive to other jobs on a shared machine than wall time):

1. Stages per frame: a `poevp render` run of `--frames` frames (the first two are the loop's
   white initialisation frames) at `render.spp` = 8, each stage's seconds taken with the process
   CPU clock (time.perf_counter replaced by time.process_time in that process): Mitsuba render,
   objective (glare and blur), DMD + relay + sensor, reconstruction, mask + predictor (the loop),
   the temporal-error check, writing the outputs, setup (scene load, PSF tables).
2. Error and cost per sample, at the first (plate at 60 m) and last (10 m) frame's first pose:
   the plate (ROI) error from the ROI box render at two spp (8 independent-seed parts each;
   the box render is the same estimator as mi.render restricted to the box:
   tests/physics/test_roi_render.py), fitted e = c / sqrt(spp) (the free log-log slope is
   printed beside it); the rest of the frame: each pixel's own relative error (median over the
   field of view) from whole-frame renders at two spp. The spp each needs for 3 % and 1 % is
   (c / target)^2. Cost: mi.render of the whole frame at two spp (a + b spp, per radiance node),
   the box render at two spp.
3. Time to plate error per frame (2 radiance nodes per frame, as the scene): before = the whole
   frame at the spp the plate needs; after = the whole frame at `--frame-spp` + the box at the rest.
4. Before and after side by side: `poevp render` runs at `--run-resolution` of `--frames`
   frames, the scene's spp vs `--frame-spp` + `--roi-spp`: CPU s, wall s and the report's plate
   and frame errors.

    .venv/bin/python -m benchmarks.render_cost [--full] [--resolutions 184x320,368x640,736x1280,1080x1920] [--results]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time

import numpy as np

from benchmarks.common import add_results_flag, machine_line, markdown_table, output_folder, save_figure, save_text

SCENE = "scenes/night_road"
TARGETS = (0.03, 0.01)
NODES_PER_FRAME = 2
LIGHT_NOTE = """## Light sampling (why the plate's error is not light-selection noise)

Mitsuba's `path` integrator takes one emitter sample per path vertex and picks the emitter with
probability proportional to its `sampling_weight` (Mitsuba 3 PR #721, "Add support for per-emitter
sampling weight"); render/lights.py sets the weights from a pilot of each emitter's contribution over
the frame and the plate's box (p ~ sqrt(E[f^2])), so at the plate the two high beams are picked in
about the ratio they light it, and the `multijitter` sampler stratifies that choice within each
pixel. The measured plate error falls as spp^-0.8 to spp^-1.05 between 8 and 32 spp (table above),
faster than the 1/sqrt(spp) of unstratified noise: what is left is stratifiable (the pixel's
footprint over the characters and the beam choice), and the ROI box render is what reduces it where
it matters. Not used: the `direct` integrator with `emitter_samples` > 1, whose delta-emitter
samples are not divided by emitter_samples (Mitsuba 3 PR #1863, open: a bias for our photometric
point beams); an integrator summing every delta lamp per sample (a custom Python integrator) was not
built: with the selection already stratified it would add 4 shadow rays per sample for little.
"""


def scaled_sets(h: int, w: int) -> list[str]:
    """--set overrides for night_road at h x w mirrors, the field of view kept (module docstring);
    none at the scene's own resolution."""
    from poevp_optics.scene.load import load_scene
    from poevp_optics.scene.scale import scaling_for

    return list(scaling_for(load_scene(SCENE), (h, w), f"--resolution {h}x{w}").sets)


def stages(h: int, w: int, frames: int, extra: list[str]) -> dict:
    """One `poevp render` run; its per-stage CPU seconds (module docstring 1/4)."""
    import tempfile

    time.perf_counter = time.process_time                 # every stage timer reads process CPU
    from poevp_optics.apps.run.render_run import BackgroundWriter

    BackgroundWriter.in_line = True                       # so the writing's CPU clock is its own
    from poevp_optics.render.ahead import RenderAhead

    RenderAhead.enabled = False                           # and the render's (no frame rendered ahead)
    from poevp_optics.cli import main

    with tempfile.TemporaryDirectory() as d:
        wall0 = time.time()
        sets = scaled_sets(h, w) + [f"timing.frames={frames}", *extra]
        args = ["render", SCENE, "--out", f"{d}/run", "--quiet"] + [a for s in sets for a in ("--set", s)]
        assert main(args) == 0
        wall = time.time() - wall0
        r = json.loads(open(f"{d}/run/report.json").read())
    st = r["stages"]
    cpu = {"render (Mitsuba)": st["render"]["mitsuba_seconds"], "setup": st["render"]["setup_seconds"],
           "objective": st.get("objective", {}).get("seconds", 0.0),
           "DMD + relay + sensor": sum(st[k]["seconds"] for k in ("dmd", "relay", "sensor")),
           "reconstruct": st["reconstruct"]["seconds"],
           "mask + predictor (loop)": st["mask"]["seconds"] + (st.get("predict", {}).get("total_seconds") or 0.0),
           "temporal check": r["errors"]["temporal"].get("seconds") or 0.0,
           "writing": r["io_seconds"]}
    # the rest: the LDR twin's and the oracle mask's captures, metrics, the night-road records
    cpu["other"] = r["total_seconds"] - sum(cpu.values())
    pf = r["per_frame"]
    return {"cpu": cpu, "total_cpu": r["total_seconds"], "wall": wall, "frames": frames,
            "plate_error": st["render"]["rel_error_roi"], "frame_unclipped": st["render"].get("rel_error_unclipped"),
            "pixel_median": st["render"].get("rel_error_pixel_median"),
            "plate_error_max": max(f["rel_error_roi"] for f in pf if f["rel_error_roi"] is not None)}


def _fit(spps, errs):
    """c of e = c / sqrt(spp) (least squares in log with slope -1/2) and the free log-log slope.
    (The plate's c is then anchored at the higher spp: a stratified sampler converges faster
    than 1/sqrt(spp) over 8-32 spp (slope -0.8..-0.9 here), so the 1/sqrt law from the higher
    point over-states the spp a lower error needs: conservative.)"""
    ls, le = np.log(spps), np.log(errs)
    c = float(np.exp(np.mean(le + 0.5 * ls)))
    slope = float((le[-1] - le[0]) / (ls[-1] - ls[0]))
    return c, slope


def per_sample(h: int, w: int, spp_lo: int, spp_hi: int) -> dict:
    """Errors and costs per sample at the first and last frame's first pose (module docstring 2)."""
    from poevp_optics.core.seeds import render_seeds
    from poevp_optics.render.progressive import pixel_rel_errors
    from poevp_optics.render.renderer import Renderer
    from poevp_optics.scene.load import load_scene

    spec = load_scene(SCENE, scaled_sets(h, w))
    r = Renderer(spec.resolved.render)
    out = {"pixels": h * w, "poses": []}
    frame_cost = []
    for fi in (0, spec.timing.frames - 1):
        r.set_time(float(spec.subframe_times_s(fi)[0]))
        r.select_lights()
        box = r.roi_box()
        errs, costs = [], []
        for spp in (spp_lo, spp_hi):
            r.render_box(1, spp, box)                      # compile this spp's kernel: untimed
            c0 = time.process_time()
            m, v, used = r.render_box_with_error(render_seeds(3, fi, spp, 8), spp * 8, box)
            costs.append((time.process_time() - c0) / 8)
            errs.append(float(np.sqrt(np.mean(v) * 8) / np.mean(m)))   # one part's (spp) error
        c, slope = _fit([spp_lo, spp_hi], errs)
        c = errs[1] * math.sqrt(spp_hi)         # the 1/sqrt law anchored at the higher spp
        bpx = (box[2] - box[0]) * (box[3] - box[1])
        b_cost = (costs[1] - costs[0]) / (spp_hi - spp_lo)
        out["poses"].append({"frame": fi, "box": list(box), "box_px": bpx, "plate_c": c, "plate_slope": slope,
                             "plate_errors": errs, "box_cpu_per_spp": max(b_cost, 1e-9),
                             "box_cpu_fixed": max(costs[0] - b_cost * spp_lo, 0.0)})
    g = r.guard_px
    for spp in (spp_lo // 2, spp_hi // 2):                 # whole frame: cost and the rest's error
        r.render_once(2, spp)
        c0 = time.process_time()
        imgs = [r.render_once(s, spp).astype(np.float64) for s in render_seeds(4, 0, spp, 4)]
        cpu = (time.process_time() - c0) / 4
        m = np.mean(imgs, axis=0)
        v = np.var(imgs, axis=0, ddof=1) / 4
        view = np.s_[g:g + h, g:g + w]
        med, _ = pixel_rel_errors(m[view], v[view], np.zeros((h, w), bool))
        frame_cost.append((spp, cpu, med * math.sqrt(4)))  # one render's error (4 averaged)
    (s0, t0, e0), (s1, t1, e1) = frame_cost
    b = (t1 - t0) / (s1 - s0)
    out.update({"frame_cpu_per_spp": max(b, 1e-9), "frame_cpu_fixed": max(t0 - b * s0, 0.0),
                "rest_c": _fit([s0, s1], [e0, e1])[0], "rest_slope": _fit([s0, s1], [e0, e1])[1]})
    return out


def time_to_error(ps: dict, pose: dict, target: float, frame_spp: int) -> tuple[float, float, int, int]:
    """CPU s per frame to plate error `target`: (before, after, spp before, roi spp after)."""
    need = max(1, math.ceil((pose["plate_c"] / target) ** 2))
    before = NODES_PER_FRAME * (ps["frame_cpu_fixed"] + ps["frame_cpu_per_spp"] * need)
    roi = max(0, need - frame_spp)
    after = NODES_PER_FRAME * (ps["frame_cpu_fixed"] + ps["frame_cpu_per_spp"] * frame_spp
                               + (pose["box_cpu_fixed"] + pose["box_cpu_per_spp"] * roi if roi else 0.0))
    return before, after, need, roi


def _in_process(fn: str, *args):
    code = (f"import json; from benchmarks.render_cost import {fn}; "
            f"print('RESULT' + json.dumps({fn}(*{list(args)!r})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(out.stderr[-3000:])
    return json.loads([ln for ln in out.stdout.splitlines() if ln.startswith("RESULT")][-1][6:])


def _plot(per, res_list, frame_spp, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.5))
    errs = np.geomspace(0.005, 0.2, 40)
    for (h, w), ps in zip(res_list, per):
        pose = max(ps["poses"], key=lambda p: p["plate_c"])
        b = [time_to_error(ps, pose, e, frame_spp)[0] for e in errs]
        a = [time_to_error(ps, pose, e, frame_spp)[1] for e in errs]
        line, = a1.loglog(b, errs, "--", label=f"{h}x{w} before")
        a1.loglog(a, errs, "-", color=line.get_color(), label=f"{h}x{w} after")
    a1.axhline(0.03, color="k", lw=0.5)
    a1.axhline(0.01, color="k", lw=0.5)
    a1.set_xlabel("CPU s per frame (render)")
    a1.set_ylabel("plate MC error")
    a1.set_title(f"time to plate error (after: frame {frame_spp} spp + ROI box)")
    a1.legend(fontsize=7)
    px = [ps["pixels"] for ps in per]
    cost = [NODES_PER_FRAME * (ps["frame_cpu_fixed"] + 8 * ps["frame_cpu_per_spp"]) for ps in per]
    a2.loglog(px, cost, "o-", label="whole frame, 8 spp, 2 nodes")
    a2.set_xlabel("pixels")
    a2.set_ylabel("CPU s per frame (render)")
    a2.set_title("render cost vs pixels")
    a2.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the default: 3 frames per run, stages at the "
                    "first and last resolution (~8 min on 2 shared cores)")
    ap.add_argument("--full", action="store_true", help="21 frames per run, stages at every resolution")
    ap.add_argument("--resolutions", default="184x320,368x640,736x1280,1080x1920")
    ap.add_argument("--frames", type=int, default=None, help="frames per run (quick: 3, else 21)")
    ap.add_argument("--run-resolution", default="1080x1920")
    ap.add_argument("--frame-spp", type=int, default=4)
    ap.add_argument("--roi-spp", type=int, default=28)
    ap.add_argument("--out", default="render_cost")
    add_results_flag(ap)
    args = ap.parse_args(argv)
    dest = output_folder(args.results)
    args.quick = not args.full
    frames = args.frames or (3 if args.quick else 21)
    res_list = [tuple(int(v) for v in r.lower().split("x")) for r in args.resolutions.split(",")]
    t_all = time.time()
    per = [_in_process("per_sample", h, w, 8, 32) for h, w in res_list]
    stage_res = [res_list[0], res_list[-1]] if args.quick else res_list
    st = {f"{h}x{w}": _in_process("stages", h, w, frames, ["render.spp=8"]) for h, w in stage_res}
    rh, rw = (int(v) for v in args.run_resolution.lower().split("x"))
    after_sets = [f"render.spp={args.frame_spp}", f"render.roi_spp={args.roi_spp}"]
    runs = {"before (render.spp=8)": st.get(f"{rh}x{rw}") or _in_process("stages", rh, rw, frames, ["render.spp=8"]),
            f"after (render.spp={args.frame_spp}, roi_spp={args.roi_spp})": _in_process("stages", rh, rw, frames, after_sets)}

    lines = [f"# Render cost of {SCENE}", "", f"Machine: {machine_line()}. Process CPU seconds "
             "(all threads; the machine is shared, so wall time is not the measure). "
             f"`.venv/bin/python -m benchmarks.render_cost{' --quick' if args.quick else ''}`: {frames} frames per run, "
             f"benchmark {time.time() - t_all:.0f} s wall. Resolutions scale the objective's focal length and "
             "guard cap, mask.smooth_px and attenuator.serve_min_mirrors with the columns, as `--resolution` does "
             "(the field kept).", ""]
    names = list(next(iter(st.values()))["cpu"])
    lines += ["## CPU s per frame by stage (render.spp = 8, 2 radiance nodes per frame)", "",
              markdown_table(["resolution", *names, "total / frame", "plate error"],
                             [[k, *[v["cpu"][n] / v["frames"] for n in names], v["total_cpu"] / v["frames"],
                               v["plate_error"]] for k, v in st.items()]), "",
              "Setup (scene load, objective PSF tables, predictor weights) is paid once per run; here it is "
              "divided by the frames like the rest.", ""]
    rows = []
    for (h, w), ps in zip(res_list, per):
        for pose in ps["poses"]:
            rows.append([f"{h}x{w}", pose["frame"], pose["box_px"], f"{pose['plate_errors'][0]:.3%}",
                         pose["plate_c"], f"{pose['plate_slope']:.2f}",
                         *[math.ceil((pose["plate_c"] / t) ** 2) for t in TARGETS],
                         f"{ps['rest_c'] / math.sqrt(8):.3%}",
                         *[math.ceil((ps["rest_c"] / t) ** 2) for t in TARGETS]])
    lines += ["## The spp each region needs", "",
              "Plate: ROI box error at 8 and 32 spp (8 independent parts each, one part's error), e = c / sqrt(spp) "
              "anchored at 32 spp (the measured log-log slope beside it: steeper than -1/2, so the spp below "
              "are upper bounds). Rest of the frame: "
              "median over pixels of each pixel's own relative error (whole-frame renders at 4 and 16 spp).", "",
              markdown_table(["resolution", "frame", "box px", "plate err @8 spp", "plate c", "log-log slope",
                              "plate spp for 3 %", "for 1 %", "rest median err @8 spp",
                              "rest spp for 3 %", "for 1 %"], rows), ""]
    rows = []
    for (h, w), ps in zip(res_list, per):
        for pose in ps["poses"]:
            for t in TARGETS:
                b, a, need, roi = time_to_error(ps, pose, t, args.frame_spp)
                rows.append([f"{h}x{w}", pose["frame"], f"{t:.0%}", need, b, f"{args.frame_spp} + {roi}", a, b / a])
    px = np.array([ps["pixels"] for ps in per], dtype=float)
    cost = np.array([ps["frame_cpu_per_spp"] for ps in per])
    slope_px = float(np.polyfit(px, cost, 1)[0]) * 1e6
    lines += ["## Time to plate error (render CPU s per frame, 2 radiance nodes)", "",
              f"Before: the whole frame at the spp the plate needs. After: the whole frame at {args.frame_spp} "
              "spp and the ROI box (render.roi_spp) at the rest.", "",
              markdown_table(["resolution", "frame", "plate error", "spp before", "CPU s before",
                              "spp after (frame + box)", "CPU s after", "speed-up"], rows), "",
              f"Cost slope in pixels: {slope_px:.3g} CPU s per Mpx per spp per radiance node (whole-frame "
              "mi.render, least squares over the resolutions); per resolution: "
              + ", ".join(f"{h}x{w} {c * 1e6 / (h * w):.3g}" for (h, w), c in zip(res_list, cost)), ""]
    lines += [f"## Before and after, side by side ({rh}x{rw}, {frames} frames)", "",
              markdown_table(["run", "CPU s / frame", "render CPU s / frame", "wall s (shared machine)",
                              "plate error (mean)", "plate error (max frame)", "rest: pixel median error"],
                             [[k, v["total_cpu"] / v["frames"], v["cpu"]["render (Mitsuba)"] / v["frames"], v["wall"],
                               v["plate_error"], v["plate_error_max"], v["pixel_median"]] for k, v in runs.items()]),
              "", "The rest of the frame (road, car bodies) renders at the frame's spp: its error is the "
              "'rest' column, kept in the report (stages.render.rel_error_pixel_median).", ""]
    lines += [LIGHT_NOTE]
    save_text(dest / f"{args.out}.md", "\n".join(lines) + "\n")
    _plot(per, res_list, args.frame_spp, dest / f"{args.out}.png")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
