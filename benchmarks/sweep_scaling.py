"""Sweep scaling on this machine: a 16-point sweep with 1 and 2 Dask workers, in one run.

Rows: bare in-process `run_render` of the 16 points one after the other (the floor: what the
points cost without any sweep machinery), then `sweep` with 1 worker x 2 threads (what a
user gets with --workers 1), 1 worker x 1 thread, and 2 workers x 1 thread (the default on 2
cores). Speed-up = 1-worker wall time / 2-worker wall time; per-point overhead = (sweep wall
- bare wall) / points, both at 2 cores in use. The first point of each worker process pays the
imports and Mitsuba's JIT; that is part of the overhead. Target: >= 1.7x on 2 cores.

    .venv/bin/python -m benchmarks.sweep_scaling [--results]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

from benchmarks.common import add_results_flag, machine_line, markdown_table, output_folder, save_text

SCENE = "scenes/highbeam_plate"
BASE = ["render.resolution=[184,320]", "timing.frames=6", "render.spp=16", "render.subframes=4",
        "outputs.previews=false", "outputs.contact_sheet=false"]
GRID = ["timing.exposure_s=0.005,0.01,0.02,0.03", "mask.target=0.3,0.4,0.5,0.6"]


def bare(points):
    from poevp_optics.core import runtime
    from poevp_optics.apps.run.render_run import run_render
    from poevp_optics.scene.load import load_scene
    from poevp_optics.apps.sweep.sweep import point_overrides

    runtime.set_threads(2)
    keys = [g.split("=")[0] for g in GRID]
    tmp = Path(tempfile.mkdtemp())
    # warm the process (imports, JIT) as a sweep worker is warmed by its first point
    run_render(load_scene(SCENE, BASE + point_overrides(keys, points[0], 0)), tmp / "warm", progress=False)
    t0 = time.perf_counter()
    for i, values in enumerate(points):
        run_render(load_scene(SCENE, BASE + point_overrides(keys, values, 0)), tmp / f"p{i}", progress=False)
    wall = time.perf_counter() - t0
    shutil.rmtree(tmp, ignore_errors=True)
    return wall


def swept(workers, threads):
    from poevp_optics.apps.sweep.sweep import sweep

    tmp = Path(tempfile.mkdtemp())
    t0 = time.perf_counter()
    df = sweep(SCENE, GRID, out=tmp / "sw", workers=workers, threads=threads, base_overrides=BASE,
               progress=False, log=lambda *a: None)
    wall = time.perf_counter() - t0
    assert (df["status"] == "ok").all(), df[df["status"] != "ok"]["error"].tolist()
    shutil.rmtree(tmp, ignore_errors=True)
    ps = df["point_seconds"].sort_values()
    return wall, float(ps.median()), float(ps.iloc[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_results_flag(ap)
    dest = output_folder(ap.parse_args(argv).results)
    import itertools

    from poevp_optics.apps.sweep.sweep import parse_grid

    points = list(itertools.product(*[parse_grid(g)[1] for g in GRID]))
    n = len(points)
    t_bare = bare(points)
    (t_11, m11, f11), (t_12, m12, f12), (t_21, m21, f21) = swept(1, 1), swept(1, 2), swept(2, 1)
    rows = [["bare run_render, in process (warm), 2 threads", t_bare, t_bare / n, "-", "-", "-"],
            ["sweep, 1 worker x 2 threads", t_12, t_12 / n, f"{(t_12 - t_bare) / n:.3f}", m12, f12],
            ["sweep, 1 worker x 1 thread", t_11, t_11 / n, "-", m11, f11],
            ["sweep, 2 workers x 1 thread (default)", t_21, t_21 / n, f"{(t_21 - t_bare) / n:.3f}", m21, f21]]
    header = ["run", "wall s", "s per point", "overhead s per point vs bare", "median point s",
              "slowest point s (first in a fresh worker)"]
    text = (f"# Sweep scaling: {n} points of {SCENE} ({', '.join(BASE[:3])})\n\n"
            f"Machine: {machine_line()}.\n\n{markdown_table(header, rows)}\n\n"
            f"Speed-up, 2 workers vs 1 worker x 2 threads: **{t_12 / t_21:.2f}x**; vs 1 worker x 1 "
            f"thread (process scaling alone): **{t_11 / t_21:.2f}x** (target >= 1.7x). Overhead of the "
            f"sweep machinery per point (Dask, worker start-up and imports, JIT in a fresh process, "
            f"scene load, table rewrite) at 1 worker: {(t_12 - t_bare) / n:.3f} s on "
            f"{t_bare / n:.3f} s of work.\n")
    print(text)
    save_text(dest / "sweep_scaling.md", text)


if __name__ == "__main__":
    main()
