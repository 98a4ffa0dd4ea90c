"""Objective stage: the Double Gauss's PSF over the field, and what the stage costs.

* PSF peak and encircled energy vs field of the Double Gauss (optiland sample) at the IMX253
  band (3 equal-signal wavelengths), on 7.56 um mirrors, along the image's diagonal and x axis:
  (a) the stage's defaults, 25 mm f/6.14 (the 720x1280 mirror field reaches 12.5 deg);
  (b) the lens at its design scale, 100 mm f/5, field to 13.9 deg (FACTS.md: 27x peak drop).
  Peak = the largest pixel's share of the energy; EE(r) = energy within r px of the node (pixel
  areas inside the circle), from the unit-sum kernels.
* Relative illumination of the prescription (ray-traced) against cos^4 at the field's corner.
* Time to build the PSF grid: cold in a fresh process (optiland import + numba JIT included),
  cold with optiland warm, and loaded from the cache; time of `apply` at 368x640 and 720x1280
  (PSF only; PSF + cos^4 + 3 % glare).

Writes objective_psf.md and objective_psf_grid.png into out/benchmarks/ (benchmarks/results/ with
--results).

    .venv/bin/python -m benchmarks.objective_psf [--results]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import (add_results_flag, machine_line, markdown_table, output_folder, save_figure,
                               save_text, timed)
from poevp_optics.camera import objective as ob

DEFAULT = ob.ObjectiveParams(psf="prescription")
DESIGN = ob.ObjectiveParams(psf="prescription", focal_length_m=0.1, f_number=5.0)


def design_shape():
    r = 0.1 * math.tan(math.radians(13.9)) / DESIGN.pixel_pitch_m
    n = 2 * int(r / math.sqrt(2)) + 1
    return (n, n)


def encircled(kernel, radius_px, o=16):
    r = kernel.shape[0] // 2
    s = (np.arange(o) + 0.5) / o - 0.5
    c = (np.arange(-r, r + 1)[:, None] + s[None, :]).ravel()
    inside = ((c[:, None] ** 2 + c[None, :] ** 2) <= radius_px ** 2).reshape(2 * r + 1, o, 2 * r + 1, o).mean(axis=(1, 3))
    return float(np.sum(kernel * inside))


def field_rows(params, shape, grid):
    h, w = shape
    cy, cx = (h - 1) / 2, (w - 1) / 2
    ny, nx = grid.kernels.shape[:2]
    rows = []
    for label, nodes in (("diagonal", [(ny // 2 + k, nx // 2 + k) for k in range(ny // 2 + 1)]),
                         ("x axis", [(ny // 2, nx // 2 + k) for k in range(1, nx // 2 + 1)])):
        for j, i in nodes:
            r_m = math.hypot(grid.node_y_px[j] - cy, grid.node_x_px[i] - cx) * params.pixel_pitch_m
            k = grid.kernels[j, i]
            rows.append([label, f"{math.degrees(math.atan(r_m / params.focal_length_m)):.2f}", float(k.max()),
                         encircled(k, 0.5), encircled(k, 1.0), encircled(k, 2.0), encircled(k, 5.0)])
    return rows


def cold_build_seconds(cache_dir: str) -> float:
    code = ("import time; t = time.perf_counter(); from poevp_optics.camera import objective as ob; "
            "ob.psf_grid(ob.ObjectiveParams(psf='prescription'), (368, 640), cache_dir=%r); "
            "print(time.perf_counter() - t)" % cache_dir)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def plot(grids, dest: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(5, 10, figsize=(16, 8.6))
    for col0, (title, grid) in zip((0, 5), grids):
        r = grid.radius_px
        c = 8
        vmax = grid.kernels.max()
        for j in range(5):
            for i in range(5):
                ax = axes[j, col0 + i]
                k = grid.kernels[j, i, r - c:r + c + 1, r - c:r + c + 1]
                ax.imshow(np.log10(np.maximum(k, vmax * 1e-6)), vmin=math.log10(vmax) - 6, vmax=math.log10(vmax),
                          cmap="magma", interpolation="nearest")
                ax.set_xticks([])
                ax.set_yticks([])
                ax.set_title(f"peak {k.max():.3f}", fontsize=7)
        axes[0, col0 + 2].set_title(f"{title}\npeak {grid.kernels[0, 2].max():.3f}", fontsize=8)
    fig.suptitle("Double Gauss PSF grid (5 x 5 nodes over the image, 17 x 17 mirrors each, log10, 6 decades)")
    return save_figure(fig, dest / "objective_psf_grid.png")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_results_flag(ap)
    dest = output_folder(ap.parse_args(argv).results)
    lines = ["# Objective stage: Double Gauss PSF over the field, and cost", "", machine_line(), "",
             "IMX253 band at " + ", ".join(f"{w:.0f}" for w in ob.band(DEFAULT)[0]) +
             " nm (equal signal), 7.56 um mirrors, pupil_rays 256, support_energy 0.999.", ""]
    with tempfile.TemporaryDirectory() as tmp:
        t_cold = cold_build_seconds(tmp)
        t0 = time.perf_counter()
        g_cached = ob.psf_grid(DEFAULT, (368, 640), cache_dir=tmp)
        t_cached = time.perf_counter() - t0
        t0 = time.perf_counter()
        g720 = ob.psf_grid(DEFAULT, (720, 1280), cache_dir=tmp)
        t_warm = time.perf_counter() - t0
        gd = ob.psf_grid(DESIGN, design_shape(), cache_dir=tmp)
        for title, p, shape, g in (("(a) 25 mm f/6.14, 720x1280 mirrors", DEFAULT, (720, 1280), g720),
                                   ("(b) design scale 100 mm f/5, field to 13.9 deg", DESIGN, design_shape(), gd)):
            lines += [f"## {title}", "",
                      f"kernel {2 * g.radius_px + 1} px, truncation {g.truncation_error:.2e}" +
                      (f" ({g.note})" if g.note else ""), "",
                      markdown_table(["direction", "field deg", "peak", "EE r<=0.5 px", "EE 1 px", "EE 2 px",
                                      "EE 5 px"], field_rows(p, shape, g)), ""]
        peaks = gd.kernels.max(axis=(2, 3))
        lines += [f"Design scale: on-axis / corner pixel peak = {peaks[2, 2] / peaks[0, 0]:.1f} "
                  "(optiland's own 0.55 um peaks: 27x, FACTS.md).", ""]
        # relative illumination
        rows = []
        for title, p, shape in (("25 mm, 720x1280", DEFAULT, (720, 1280)), ("100 mm, design field", DESIGN, design_shape())):
            pv = dataclasses.replace(p, vignetting="prescription")
            th = float(ob.field_angle_rad(p, shape).max())
            t_deg, ri = ob.ri_profile(pv, th)
            rows.append([title, f"{math.degrees(th):.2f}", float(ri[-1]), float(math.cos(th) ** 4),
                         float(ri[-1] / math.cos(th) ** 4)])
        lines += ["## Relative illumination at the corner (ray-traced: distortion x pupil x cos theta)", "",
                  markdown_table(["lens", "corner deg", "prescription", "cos^4", "ratio"], rows), ""]
        # time
        trows = [["build grid 368x640, fresh process (import + JIT + 9 radii x 3 wavelengths)", t_cold],
                 ["build grid 720x1280, optiland warm", t_warm],
                 ["load grid from cache", t_cached]]
        full = ob.ObjectiveParams(psf="prescription", vignetting="cos4", glare_fraction=0.03)
        for shape, grid in (((368, 640), g_cached), ((720, 1280), g720)):
            img = np.random.default_rng(0).random(shape) * 1e3
            ri = ob.relative_illumination(full, shape)
            glare = ob.glare_kernel(full, shape)
            t1, _ = timed(lambda: ob.apply(img, DEFAULT, grid=grid), 3)
            t2, _ = timed(lambda: ob.apply(img, full, grid=grid, ri=ri, glare=glare), 3)
            trows += [[f"apply {shape[0]}x{shape[1]}: PSF (25 nodes, {2 * grid.radius_px + 1} px kernels)", t1],
                      [f"apply {shape[0]}x{shape[1]}: PSF + cos^4 + 3 % glare ({2 * glare.radius_px + 1} px halo)", t2]]
        lines += ["## Time (s)", "", markdown_table(["what", "seconds"], trows), ""]
        png = plot([("(a) 25 mm f/6.14, 720x1280", g720), ("(b) 100 mm f/5, 13.9 deg", gd)], dest)
    lines += [f"Plot: `{png.name}`.", ""]
    text = "\n".join(lines)
    save_text(dest / "objective_psf.md", text)
    print(text)


if __name__ == "__main__":
    main()
