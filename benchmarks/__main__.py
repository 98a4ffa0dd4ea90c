"""`.venv/bin/python -m benchmarks [--results]`: run every benchmark script in turn (tables + plots in
out/benchmarks/, or with --results in benchmarks/results/, as `make bench` does)."""

from __future__ import annotations

import argparse
import subprocess
import sys

SCRIPTS = ["render_error_vs_time", "subframes_error", "camera_throughput", "predictor_latency",
           "loop_comparison", "sweep_scaling", "stage_performance", "work_precision", "objective_psf",
           "night_road_check", "render_cost", "scene_flow", "sweep_reuse", "search_vs_grid", "recognition",
           "predictor_traffic", "predictor_scenes", "scene_library"]

if __name__ == "__main__":
    ap = argparse.ArgumentParser(prog="python -m benchmarks", description="run every benchmark script in turn")
    ap.add_argument("--results", action="store_true", help="write into benchmarks/results/ (the committed results)")
    extra = ["--results"] if ap.parse_args().results else []
    failed = []
    for name in SCRIPTS:
        print(f"== benchmarks.{name}", flush=True)
        rc = subprocess.call([sys.executable, "-m", f"benchmarks.{name}", *extra])
        if rc:
            failed.append(name)
    if failed:
        sys.exit(f"benchmarks failed: {', '.join(failed)}")
