"""One job runner for every scene command: load the scene (with its overrides), decide the output
folder, run every check short of rendering (apps/run/preflight.py, with the memory estimate), set
the thread counts, then run the job into a staging folder that replaces the output folder only
when it succeeds (core/io.py). The jobs are a registry (`JOBS`): `render`, `chart` and `compare`
here; `poevp sweep` runs the scene jobs (`SWEEP_JOBS`) per grid point.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from poevp_optics.core import runtime
from poevp_optics.core.registry import Registry


@dataclass(frozen=True)
class Job:
    """run(spec, staging folder, progress, **options) -> the job's result (its report or rows);
    suffix: the default output folder is out/<scene><suffix>; sweepable: a grid point can run it."""

    run: Callable
    suffix: str = ""
    sweepable: bool = False


def _render(spec, stage, progress, render_cache=None, **_):
    from poevp_optics.apps.run.render_run import run_render

    return run_render(spec, stage, progress=progress, render_cache=render_cache)


def _chart(spec, stage, progress, **_):
    from poevp_optics.apps.run.chart import run_chart

    return run_chart(spec, stage, progress=progress)


def _compare(spec, stage, progress, *, predictors, modes, **_):
    from poevp_optics.apps.run.compare import compare

    return compare(spec, predictors, modes, stage, progress=progress)


JOBS = Registry("job")
JOBS.register("render", Job(_render, "", sweepable=True), source="apps/run/render_run.py: frames, masks, HDR, report")
JOBS.register("chart", Job(_chart, "-chart", sweepable=True), source="apps/run/chart.py: dynamic range on a test chart")
JOBS.register("compare", Job(_compare, "-compare"), source="apps/run/compare.py: predictors x loop modes on one render")


def _train_sequence(spec, stage, progress, **_):
    from poevp_optics.apps.train.train_render import run_sequence_job

    return run_sequence_job(spec, stage, progress)


JOBS.register("train_sequence", Job(_train_sequence, "-train-sequence"),
              source="apps/train/train_render.py: one predictor training sequence (poevp train-data on Dask)")


def sweep_jobs() -> tuple[str, ...]:
    """The jobs a sweep can run per grid point."""
    return tuple(n for n in JOBS if JOBS[n].sweepable)


def reads(spec) -> tuple:
    """Paths a run reads and must never be given as (or inside) its output folder."""
    return tuple(p for p in (spec.toml_path, spec.toml_path.resolve().parent, spec.xml_path) if p)


def output_folder(spec, job: str, out: str | Path | None) -> Path:
    return Path(out) if out else Path("out") / f"{spec.name}{JOBS[job].suffix}"


def check_size(spec, job: str, plan, folder: Path | None, yes: bool):
    """The run-size estimate (apps/run/run_size.py) within its limits (unless `yes`) and, when the
    output folder is known, within the free space there (always). Returns the RunSize."""
    from poevp_optics.apps.run import run_size
    from poevp_optics.core.io import check_free_space

    size = run_size.estimate(spec, job, mode=getattr(plan, "mode", None))
    run_size.check(size, where=str(spec.origin or spec.toml_path), yes=yes, what=f"`poevp {job}`")
    if folder is not None:
        check_free_space(folder, size.disk_bytes, f"`poevp {job}` of {spec.name}")
    return size


def run_job(job: str, scene, overrides: list[str], *, out=None, threads: int | None = None,
            progress: bool = True, check: dict | None = None, yes: bool = False, **options):
    """Run the scene job `job` (module docstring); returns (spec, output folder, result).
    check: extra keywords of preflight.check_run (e.g. the predictors compare will run).
    yes: run even above the run-size limits (apps/run/run_size.py)."""
    from poevp_optics.apps.run.preflight import check_run
    from poevp_optics.core.io import check_output, staged_dir
    from poevp_optics.scene.load import load_scene

    spec = load_scene(scene, overrides)
    folder = output_folder(spec, job, out)
    check_output(folder, job, protect=reads(spec))
    pf = check_run(spec, job, **(check or {}))
    check_size(spec, job, pf.plan, folder, yes)
    runtime.set_threads(threads)
    with staged_dir(folder, kind=job, protect=reads(spec)) as stage:
        result = JOBS[job].run(spec, stage, progress, **options)
    return spec, folder, result


def run_in_folder(kind: str, out: Path, threads: int | None, fn: Callable[[Path], object]):
    """A job that is not a scene's (evaluate): the same folder policy and thread counts."""
    from poevp_optics.core.io import check_output, staged_dir

    check_output(out, kind)
    runtime.set_threads(threads)
    with staged_dir(out, kind=kind) as stage:
        return fn(stage)
