"""One scene rendered on two Mitsuba backends (a CUDA GPU's `cuda_ad_*` and the CPU's `llvm_ad_*`):
where the run's time goes on each, and how far the two radiance images of each frame differ.

    .venv/bin/python -m benchmarks.render_backends RUN [RUN ...] [--results]

Each RUN is a `poevp render` output folder (its report.json; its radiance/ EXRs where present), on
whichever machine made it: the CUDA runs need a GPU, so they are made there and their folders
brought back. Table 1 lists each run's variant, resolution, the stage seconds from its report
(render, of it the Mitsuba calls; objective; writing) and the total wall seconds, with the plate's
Monte Carlo error. Table 2 compares, frame by frame, every two runs of the same scene, resolution
and seed that both wrote radiance: the relative difference of the frame's summed radiance, the
median and 99th percentile of the per-pixel relative difference, the fraction of pixels that differ
by more than 1e-3, and the median per-pixel difference in units of that pixel's own MC standard
error (the `mc_stderr` channel). The same seed draws the same samples on both backends, so the
difference is floating-point arithmetic and the ray tracers' intersection precision (OptiX against
Embree), not Monte Carlo noise.
"""

from __future__ import annotations

import argparse
import json
from itertools import combinations
from pathlib import Path

import numpy as np

from benchmarks.common import add_results_flag, markdown_table, output_folder, save_text


def run_summary(folder: Path) -> dict:
    """The facts of one run folder that the tables need (report.json)."""
    r = json.loads((folder / "report.json").read_text())
    st = r["stages"]
    ren = st["render"]
    return {"folder": folder, "scene": r["scene"], "seed": r["seed"], "resolution": tuple(r["resolution"]),
            "frames": r["frames"], "variant": ren["variant"], "render_s": ren["seconds"],
            "mitsuba_s": ren.get("mitsuba_seconds", float("nan")), "calls": ren.get("calls", 0),
            "objective_s": st.get("objective", {}).get("seconds", float("nan")),
            "io_s": r.get("io_seconds", float("nan")), "total_s": r["total_seconds"],
            "plate_mc": ren.get("rel_error_roi", float("nan"))}


def frame_differences(a: Path, b: Path) -> dict:
    """Per-frame radiance differences of run a against run b (both radiance/frame_*.exr)."""
    from poevp_optics.core.io import read_exr

    sums, med, p99, frac, in_sigma = [], [], [], [], []
    for fa in sorted((a / "radiance").glob("frame_*.exr")):
        ya, _ = read_exr(fa)
        yb, _ = read_exr(b / "radiance" / fa.name)
        x, y = ya["Y"].astype(np.float64), yb["Y"].astype(np.float64)
        sigma = np.maximum(yb["mc_stderr"].astype(np.float64), ya["mc_stderr"].astype(np.float64))
        d = np.abs(x - y)
        rel = d / np.maximum(np.abs(y), np.finfo(np.float64).tiny)
        sums.append(abs(x.sum() / y.sum() - 1.0))
        med.append(np.median(rel))
        p99.append(np.percentile(rel, 99))
        frac.append(float((rel > 1e-3).mean()))
        noisy = sigma > 0
        in_sigma.append(np.median(d[noisy] / sigma[noisy]) if noisy.any() else float("nan"))
    return {"frames": len(sums), "sum_max": max(sums), "median_max": max(med), "p99_max": max(p99),
            "frac_max": max(frac), "sigma_median_max": max(in_sigma)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="poevp render output folders")
    ap.add_argument("--note", default="", help="what the table cannot say (the machines, their load, the kernel cache)")
    add_results_flag(ap)
    args = ap.parse_args(argv)
    runs = [run_summary(f) for f in args.runs]
    rows1 = [[r["folder"].name, r["variant"], f"{r['resolution'][0]}x{r['resolution'][1]}", r["frames"], r["calls"],
              r["render_s"], r["mitsuba_s"], r["mitsuba_s"] / max(r["calls"], 1), r["objective_s"], r["io_s"],
              r["total_s"], f"{r['plate_mc']:.2%}"] for r in runs]
    rows2 = []
    for a, b in combinations(runs, 2):
        same = all(a[k] == b[k] for k in ("scene", "seed", "resolution", "frames"))
        if same and a["variant"] != b["variant"] and all((r["folder"] / "radiance").is_dir() for r in (a, b)):
            d = frame_differences(a["folder"], b["folder"])
            rows2.append([f"{a['folder'].name} / {b['folder'].name}", f"{a['resolution'][0]}x{a['resolution'][1]}",
                          d["frames"], d["sum_max"], d["median_max"], d["p99_max"], f"{d['frac_max']:.1%}",
                          d["sigma_median_max"]])
    h1 = ["run", "variant", "mirrors", "frames", "Mitsuba calls", "render s", "of it Mitsuba s",
          "Mitsuba s per call", "objective s", "writing s", "total wall s", "plate MC error"]
    h2 = ["runs", "mirrors", "frames", "frame sum, rel. diff. (worst frame)",
          "pixel rel. diff., median (worst frame)", "pixel rel. diff., p99 (worst frame)",
          "pixels > 1e-3 apart (worst frame)", "median |diff| / MC std. error (worst frame)"]
    text = ("# Rendering on a GPU and on the CPU\n\nThe same scene, seed and frames rendered with Mitsuba's "
            "CUDA variant on a GPU and its LLVM variant on the CPU (`poevp render` picks cuda > llvm > "
            "scalar by itself). Runs: " + ", ".join(f"`{f}`" for f in args.runs) + ".\n\n"
            + (args.note + "\n\n" if args.note else "")
            + markdown_table(h1, rows1) + "\n")
    if rows2:
        text += ("\nThe radiance of each frame, one backend against the other (same samples, so the "
                 "differences are arithmetic and intersection precision, not noise):\n\n"
                 + markdown_table(h2, rows2) + "\n")
    print(text)
    save_text(output_folder(args.results) / "render_backends.md", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
