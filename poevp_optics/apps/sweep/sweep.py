"""`poevp sweep`: a grid of scene variations run in parallel on Dask, resumable, one tidy table.

Grid syntax (`--grid KEY=VALUES`, KEY any dotted scene key):
  `v1,v2,...`            values in TOML syntax (`[320,320]`, `'flow'`, `0.01`)
  `start:stop:num`       `num` equally spaced values, both ends included (numpy.linspace)
  `log:start:stop:num`   `num` log-spaced values (numpy.geomspace)

Every point is first validated without running (`load_scene(..., cross_checks=False)`): an
unknown key or a bad value stops the sweep with the scene error and nothing is written; so does
a sweep whose largest point, times the workers running at once, does not fit in memory
(memory.py). A point whose combination is impossible (timing beyond the frame period, any
check of preflight.py) or that raises while running is recorded as `failed` with its message;
the others go on, and `poevp sweep` exits 1 when any point failed.

A sweep is its scene file (however named: `scenes/x` and `scenes/x/scene.toml` are one), job,
seeds, grid (keys in any order: the grid is sorted by key) and the effective scene after the
base overrides. Its record `sweep.json` also holds the SHA-256 of every file the points read
(apps/sweep/bundle.py: TOML, XML and the files it names, spectrum tables, lamp and sheeting files,
PSF image, predictor weights, a chart's reference camera, a frame source's files). A rerun of
the same sweep resumes; a rerun whose record differs, or whose files changed since, is refused
with what differs, so old and new points never mix in one table. Point folders are named by a
hash of the point's effective scene table, not of the override text.

Execution: Dask distributed (https://distributed.dask.org): an embedded `LocalCluster` of
worker processes, one thread each, with DrJit/torch/OpenCV threads = cores // workers, or an
existing cluster (`--scheduler tls://HOST:PORT` or `--scheduler-file PATH`, cluster.py). The
client resolves every path before submitting; a point carries its inputs (bundle.py): on a
cluster a scene bundle (the files the points read, content-hashed, scattered once to the
workers and unpacked into each point's temporary folder), or with `--shared-fs` (and on a
LocalCluster) the client's own paths, which each worker verifies byte for byte. Workers must
run the client's poevp_optics, Mitsuba, DrJit and torch (on a cluster: checked at start and by
each point); a worker that differs, in software or in the files it sees, stops the sweep with
one line. A worker writes only into its temporary folder, removed when the point ends; the point's
folder comes back as a zip that the client writes to `points/<key>-s<seed>/` (staged, so a
killed client leaves nothing half-written), and the table `results.parquet` +
`results.csv` is rewritten atomically after every finished point. A point whose worker died
(killed process, lost machine) runs again on another worker up to `retries` times before it
becomes a `failed` row. A rerun of the same command skips the finished points (ok or failed),
so killing a sweep loses at most the points in flight. Timing columns (`*.seconds`) naturally
differ between runs; every other column of a point is reproducible from its seeds.
"""

from __future__ import annotations

import itertools
import json
import math
import os
from pathlib import Path

import numpy as np

from poevp_optics.apps.sweep.bundle import InputPlan, make_plan, scene_inputs, with_hashes
from poevp_optics.apps.sweep.cluster import ClusterError, check_local_flags
from poevp_optics.apps.sweep.execute import (ClusterSettings, DaskSession, execute_points, sigterm_noted,
                                             stop_if_terminated)
from poevp_optics.apps.sweep.point import PointTask, flatten_report, run_point  # noqa: F401
from poevp_optics.apps.run.runner import sweep_jobs
from poevp_optics.apps.sweep.reuse import columns_from_report, reuse_columns
from poevp_optics.apps.sweep.sweep_grid import (GRID_HELP, SEED_KEYS, canonical, parse_grid, point_key,  # noqa: F401
                                         point_overrides, toml_literal)
from poevp_optics.apps.sweep.sweep_state import (RECORD_KEYS, TABLE_COLUMNS, SweepStateError,  # noqa: F401
                                          check_sweep_size, read_record, read_table, read_table_checked,
                                          record_differences, sweep_record, write_table)
from poevp_optics.apps.run.run_size import MAX_SEEDS, MAX_SWEEP_RUNS, RunTooLarge
from poevp_optics.core.exceptions import SceneError
from poevp_optics.core.io import atomic_path, locked_dir, write_json
from poevp_optics.core.runtime import Terminated
from poevp_optics.scene.load import apply_overrides, load_scene, resolve_scene_path

# ---------------------------------------------------------------------------- one point
# ---------------------------------------------------------------------------- table + plots
def plot_metric(df, keys: list[str], metric: str, path: Path) -> Path | None:
    """Line plot (one key) or heat maps (two keys; one panel per value of any further keys)."""
    from poevp_optics.core.runtime import pyplot

    plt = pyplot()

    ok = df[df["status"] == "ok"]
    if metric not in ok.columns or ok.empty:
        return None
    gkeys = [f"grid.{k}" for k in keys]
    mean = ok.groupby(gkeys, dropna=False)[metric].agg(["mean", "std", "count"]).reset_index()
    if len(keys) == 1:
        fig, ax = plt.subplots(figsize=(6, 4))
        x = mean[gkeys[0]].astype(float)
        ax.errorbar(x, mean["mean"], yerr=mean["std"].fillna(0), marker="o", capsize=3)
        ax.set(xlabel=keys[0], ylabel=metric, title=f"{metric} (mean over seeds)")
    else:
        order = sorted(range(len(keys)), key=lambda i: -mean[gkeys[i]].nunique())
        kx, ky, rest = gkeys[order[0]], gkeys[order[1]], [gkeys[i] for i in order[2:]]
        combos = [()] if not rest else list(mean[rest].drop_duplicates().itertuples(index=False, name=None))
        fig, axes = plt.subplots(1, len(combos), figsize=(5 * len(combos), 4), squeeze=False)
        vmin, vmax = np.nanmin(mean["mean"]), np.nanmax(mean["mean"])
        for ax, combo in zip(axes[0], combos):
            sub = mean
            for k, v in zip(rest, combo):
                sub = sub[sub[k] == v]
            xs, ys = sorted(sub[kx].unique()), sorted(sub[ky].unique())
            grid = np.full((len(ys), len(xs)), np.nan)
            for _, r in sub.iterrows():
                grid[ys.index(r[ky]), xs.index(r[kx])] = r["mean"]
            im = ax.imshow(grid, origin="lower", aspect="auto", vmin=vmin, vmax=vmax, cmap="viridis")
            for (j, i), v in np.ndenumerate(grid):
                if np.isfinite(v):
                    ax.text(i, j, f"{v:.3g}", ha="center", va="center", fontsize=8, color="w")
            ax.set_xticks(range(len(xs)), [f"{v:g}" if isinstance(v, float) else str(v) for v in xs])
            ax.set_yticks(range(len(ys)), [f"{v:g}" if isinstance(v, float) else str(v) for v in ys])
            ax.set(xlabel=kx[5:], ylabel=ky[5:],
                   title=", ".join(f"{k[5:]}={v}" for k, v in zip(rest, combo)) or metric)
        fig.colorbar(im, ax=axes[0].tolist(), label=metric)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png", bbox_inches="tight")
    plt.close(fig)
    return path


# ---------------------------------------------------------------------------- driver
def _check_flags(job: str, seeds: int, retries: int) -> None:
    """One line naming the flag for a job, seed count or retry count out of range."""
    if job not in sweep_jobs():
        raise SceneError(f"--job {job}: must be one of {', '.join(sweep_jobs())}")
    if seeds < 1 or seeds > MAX_SEEDS:
        raise SceneError(f"--seeds {seeds}: must be 1 to {MAX_SEEDS}")
    if retries < 0:
        raise SceneError(f"--retries {retries}: must be >= 0")


def sweep(scene: str, grid_args: list[str], *, out: Path, seeds: int = 1, workers: int | None = None,
          scheduler: str | None = None, scheduler_file: str | None = None, shared_fs: bool = False,
          retries: int = 2, job: str = "render", base_overrides: list[str] = (),
          metric: str | None = None, progress: bool = True, retry_failed: bool = False,
          threads: int | None = None, log=print, yes: bool = False, rebuild: bool = False,
          tls_ca_file: str | None = None, tls_cert: str | None = None, tls_key: str | None = None,
          require_tls: bool = False, reuse_render: bool = True):
    """Run the grid; returns the results DataFrame. See the module docstring.

    scheduler / scheduler_file: an existing Dask scheduler (else a LocalCluster of `workers`).
    shared_fs: workers read the client's paths (verified) instead of a scene bundle.
    tls_ca_file / tls_cert / tls_key / require_tls: TLS to the scheduler (ClusterSettings).
    retries: runs again of a point whose worker died, >= 0 (default 2). yes: run above the
    run-size limits (apps/run/run_size.py). rebuild: a results table or sweep.json that does not
    read is rebuilt from the points' own report.json files instead of refused. reuse_render:
    points with the same render inputs share one render (reuse.py; False renders every point)."""
    _check_flags(job, seeds, retries)
    cl = ClusterSettings(workers, scheduler, str(scheduler_file) if scheduler_file else None, shared_fs,
                         retries, threads, tls_ca_file, tls_cert, tls_key, require_tls)
    if scheduler and scheduler_file:
        raise ClusterError("--scheduler and --scheduler-file: give one of them")
    if shared_fs and cl.local:
        raise ClusterError("--shared-fs: only with --scheduler or --scheduler-file (a local cluster "
                           "reads this machine's files in place)")
    if cl.local:
        check_local_flags(tls_ca_file, tls_cert, tls_key)
    grid = sorted((parse_grid(g) for g in grid_args), key=lambda kv: kv[0])
    keys = [k for k, _ in grid]
    if len(set(keys)) != len(keys):
        raise SceneError(f"--grid: a key appears twice ({', '.join(keys)})")
    if not grid:
        raise SceneError("--grid: give at least one KEY=VALUES")
    base = list(base_overrides)
    runs = math.prod(len(v) for _, v in grid) * seeds
    if runs > MAX_SWEEP_RUNS:
        raise RunTooLarge(f"--grid {' '.join(grid_args)} --seeds {seeds}: {runs} runs (points x seeds); a "
                          f"sweep runs at most {MAX_SWEEP_RUNS}: give fewer values or seeds")
    combos = list(itertools.product(*[v for _, v in grid]))
    # validate every point before anything runs or is written; list and hash what each reads
    specs = [load_scene(scene, base + point_overrides(keys, values, 0), cross_checks=False)
             for values in combos]
    hashes: dict[str, str] = {}
    point_refs = [tuple(with_hashes(scene_inputs(sp), hashes)) for sp in specs]
    toml = resolve_scene_path(scene).resolve()
    base_raw = load_scene(scene, base, cross_checks=False).raw
    sizes = _check_sizes(specs, job, seeds, toml, yes, out, cl, reuse_render)
    record = sweep_record(toml, job, seeds, dict(grid), dict(base_raw), point_refs)
    plan = make_plan("shared" if cl.local or shared_fs else "bundle", resolve_scene_path(scene),
                     [r for refs in point_refs for r in refs])
    out = Path(os.path.abspath(out))
    dask = DaskSession(cl, len(combos) * seeds, log)
    try:
        if not cl.local:
            dask.open()                    # other software on the workers: refused before writing
        with locked_dir(out, kind="sweep", protect=(toml, toml.parent)):
            mpath = out / "sweep.json"
            if mpath.is_file() or mpath.is_symlink():
                old_record = read_record(mpath, rebuild)
                diffs = record_differences(old_record, record) if old_record is not None else []
                if diffs:
                    raise SceneError(f"{out}: holds a different sweep or one whose inputs changed since "
                                     f"it started ({'; '.join(diffs)}); give another --out, or remove "
                                     f"{out} to start over")
            write_json(mpath, record)
            with sigterm_noted() as term:
                return _run_sweep(scene, out, keys, combos, point_refs, plan, seeds, base, job, dask, metric,
                                  progress, retry_failed, log, rebuild, sizes, reuse_render, term)
    finally:
        dask.close()


def _check_sizes(specs, job: str, seeds: int, toml: Path, yes: bool, out, cl: ClusterSettings,
                 reuse_render: bool) -> list:
    """Before anything runs: on a LocalCluster the largest point's memory times the workers at
    once (a remote cluster's memory is not this machine's), the whole sweep's run size, and for
    a new sweep the free space for its points and stored renders. Returns each point's size."""
    if cl.local:
        from poevp_optics.apps.run.memory import check_memory, estimate_run

        n_workers = max(1, min(cl.workers or os.cpu_count() or 1, len(specs) * seeds))
        biggest = max(specs, key=lambda sp: estimate_run(sp, job).total_bytes)
        check_memory(biggest, job, workers=n_workers,
                     where=f"{toml} (largest sweep point, {n_workers} at once)")
    sizes = check_sweep_size(specs, job, seeds, toml, yes)
    if not (Path(out) / "results.parquet").exists():   # a new sweep: refused before writing anything
        from poevp_optics.apps.sweep.reuse import render_bytes_estimate
        from poevp_optics.core.io import check_free_space

        stored = render_bytes_estimate(specs, seeds) if reuse_render and job == "render" else 0
        check_free_space(out, seeds * sum(sz.disk_bytes for sz in sizes) + stored,
                         f"this sweep ({len(specs)} points x {seeds} seeds)")
    return sizes


def _run_sweep(scene, out, keys, combos, point_refs, plan, seeds, base, job, dask, metric, progress,
               retry_failed, log, rebuild=False, sizes=None, reuse_render=False, term=None):
    import shutil
    import tomllib

    for stale in (out / "points").glob(".*.staging-*") if (out / "points").is_dir() else ():
        shutil.rmtree(stale, ignore_errors=True)        # points killed mid-write last time
    raw = tomllib.loads(resolve_scene_path(scene).read_text())
    tasks = []
    for idx, values in enumerate(combos):
        for s in range(seeds):
            ov = base + point_overrides(keys, values, s)
            k = point_key(apply_overrides(raw, ov))
            row = {"point": idx, "seed": s, "point_key": k,
                   **{f"grid.{key}": (json.dumps(v) if isinstance(v, (list, tuple)) else v)
                      for key, v in zip(keys, values)}}
            tasks.append((row, tuple(ov), point_refs[idx], out / "points" / f"{k}-s{s}"))
    prev = read_table_checked(out, rebuild, {t[0]["point_key"] for t in tasks})
    done = {}
    if prev is not None:
        for r in prev.to_dict("records"):
            if r["status"] == "ok" or (r["status"] == "failed" and not retry_failed):
                done[r["point_key"]] = r
    elif rebuild:
        done = _rows_from_reports(tasks)
        log(f"poevp sweep: rebuilt the table from {len(done)} points' own reports")
    lost = [t[0]["point_key"] for t in tasks if done.get(t[0]["point_key"], {}).get("status") == "ok"
            and not (t[3] / "report.json").is_file()]
    for k in lost:                     # its row points at nothing: run it again
        del done[k]
    if lost:
        log(f"poevp sweep: {len(lost)} finished points have no output folder any more; running them again")
    rows = [done[t[0]["point_key"]] for t in tasks if t[0]["point_key"] in done]
    todo = [t for t in tasks if t[0]["point_key"] not in done]
    log(f"poevp sweep: {len(tasks)} runs ({len(combos)} points x {seeds} seeds), "
        f"{len(rows)} already finished, {len(todo)} to run -> {out}")
    if todo and sizes:                 # room for the runs still to do (io.check_free_space)
        from poevp_optics.core.io import check_free_space

        check_free_space(out, sum(sizes[t[0]["point"]].disk_bytes for t in todo),
                         f"the {len(todo)} sweep runs still to do")
    df = write_table(rows, out) if rows else None
    if todo:
        reuse = None
        if reuse_render:
            from poevp_optics.apps.sweep.reuse import RenderReuse, point_render_groups

            reuse = RenderReuse(out, point_render_groups(scene, todo, job, log), plan.mode == "shared", log)
        df = _execute(todo, rows, out, job, plan, dask, progress, log, reuse, term)
    if df is not None and metric:
        path = plot_metric(df, keys, metric, out / f"plot_{metric.replace('.', '_')}.png")
        if path:
            log(f"poevp sweep: plot -> {path}")
        else:
            log(f"poevp sweep: no ok rows with column {metric!r}; no plot")
    return df


def _rows_from_reports(tasks) -> dict:
    """Rows of the points whose folder holds a report.json that reads (`--rebuild`); their
    `point_seconds` is not recorded there (NaN), their render columns come from the stored
    render the report names (reuse.py). Points without one run again."""
    out = {}
    for row, _ov, _refs, folder in tasks:
        try:
            report = json.loads((folder / "report.json").read_text())
        except (OSError, ValueError):
            continue
        if isinstance(report, dict):
            out[row["point_key"]] = {**row, "status": "ok", "error": "", **flatten_report(report),
                                     "point_seconds": math.nan, **columns_from_report(folder, report)}
    return out


def run_points(todo, out: Path, job: str, plan: InputPlan, cl: ClusterSettings, *, progress: bool = True,
               log=print):
    """Run points that are not a grid (e.g. apps/train/train_data.py's sequences) on Dask as a sweep
    runs its own: `todo` holds (row with point, seed and point_key; overrides; input refs;
    point folder); returns the table (also written to `out`)."""
    dask = DaskSession(cl, len(todo), log)
    try:
        return _execute(todo, [], Path(out), job, plan, dask, progress, log)
    finally:
        dask.close()


def _execute(todo, rows, out, job, plan: InputPlan, dask: DaskSession, progress, log, reuse=None, term=None):
    """execute_points with the sweep's table rewritten after every point; returns the table."""
    table = [None]

    def on_result(task, res):
        rows.append({**task[0], **res["row"], **reuse_columns(reuse, res)})
        table[0] = write_table(rows, out)
        stop_if_terminated(term)

    try:
        execute_points(todo, job, plan, dask, on_result=on_result, reuse=reuse, progress=progress, log=log,
                       resume_hint=f"the finished points are in {out}/results.parquet: ")
    except (Terminated, KeyboardInterrupt):
        log(f"poevp sweep: interrupted; {len(rows)} finished points are in {out}/results.parquet")
        raise
    return table[0]
