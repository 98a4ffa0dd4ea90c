"""Predictor budget sweep: as predictor + mask time grows from 2 to 40 ms, masks start
arriving after their display window opens; the saturated plate fraction, the plate's white in
band and whole-frame recognition, at 30 and 60 fps.

At 30 fps: exposure = DMD window = 28 ms, 8-bit (DLPC900: 28 ms / 255 = 110 us planes >= 105 us).
At 60 fps: 14 ms; an 8-bit mask would need 26.8 ms on a DLPC900 (camera: no illumination
gating), so the mask is 7-bit (14 ms / 127 = 110 us). Bus: 32-bit 200 MHz (paper App. D).
One render per frame rate; the camera loop runs on it once per (budget, late_mask).

    .venv/bin/python -m benchmarks.loop_timing_budget [--budgets-ms 2,4,...] [--frames 12] [--resolution 368x640] [--results]

Writes loop_timing_budget.md and .png into out/benchmarks/ (benchmarks/results/ with --results).
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from benchmarks.common import add_results_flag, machine_line, markdown_table, output_folder, save_figure, save_text
from benchmarks.plate_band import loop_frames, render_once, summarise

RATES = {30.0: (0.028, 8), 60.0: (0.014, 7)}


def main(argv=None):
    from poevp_optics.control.timing_budget import BudgetSpec
    from poevp_optics.core import runtime

    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="scenes/highbeam_plate")
    ap.add_argument("--budgets-ms", default="2,4,6,8,12,16,24,32,40")
    ap.add_argument("--modes", default="partial,next")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--resolution", default="368x640")
    ap.add_argument("--ocr", type=int, default=1)
    add_results_flag(ap)
    args = ap.parse_args(argv)
    dest = output_folder(args.results)
    runtime.set_threads(2)
    h, w = args.resolution.split("x")
    rows = []
    curves = {}
    for fps, (exposure, bits) in RATES.items():
        ov = [f"timing.fps={fps}", f"timing.exposure_s={exposure}", f"timing.dmd_window_s={exposure}",
              f"dmd.bits={bits}", f"timing.frames={args.frames}", f"render.resolution=[{h},{w}]"]
        t0 = time.perf_counter()
        spec, renderer, ex = render_once(args.scene, ov)
        render_s = time.perf_counter() - t0
        for mode in args.modes.split(","):
            for ms in [float(b) for b in args.budgets_ms.split(",")]:
                b = BudgetSpec(bus_hz=spec.budget.bus_hz, bus_width_bits=spec.budget.bus_width_bits,
                               compute="given", compute_s=ms * 1e-3, late_mask=mode)
                s2 = dataclasses.replace(spec, budget=b)
                fr = loop_frames(s2, renderer, ex, spec.plate.text, ocr=bool(args.ocr))
                s = summarise(fr, spec.mask.band_low, spec.mask.band_high)
                late = float(np.mean([r["late"] for r in fr if not r["init"]]))
                rows.append([fps, mode, ms, late, s["saturated"], s["in_band"],
                             s["read"] if args.ocr else "-", s["white_median"]])
                curves.setdefault((fps, mode), []).append((ms, s["saturated"], s["in_band"], late))
                print(rows[-1], flush=True)
        print(f"render {fps:g} fps: {render_s:.1f} s", flush=True)
    header = ["fps", "late_mask", "predictor + mask (ms)", "late fraction", "saturated plate",
              "white in 40-90 %", "read (whole frame)", "white median"]
    text = (f"# Predictor budget sweep: late masks at 30 and 60 fps\n\nScene `{args.scene}` at "
            f"{args.resolution}, {args.frames} frames (2 white init frames excluded from the columns). "
            f"30 fps: 28 ms exposure and window, 8-bit; 60 fps: 14 ms, 7-bit (DLPC900 105 us planes). "
            f"Readout and mask transfer on a 32-bit 200 MHz bus. Machine: {machine_line()}.\n\n"
            f"{markdown_table(header, rows)}\n")
    print(text)
    save_text(dest / "loop_timing_budget.md", text)
    from poevp_optics.core.runtime import pyplot

    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
    for (fps, mode), pts in curves.items():
        pts = np.array(pts)
        axes[0].plot(pts[:, 0], pts[:, 1], marker="o", label=f"{fps:g} fps, {mode}")
        axes[1].plot(pts[:, 0], pts[:, 2], marker="o", label=f"{fps:g} fps, {mode}")
    axes[0].set_ylabel("saturated plate fraction")
    axes[1].set_ylabel("frames with plate white in 40-90 %")
    for ax in axes:
        ax.set_xlabel("predictor + mask time (ms)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, dest / "loop_timing_budget.png")


if __name__ == "__main__":
    main()
