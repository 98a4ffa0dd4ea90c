"""How much of a shared render the sweep's client holds in memory: peak RSS of the client process
(VmHWM) for a 2-point sweep that shares one render, with the render moved between worker and
client as one zip in memory (the code at `--before`, a git revision) and by file (the code at
`--after`: by path on a shared file system, in chunks of
apps/sweep/reuse.CHUNK_BYTES otherwise). Both are taken from git (`git archive`), so neither
sees uncommitted edits.

Two clusters: an embedded LocalCluster (shared file system: the worker records the render in the
sweep's folder) and an external `dask scheduler` with one `dask worker` in its own folder, no
--shared-fs (a scene bundle: the render is pulled from the worker in chunks, and sent to it in
chunks for the second point). Each sweep runs in a fresh process; its outputs are compared
file by file with the other revision's (images and arrays byte for byte, report.json without
timings). Not a timed test: a table.

    .venv/bin/python -m benchmarks.render_transport [--before REV] [--after REV] [--results]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import add_results_flag, machine_line, markdown_table, output_folder, save_text
from benchmarks.sweep_reuse import fingerprint   # point folder -> file hashes, <root> for the checkout
from poevp_optics.apps.sweep.reuse import CHUNK_BYTES

ROOT = Path(__file__).resolve().parents[1]
SCENE = "scenes/highbeam_plate"
#: 360x640, 3 frames of 3 radiance nodes: a stored render of ~50 MB
BASE = ["render.resolution=[360,640]", "timing.frames=3", "render.spp=2", "render.subframes=3",
        "mask.law='threshold_exp'", "predictor.name='oracle'", "outputs.previews=false",
        "outputs.contact_sheet=false", "outputs.radiance_exr=false"]
GRID = ["mask.a=0.5,0.9"]
#: --resolution H W: another render size (the --set of BASE otherwise)
RESOLUTION: list[str] = []
#: the commit that moved renders by file (AFTER) and its parent (BEFORE: zip bytes in memory); the
#: two differ in nothing else, so the outputs must be identical
BEFORE, AFTER = "281f3df", "a23d696"

CLIENT = """
import json, os, sys
import poevp_optics
from poevp_optics.cli import main
assert poevp_optics.__file__.startswith(os.getcwd()), poevp_optics.__file__
rc = main(sys.argv[1:])
hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0].split()[1]
print(json.dumps({'rc': rc, 'vmhwm_kib': int(hwm)}))
"""


def checkout(rev: str, dest: Path) -> Path:
    """The package as it was at `rev` (git archive), for PYTHONPATH."""
    dest.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "poevp_optics"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    for data in ("assets", "scenes"):              # the package finds them beside itself (core/paths.py)
        (dest / data).symlink_to(ROOT / data)
    return dest


def client_run(pythonpath: Path, out: Path, extra: list[str]) -> dict:
    args = ["sweep", SCENE, *(a for o in BASE for a in ("--set", o)), *RESOLUTION,
            *(a for g in GRID for a in ("--grid", g)),
            "--out", str(out), "--quiet", *extra]
    env = {**os.environ, "PYTHONPATH": str(pythonpath)}
    t0 = time.perf_counter()
    # run from the checkout (its scenes/ and assets/ link to this repository's): `-c` puts the
    # working folder first on sys.path, so the checkout's package is the one imported
    p = subprocess.run([sys.executable, "-c", CLIENT, *args], cwd=pythonpath, env=env, capture_output=True,
                       text=True)
    wall = time.perf_counter() - t0
    last = p.stdout.strip().splitlines()[-1] if p.stdout.strip() else "{}"
    res = json.loads(last) if last.startswith("{") else {}
    if res.get("rc") != 0:
        raise SystemExit(f"render_transport: sweep failed ({p.returncode}): {p.stderr[-2000:]}")
    return {**res, "wall_s": wall}


class External:
    """A `dask scheduler` and one `dask worker` in their own folders, on this machine."""

    def __init__(self, tmp: Path, pythonpath: Path):
        self.tmp, self.procs = tmp, []
        tmp.mkdir(parents=True)
        self.sf = tmp / "scheduler.json"
        env = {**os.environ, "PYTHONPATH": str(pythonpath), "TMPDIR": str(tmp)}
        dask = str(Path(sys.executable).parent / "dask")
        self.procs.append(subprocess.Popen([dask, "scheduler", "--scheduler-file", str(self.sf), "--no-dashboard",
                                            "--host", "127.0.0.1"], cwd=tmp, env=env,
                                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        while not self.sf.is_file():
            time.sleep(0.2)
        work = tmp / "worker"
        work.mkdir()
        self.procs.append(subprocess.Popen([dask, "worker", "--scheduler-file", str(self.sf), "--nworkers", "1",
                                            "--nthreads", "1", "--no-dashboard", "--local-directory", str(work)],
                                           cwd=work, env=env, stdout=subprocess.DEVNULL,
                                           stderr=subprocess.DEVNULL))

    def close(self):
        for p in reversed(self.procs):
            p.terminate()
            p.wait(timeout=60)


def measure(label: str, pythonpath: Path, tmp: Path) -> dict:
    out = {}
    local = tmp / f"{label}-local"
    out["local"] = {**client_run(pythonpath, local, ["--workers", "1"]),
                    "points": fingerprint(local / "points", pythonpath)}
    ext = External(tmp / f"{label}-cluster", pythonpath)
    try:
        remote = tmp / f"{label}-external"
        out["external"] = {**client_run(pythonpath, remote, ["--scheduler-file", str(ext.sf)]),
                           "points": fingerprint(remote / "points", pythonpath)}
    finally:
        ext.close()
    sizes = [sum(f.stat().st_size for f in d.iterdir()) for d in (local / "renders").iterdir() if d.is_dir()]
    out["render_bytes"] = max(sizes) if sizes else 0
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", default=BEFORE, help=f"git revision whose sweeps moved zip bytes (default {BEFORE})")
    ap.add_argument("--resolution", nargs=2, type=int, metavar=("H", "W"),
                    help="render resolution instead of 360 640 (the stored render grows with H x W)")
    ap.add_argument("--after", default=AFTER, help=f"git revision whose sweeps move renders by file (default {AFTER})")
    add_results_flag(ap)
    args = ap.parse_args(argv)
    if args.resolution:
        RESOLUTION[:] = ["--set", f"render.resolution=[{args.resolution[0]},{args.resolution[1]}]"]
    dest = output_folder(args.results)
    tmp = Path(tempfile.mkdtemp(prefix="poevp-render-transport-"))
    try:
        old = measure("before", checkout(args.before, tmp / "old"), tmp)
        new = measure("after", checkout(args.after, tmp / "new"), tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    mb = 1 << 20
    rows, same = [], True
    for where, what in (("local", "LocalCluster, 1 worker (shared file system)"),
                        ("external", "dask scheduler + 1 worker, own folders (scene bundle)")):
        b, a = old[where], new[where]
        same &= b["points"] == a["points"]
        rows.append([what, b["vmhwm_kib"] * 1024 / mb, a["vmhwm_kib"] * 1024 / mb,
                     (b["vmhwm_kib"] - a["vmhwm_kib"]) * 1024 / mb, b["wall_s"], a["wall_s"],
                     "yes" if b["points"] == a["points"] else "NO"])
    header = ["cluster", "client peak RSS, render in memory (MiB)", "render by file (MiB)", "saved (MiB)",
              "wall in memory (s)", "wall by file (s)", "outputs identical"]
    text = (f"# A shared render between Dask worker and client: in memory vs by file\n\n"
            f"`poevp sweep {SCENE}` with {', '.join([*RESOLUTION[1:], *BASE[1:4]] if RESOLUTION else BASE[:4])}, "
            f"grid {' '.join(GRID)}: 2 points, one render "
            f"of {new['render_bytes'] / mb:.0f} MiB on disk (recorded by the first point, replayed by the "
            f"second). In memory: the render as one zip (worker -> client in the "
            f"point's result; client -> worker by Dask scatter). By file: by path on a shared "
            f"file system, in chunks of {CHUNK_BYTES // mb} MiB otherwise. Client peak RSS is its VmHWM (the client "
            f"process alone; the workers are other processes).\n\nMachine: {machine_line()}.\n\n"
            f"{markdown_table(header, rows)}\n\nOutputs of every point: "
            f"{'identical' if same else 'DIFFERENT'} either way (images and arrays byte for byte, "
            f"report.json without timings).\n")
    print(text)
    name = "render_transport" + (f"_{args.resolution[0]}x{args.resolution[1]}" if args.resolution else "")
    save_text(dest / f"{name}.md", text)
    if not same:
        raise SystemExit("render_transport: the outputs differ")


if __name__ == "__main__":
    main()
