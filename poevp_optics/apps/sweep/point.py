"""One sweep point on a Dask worker (apps/sweep/sweep.py's docstring): what the task carries
(`PointTask`), how the worker runs it inside a temporary folder and what comes back
(`run_point`), and the report's scalar metrics as table columns (`flatten_report`)."""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

from poevp_optics.apps.run.runner import JOBS
from poevp_optics.apps.sweep.bundle import (InputMismatch, InputPlan, InputRef, check_same_inputs, map_paths,
                                            materialize, pack_folder, point_workdir)
from poevp_optics.apps.sweep.cluster import software_versions, version_mismatch
from poevp_optics.apps.sweep.reuse import point_render_cache, render_result
from poevp_optics.core.io import write_json
from poevp_optics.scene.load import load_scene


def flatten_report(report: dict) -> dict:
    """Scalar metrics of a run's report as dotted columns (metrics, stages, DR, limits)."""
    out = {}

    def walk(prefix, obj):
        if isinstance(obj, dict):
            for k, v in obj.items():
                if not str(k).startswith("_"):
                    walk(f"{prefix}.{k}", v)
        elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
            out[prefix] = float(obj)

    for sec in ("metrics", "stages", "dynamic_range_db", "limits", "render"):
        if sec in report:
            walk(sec, report[sec])
    if "settle" in report:
        out["settle.frames"] = float(report["settle"]["frames"])
    out["total_seconds"] = float(report.get("total_seconds", math.nan))
    return out


@dataclass(frozen=True)
class PointTask:
    """What a worker needs for one point (pickled with the task; small).

    overrides: the point's `KEY=VALUE` overrides (base, grid values, seeds). job: a sweepable
    job of apps/run/runner.py's JOBS. threads: DrJit/torch/OpenCV threads. plan, refs: where its inputs are and their
    hashes (bundle.py). versions: the client's software (cluster.PACKAGES); empty on a
    LocalCluster, whose workers run this interpreter's. render_group: the point's render group
    (reuse.py; "" renders without storing), render_read: folders of stored renders this worker
    reads itself, label: the point's folder name (who rendered a stored render), render_store:
    the sweep's store of renders, where a worker that shares the client's file system records
    its render itself ("": recorded in the worker's folder and streamed to the client)."""

    overrides: tuple[str, ...]
    job: str
    threads: int
    plan: InputPlan
    refs: tuple[InputRef, ...]
    versions: dict = field(default_factory=dict)
    render_group: str = ""
    render_read: tuple[str, ...] = ()
    label: str = ""
    render_store: str = ""


def worker_name() -> str:
    try:
        from distributed import get_worker

        return f"worker {get_worker().address}"
    except (ImportError, ValueError):
        return "this process"


def one_line(e: BaseException) -> str:
    msg = str(e).strip().splitlines()[0] if str(e).strip() else ""
    return f"{type(e).__name__}: {msg}"


def run_point(task: PointTask, bundle: bytes | None = None, renders: list = ()) -> dict:
    """Run one point in this (worker) process, inside a temporary folder removed afterwards;
    never raises. Returns {"row": columns, "archive": zip of the point's folder} (no archive
    when the point failed) with, for a point of a render group, "render" (the render it used)
    and "render_archive" (the zip of a render it made), or {"refused": one line} when this
    worker cannot run the sweep (other software, other files): the client then stops the sweep.
    renders: unused (stored renders reach a worker that cannot read the client's paths through
    its inbox, reuse.py); kept for the task's signature."""
    from poevp_optics.core import runtime

    from poevp_optics.apps.run.preflight import check_run

    t0 = time.perf_counter()
    path_map = ()
    try:
        problem = version_mismatch(task.versions, software_versions()) if task.versions else None
        if problem:
            return {"refused": f"{worker_name()}: {problem}; install the same software on every worker"}
        runtime.set_threads(task.threads)
        with point_workdir() as work:
            try:
                inputs = materialize(task.plan, list(task.refs), bundle, work)
                path_map = inputs.path_map
                spec = load_scene(inputs.scene, [*task.overrides, *inputs.overrides])
                check_same_inputs(list(task.refs), spec, path_map)
            except InputMismatch as e:
                return {"refused": f"{worker_name()}: {map_paths(str(e), path_map)}"}
            check_run(spec, task.job, memory=False)
            folder = work / "out"
            folder.mkdir()
            cache = point_render_cache(task, renders, work)
            report = JOBS[task.job].run(spec, folder, False, **({"render_cache": cache} if cache else {}))
            report_paths_to_client(folder / "report.json", path_map)
            return {"row": {"status": "ok", "error": "", **flatten_report(report),
                            "point_seconds": time.perf_counter() - t0},
                    "archive": pack_folder(folder), **render_result(cache, bool(task.render_store))}
    except Exception as e:  # noqa: BLE001 - a failed point is data, not a crash
        return {"row": {"status": "failed", "error": map_paths(one_line(e), path_map),
                        "point_seconds": time.perf_counter() - t0}}


def report_paths_to_client(path: Path, path_map) -> None:
    """Name the client's files in report.json, not the worker's temporary copies."""
    if not path_map or not path.is_file():
        return
    report = json.loads(path.read_text())
    mapped = map_paths(report, path_map)
    if mapped != report:
        write_json(path, mapped)
