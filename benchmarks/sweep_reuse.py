"""Radiance rendered once per sweep: a 27-point sweep over the mask law's coefficients (paper Eq. 2:
Vs, a, b, 3 values each) rendering every point, then sharing one render, in one run.

Both sweeps run the same points on a fresh 2-worker LocalCluster (the default on 2 cores) into
fresh folders; wall time is the whole `sweep` call (cluster start, scene checks, every point,
the table). The outputs are compared file by file: every image and array byte for byte, and
report.json without its timing fields and the reuse sweep's `render_reuse` entry. Target:
reuse wall time <= 0.6x rendering every point, results bit-identical.

    .venv/bin/python -m benchmarks.sweep_reuse [--results]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import tempfile
import time
from pathlib import Path

from benchmarks.common import add_results_flag, machine_line, markdown_table, output_folder, save_text

SCENE = "scenes/highbeam_plate"
BASE = ["render.resolution=[92,160]", "timing.frames=4", "render.spp=8", "render.subframes=3",
        "mask.law='threshold_exp'", "predictor.name='oracle'", "outputs.previews=false",
        "outputs.contact_sheet=false"]
GRID = ["mask.vs=150.0,200.0,250.0", "mask.a=0.5,0.7,0.9", "mask.b=0.0,0.1,0.2"]
TARGET = 0.6


def _untimed(obj):
    if isinstance(obj, dict):
        return {k: _untimed(v) for k, v in obj.items() if "seconds" not in k and k != "render_reuse"}
    if isinstance(obj, list):
        return [_untimed(v) for v in obj]
    return obj


def fingerprint(points: Path, root: Path | None = None) -> dict:
    """Point folder -> {file: SHA-256 of its bytes} (report.json: of its untimed content, with
    the folder `root`, where given, written as <root>)."""
    out = {}
    for p in sorted(points.iterdir()):
        if not p.is_dir():
            continue
        files = {}
        for f in sorted(p.rglob("*")):
            if not f.is_file() or f.name.startswith(".") or f.name == "report.html":
                continue
            data = f.read_bytes()
            if f.name == "report.json":
                text = json.dumps(_untimed(json.loads(data)), sort_keys=True)
                data = (text.replace(str(root), "<root>") if root is not None else text).encode()
            files[str(f.relative_to(p))] = hashlib.sha256(data).hexdigest()
        out[p.name] = files
    return out


def run(reuse: bool, tmp: Path):
    from poevp_optics.apps.sweep.sweep import sweep

    out = tmp / ("reuse" if reuse else "every")
    t0 = time.perf_counter()
    df = sweep(SCENE, GRID, out=out, workers=2, base_overrides=BASE, progress=False, log=lambda *a: None,
               reuse_render=reuse)
    wall = time.perf_counter() - t0
    assert (df["status"] == "ok").all(), df[df["status"] != "ok"]["error"].tolist()
    renders = int(df["render_key"].nunique()) if reuse else len(df)
    return wall, df, renders, fingerprint(out / "points")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_results_flag(ap)
    dest = output_folder(ap.parse_args(argv).results)
    tmp = Path(tempfile.mkdtemp(prefix="poevp-sweep-reuse-"))
    try:
        t_every, df_every, n_every, fp_every = run(False, tmp)
        t_reuse, df_reuse, n_reuse, fp_reuse = run(True, tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    n = len(df_every)
    same = sum(fp_every[k] == fp_reuse.get(k) for k in fp_every)
    files = sum(len(v) for v in fp_every.values())
    stable = [c for c in df_every.columns if "seconds" not in c]
    table_same = df_every[stable].equals(df_reuse[stable])
    ratio = t_reuse / t_every
    rows = [["every point renders (--no-reuse-render)", n_every, t_every, t_every / n,
             float(df_every["point_seconds"].median())],
            ["one render shared (default)", n_reuse, t_reuse, t_reuse / n, float(df_reuse["point_seconds"].median())]]
    header = ["sweep", "renders", "wall s", "wall s per point", "median point s"]
    text = (f"# Radiance rendered once per sweep: {n} points of {SCENE}\n\n"
            f"{', '.join(BASE[:4])}; grid {' x '.join(GRID)} (the mask law's coefficients: none "
            f"changes the render); 2 Dask workers x 1 thread.\n\n"
            f"Machine: {machine_line()}.\n\n{markdown_table(header, rows)}\n\n"
            f"Wall time with one shared render: **{ratio:.2f}x** rendering every point (target <= "
            f"{TARGET}x). Outputs: {same} of {n} points identical in all {files} files (images and "
            f"arrays byte for byte, report.json without timings); the table's columns other than "
            f"timings {'equal' if table_same else 'DIFFER'}.\n")
    print(text)
    save_text(dest / "sweep_reuse.md", text)
    if same != n or not table_same:
        raise SystemExit("sweep_reuse: the outputs differ between the two sweeps")


if __name__ == "__main__":
    main()
