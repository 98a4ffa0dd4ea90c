"""Render error against run time: time to 1 % and 3 % plate (ROI) error, naive baseline vs the
new defaults, measured side by side in one run.

Configurations (each in its own process: a Mitsuba variant is process-wide state):

* baseline: spectral path, `independent` sampler, uniform light selection (every emitter's
  sampling weight 1);
* previous default: the scene's path (mono), `independent`, the XML's own weights;
* new default: the scene's path, `render.sampler` default, `render.light_selection = power`.

The first frame's pose of the scene is rendered once per spp with a fixed seed and timed (wall
and process CPU seconds: the CPU time is less sensitive to other jobs on a shared machine). Its
error is the RMS per-pixel difference to a reference over the plate ROI, the reference's own
variance subtracted, relative to the reference's ROI mean. The reference (new defaults, ref-spp
in 8 independent-seed replicates, cached under the cache folder) comes from the mono path, which
is exact here (renderer.py: one SPD shape, one bounce); the spectral path's mean offset from it is
printed. The time to an error is interpolated in log-log between the measured points, or
extrapolated from the last two when the error was not reached (marked). Also: every sampler at
64 spp, and the light selections at 64 spp (variance of the ROI and frame error).

    .venv/bin/python -m benchmarks.render_error_vs_time [--scene scenes/highbeam_plate] [--resolution 184x320] [--results]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import subprocess
import sys
import time

import numpy as np

from benchmarks.common import add_results_flag, machine_line, markdown_table, output_folder, save_figure, save_text

CONFIGS = {
    "baseline": {"mode": "spectral", "sampler": "independent", "lights": "uniform", "spps": [4, 16, 64, 256, 1024]},
    "previous default": {"mode": "auto", "sampler": "independent", "lights": "xml", "spps": [4, 16, 64, 256]},
    "new default": {"mode": "auto", "sampler": None, "lights": "power", "spps": [4, 16, 64, 256]},
}
TARGETS = (0.03, 0.01)
REF_SPLITS = 8


def _renderer(scene, res, mode, sampler, lights):
    from poevp_optics.render.renderer import DEFAULT_SAMPLER, Renderer
    from poevp_optics.scene.load import load_scene

    spec = load_scene(scene, [f"render.resolution={res}", f"render.spectral_mode='{mode}'",
                              f"render.sampler='{sampler or DEFAULT_SAMPLER}'", f"render.light_selection='{lights}'"])
    r = Renderer(spec.resolved.render)
    r.set_time(float(spec.subframe_times_s(0)[0]))
    t0 = time.perf_counter()
    r.select_lights()
    pilot_s = time.perf_counter() - t0
    return r, pilot_s


def reference(scene, res, ref_spp):
    """(mean, variance of the mean, ROI box) of the new defaults at ref_spp; cached."""
    import mitsuba as mi

    from poevp_optics.core.runtime import cache_dir
    from poevp_optics.core.seeds import render_seeds
    from poevp_optics.scene.load import resolve_scene_path

    p = resolve_scene_path(scene)
    key = hashlib.sha256(p.read_bytes() + (p.parent / "scene.xml").read_bytes()
                         + f"{res}{ref_spp}{mi.__version__}{REF_SPLITS}".encode()).hexdigest()[:16]
    path = cache_dir("benchmarks", f"render_ref_{key}.npz")
    if path.is_file():
        z = np.load(path)
        return z["mean"], z["var"], tuple(int(v) for v in z["box"])
    r, _ = _renderer(scene, res, "auto", None, "power")
    mean, var = r.render_with_error(render_seeds(4242, 0, 0, REF_SPLITS), ref_spp)
    box = r.roi_box()
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, mean=mean.astype(np.float64), var=var, box=np.array(box))
    return mean.astype(np.float64), var, box


def _roi_error(img, ref, ref_var, box):
    y0, x0, y1, x1 = box
    d2 = np.mean((img[y0:y1, x0:x1] - ref[y0:y1, x0:x1]) ** 2) - np.mean(ref_var[y0:y1, x0:x1])
    return math.sqrt(max(d2, 0.0)) / float(np.mean(ref[y0:y1, x0:x1]))


def _timed_render(r, seed, spp):
    """One timed render after an untimed one at the same spp (a new sample count compiles new
    kernels; a run compiles once, its spp is fixed)."""
    r.render_once(seed + 1_000_000, spp)
    t0, c0 = time.perf_counter(), time.process_time()
    img = r.render_once(seed, spp).astype(np.float64)
    return img, time.perf_counter() - t0, time.process_time() - c0


def cache_reference(scene, res, ref_spp) -> bool:
    """Render (or find) the cached reference; True when done."""
    reference(scene, res, ref_spp)
    return True


def measure(scene, res, ref_spp, name):
    """Rows [config, variant, spp asked, spp used, wall s, cpu s, ROI error] of one configuration."""
    ref, ref_var, box = reference(scene, res, ref_spp)
    c = CONFIGS[name]
    r, pilot_s = _renderer(scene, res, c["mode"], c["sampler"], c["lights"])
    rows, last = [], None
    for spp in c["spps"]:
        img, wall, cpu = _timed_render(r, 1000 + spp, spp)
        rows.append([name, r.variant, r.scene.render.sampler, spp, r.last_spp, wall, cpu,
                     _roi_error(img, ref, ref_var, box)])
        last = img
    y0, x0, y1, x1 = box
    offset = float(np.mean(last[y0:y1, x0:x1]) / np.mean(ref[y0:y1, x0:x1]) - 1)
    return {"rows": rows, "pilot_s": pilot_s, "roi_mean_offset": offset, "weights": r.light_weights}


def measure_samplers(scene, res, ref_spp, spp=64):
    """Every sampler (mono path, power light selection) at `spp`: [sampler, spp used, wall, cpu, ROI error]."""
    from poevp_optics.render.samplers import SAMPLERS

    ref, ref_var, box = reference(scene, res, ref_spp)
    rows = []
    for name in SAMPLERS:
        r, _ = _renderer(scene, res, "auto", name, "power")
        img, wall, cpu = _timed_render(r, 777, spp)
        err = _roi_error(img, ref, ref_var, box)
        rows.append([name, r.last_spp, wall, cpu, err, 1.0 / (err * err * cpu)])
    return rows


def measure_lights(scene, res, spp=64):
    """Light selections (mono, default sampler) at `spp`, 2 splits: estimated ROI and frame errors."""
    from poevp_optics.core.seeds import render_seeds
    from poevp_optics.render.progressive import rel_error

    rows = []
    for lights in ("uniform", "xml", "power"):
        r, _ = _renderer(scene, res, "auto", None, lights)
        mean, var = r.render_with_error(render_seeds(31, 0, 0, 2), spp)
        w = ", ".join(f"{k} {v:.3g}" for k, v in r.light_weights.items())
        rows.append([lights, w, rel_error(mean, var, r.roi_box()), rel_error(mean, var)])
    return rows


def time_to(rows, target, col):
    """Seconds (column `col`) to reach ROI error `target`: log-log interpolation, else extrapolation
    from the last two points (returns (seconds, extrapolated))."""
    pts = sorted((r[col], r[-1]) for r in rows)
    t, e = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    for i in range(len(pts) - 1):
        if e[i] >= math.log(target) >= e[i + 1]:
            f = (math.log(target) - e[i]) / (e[i + 1] - e[i])
            return float(math.exp(t[i] + f * (t[i + 1] - t[i]))), False
    if math.log(target) > e[0]:
        return float(pts[0][0]), False
    slope = (e[-1] - e[-2]) / (t[-1] - t[-2])
    return float(math.exp(t[-1] + (math.log(target) - e[-1]) / slope)), True


def _in_process(fn: str, *args):
    code = (f"import json; from benchmarks.render_error_vs_time import {fn}; "
            f"print('RESULT' + json.dumps({fn}(*{list(args)!r})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(out.stderr[-3000:])
    return json.loads([ln for ln in out.stdout.splitlines() if ln.startswith("RESULT")][-1][6:])


def summary(results):
    """Rows [config, target, wall s, cpu s, extrapolated] and the ratios baseline / new."""
    rows, ratios = [], {}
    for target in TARGETS:
        got = {}
        for name, res in results.items():
            (tw, xw), (tc, xc) = time_to(res["rows"], target, 5), time_to(res["rows"], target, 6)
            got[name] = (tw, tc)
            rows.append([name, f"{target:.0%}", tw, tc, "yes" if (xw or xc) else "no"])
        ratios[target] = (got["baseline"][0] / got["new default"][0], got["baseline"][1] / got["new default"][1])
    return rows, ratios


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="scenes/highbeam_plate")
    ap.add_argument("--resolution", default="184x320", help="HxW (368x640 is the scene's; 4x the time)")
    ap.add_argument("--ref-spp", type=int, default=2048)
    add_results_flag(ap)
    args = ap.parse_args(argv)
    dest = output_folder(args.results)
    h, w = (int(v) for v in args.resolution.lower().split("x"))
    res = f"[{h},{w}]"
    t_all = time.perf_counter()
    _in_process("cache_reference", args.scene, res, args.ref_spp)              # cache it once
    results = {name: _in_process("measure", args.scene, res, args.ref_spp, name) for name in CONFIGS}
    samplers = _in_process("measure_samplers", args.scene, res, args.ref_spp)
    lights = _in_process("measure_lights", args.scene, res)
    rows = [row for r in results.values() for row in r["rows"]]
    srows, ratios = summary(results)
    text = report_text(args, res, rows, srows, ratios, samplers, lights, results, time.perf_counter() - t_all)
    print(text)
    save_text(dest / "render_error_vs_time.md", text)
    plot(results, dest)


def report_text(args, res, rows, srows, ratios, samplers, lights, results, total_s) -> str:
    import os

    load = os.getloadavg()[0]
    var_ratio = ", ".join(f"{r[0]}: ROI variance x{(r[2] / lights[0][2]) ** 2:.2f}, frame x{(r[3] / lights[0][3]) ** 2:.2f}"
                          for r in lights[1:])
    return (
        f"# Render error against run time\n\nScene `{args.scene}` at {res}, frame 0 pose; error = RMS "
        f"per-pixel difference over the plate ROI to a {args.ref_spp}-spp reference (new defaults, "
        f"{REF_SPLITS} replicates, its variance subtracted) / the reference's ROI mean. Machine: "
        f"{machine_line()}; load average {load:.1f} at the end (a shared machine: CPU seconds are "
        f"the steadier measure). Benchmark run time {total_s / 60:.1f} min.\n\n"
        f"## Time to 3 % and 1 % plate error\n\n"
        + markdown_table(["configuration", "ROI error", "wall s", "CPU s", "extrapolated"], srows)
        + "\n\n" + "\n".join(f"* baseline / new default at {t:.0%}: **{a:.1f}x** less wall time, "
                             f"**{b:.1f}x** less CPU time" for t, (a, b) in ratios.items())
        + f"\n* spectral baseline's ROI mean vs the mono reference: "
          f"{results['baseline']['roi_mean_offset']:+.2%} at {CONFIGS['baseline']['spps'][-1]} spp "
          f"(noise included): the mono reference is the spectral path's expectation.\n"
        + f"* light-selection pilot: {results['new default']['pilot_s']:.2f} s once per renderer "
          f"(not in the times above).\n\n## Measured points\n\n"
        + markdown_table(["configuration", "variant", "sampler", "spp asked", "spp used", "wall s", "CPU s",
                          "ROI error"], rows)
        + "\n\n## Samplers at 64 spp (mono path, power light selection)\n\nEfficiency = 1 / "
          "(error^2 x CPU s), one render each (single-run scatter of a few 10 %). The default "
          "(renderer.DEFAULT_SAMPLER) is the most efficient sampler that renders any split's count "
          "exactly: `ldsampler` rounds each split up to a power of 4 (16 spp in 2 splits renders 32), "
          "`orthogonal` to a prime squared.\n\n"
        + markdown_table(["sampler", "spp used", "wall s", "CPU s", "ROI error", "efficiency"], samplers)
        + "\n\n## Light selection at 64 spp (mono path, default sampler, 2 splits)\n\n"
        + markdown_table(["light selection", "sampling weights", "est. ROI error", "est. frame error"], lights)
        + f"\n\nRelative to uniform: {var_ratio}.\n")


def plot(results, dest):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.2))
    for (name, res), marker in zip(results.items(), "soD"):
        rows = res["rows"]
        ax.loglog([r[6] for r in rows], [r[7] for r in rows], marker=marker, label=name)
        for r in rows:
            ax.annotate(f"{r[4]}", (r[6], r[7]), fontsize=7, xytext=(3, 3), textcoords="offset points")
    for t in TARGETS:
        ax.axhline(t, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("CPU seconds per render")
    ax.set_ylabel("plate (ROI) relative RMS error")
    ax.set_title("highbeam_plate: plate error vs time (labels: spp)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    print("wrote", save_figure(fig, dest / "render_error_vs_time.png"))


if __name__ == "__main__":
    main()
