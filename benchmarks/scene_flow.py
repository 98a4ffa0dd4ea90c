"""Where a run's scene value goes: stops, files, climbs back up, and the functions below
apps/ that receive the whole scene object, for this checkout and (``--before REV``) an older one,
side by side in one run. Writes scene_flow.md into out/benchmarks/ (benchmarks/results/ with --results).

Definitions (tests/scene_flow.py): a stop is a call of a poevp_optics function given the scene or
a part resolved from it (distinct functions, in first-visit order); a climb is a stop in a package
above the previous stop's in the import table. An older checkout is traced with this checkout's
tracer and runs (a temporary ``git worktree``), its own package on the path.

    .venv/bin/python -m benchmarks.scene_flow --before b481423 [--results]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks.common import add_results_flag, machine_line, markdown_table, output_folder, save_text

ROOT = Path(__file__).resolve().parent.parent
TRACER = ROOT / "tests" / "scene_flow.py"
HELPERS = ROOT / "tests" / "helpers.py"          # the import table the tracer counts climbs by

_CHILD = """
import importlib.util, json, sys, tempfile
from pathlib import Path
import tests                                       # the traced tree's; this checkout's table and tracer:
h = importlib.util.spec_from_file_location("tests.helpers", sys.argv[3])
sys.modules["tests.helpers"] = importlib.util.module_from_spec(h); h.loader.exec_module(sys.modules["tests.helpers"])
spec = importlib.util.spec_from_file_location("scene_flow", sys.argv[1])
sf = importlib.util.module_from_spec(spec); sys.modules["scene_flow"] = sf; spec.loader.exec_module(sf)
out = {}
for name in sf.RUNS:
    f = sf.follow_run(name, Path(tempfile.mkdtemp()) / "out", Path(sys.argv[2]))
    out[name] = {"stops": len(f.path), "files": len(f.files), "climbs": f.climbs,
                 "scene_object_below_apps": sorted(set(f.whole_scene_below_apps))}
print("RESULT " + json.dumps(out))
"""


def trace(tree: Path) -> dict:
    """Follow every run with `tree`'s poevp_optics and scenes."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    r = subprocess.run([sys.executable, "-c", _CHILD, str(TRACER), str(tree / "scenes"), str(HELPERS)], env=env, cwd=tree,
                       capture_output=True, text=True, timeout=1800)
    line = [x for x in r.stdout.splitlines() if x.startswith("RESULT ")]
    if r.returncode or not line:
        raise SystemExit(f"tracing {tree} failed:\n{r.stderr[-3000:]}")
    return json.loads(line[0][len("RESULT "):])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", help="an older commit to trace side by side")
    add_results_flag(ap)
    args = ap.parse_args()
    dest = output_folder(args.results)
    trees = {"this checkout": ROOT}
    tmp = None
    if args.before:
        tmp = Path(tempfile.mkdtemp()) / "before"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "-q", "--detach", str(tmp), args.before],
                       check=True)
        trees = {f"{args.before}": tmp, **trees}
    try:
        results = {label: trace(tree) for label, tree in trees.items()}
    finally:
        if tmp is not None:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tmp)], check=False)
    rows = []
    for label, res in results.items():
        for run, r in res.items():
            rows.append([label, run, r["stops"], r["files"], r["climbs"], len(r["scene_object_below_apps"]),
                         ", ".join(r["scene_object_below_apps"]) or "-"])
    table = markdown_table(["checkout", "run", "stops", "files", "climbs back up", "functions below apps/ given "
                            "the SceneSpec", "which"], rows)
    text = (f"# Where the scene value goes\n\n{machine_line()}\n\n{table}\n\nStops: distinct poevp_optics "
            "functions given the scene or a part resolved from it (SceneSpec, ResolvedScene, "
            "RenderScene, CameraParams, LoopParams), first-visit order. Climbs: a stop in a package that may "
            "import the previous stop's. Runs: tests/scene_flow.py RUNS.\n")
    print(text)
    save_text(dest / "scene_flow.md", text)


if __name__ == "__main__":
    main()
