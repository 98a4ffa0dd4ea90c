"""Render error against run time over spp (1..256), default scene at 368x640.

For each spp the first frame's pose is rendered once with a fixed seed and timed; its error is
the RMS per-pixel difference to a 4096-spp reference, relative to the reference mean, over the
frame and over the plate ROI. Both render paths are measured side by side in one run: the
pre-integrated mono path the scene chooses, and the spectral path (wavelength sampling).

    python -m benchmarks.render_error_vs_time [--scene scenes/highbeam_plate] [--ref-spp 4096]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.common import machine_line, markdown_table, save_figure, save_text

SPPS = [1, 2, 4, 8, 16, 32, 64, 128, 256]


def measure(scene: str, mode: str, ref_spp: int, repeats: int = 3):
    from poevp_optics.render.renderer import Renderer
    from poevp_optics.scene.load import load_scene
    spec = load_scene(scene, ["render.resolution=[368,640]", f"render.spectral_mode='{mode}'"])
    r = Renderer(spec)
    t_mid = float(spec.subframe_times_s(0)[0])
    r.set_time(t_mid)
    box = r.roi_box()
    r.render_once(1, 1)                                   # JIT warm-up, not timed
    ref = np.mean([r.render_once(10_000 + i, ref_spp // 4).astype(np.float64) for i in range(4)], axis=0)
    rows = []
    for spp in SPPS:
        times, errs, errs_roi = [], [], []
        for rep in range(repeats):
            t0 = time.perf_counter()
            img = r.render_once(rep * 1000 + spp, spp).astype(np.float64)
            times.append(time.perf_counter() - t0)
            errs.append(np.sqrt(np.mean((img - ref) ** 2)) / np.mean(ref))
            if box:
                y0, x0, y1, x1 = box
                d, rr = img[y0:y1, x0:x1], ref[y0:y1, x0:x1]
                errs_roi.append(np.sqrt(np.mean((d - rr) ** 2)) / np.mean(rr))
        rows.append([mode, r.variant, spp, float(np.median(times)), float(np.mean(errs)),
                     float(np.mean(errs_roi)) if errs_roi else float("nan")])
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="scenes/highbeam_plate")
    ap.add_argument("--ref-spp", type=int, default=4096)
    args = ap.parse_args(argv)
    import subprocess
    import sys
    import json

    rows = []
    for mode in ("mono", "spectral"):
        # one process per path: a Mitsuba variant is process-wide state
        code = ("import json,sys; from benchmarks.render_error_vs_time import measure; "
                f"print(json.dumps(measure({args.scene!r}, {mode!r}, {args.ref_spp})))")
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        rows += json.loads(out.stdout.strip().splitlines()[-1])
    header = ["path", "variant", "spp", "wall s", "rel. error frame", "rel. error ROI"]
    table = markdown_table(header, rows)
    text = (f"# Render error against run time\n\nScene `{args.scene}`, 368x640, frame 0 pose; "
            f"error = RMS per-pixel difference to a {args.ref_spp}-spp reference / reference "
            f"mean. Machine: {machine_line()}.\n\n{table}\n")
    print(text)
    save_text("render_error_vs_time.md", text)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.2))
    for mode, marker in (("mono", "o"), ("spectral", "s")):
        sel = [r for r in rows if r[0] == mode]
        ax.loglog([r[3] for r in sel], [r[4] for r in sel], marker=marker, label=f"{mode}: frame")
        ax.loglog([r[3] for r in sel], [r[5] for r in sel], marker=marker, ls="--", label=f"{mode}: plate ROI")
        for r in sel[::2]:
            ax.annotate(f"{r[2]}", (r[3], r[4]), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xlabel("wall time per render (s)")
    ax.set_ylabel("relative RMS error")
    ax.set_title("highbeam_plate 368x640: render error vs time (labels: spp)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    print("wrote", save_figure(fig, "render_error_vs_time.png"))


if __name__ == "__main__":
    main()
