"""`python -m benchmarks`: run every benchmark script in turn (tables + plots in results/)."""

from __future__ import annotations

import subprocess
import sys

SCRIPTS = ["render_error_vs_time", "subframes_error", "camera_throughput", "predictor_latency",
           "loop_comparison", "sweep_scaling", "stage_performance", "work_precision", "objective_psf",
           "night_road_check", "render_cost", "scene_flow"]

if __name__ == "__main__":
    failed = []
    for name in SCRIPTS:
        print(f"== benchmarks.{name}", flush=True)
        rc = subprocess.call([sys.executable, "-m", f"benchmarks.{name}"])
        if rc:
            failed.append(name)
    if failed:
        sys.exit(f"benchmarks failed: {', '.join(failed)}")
