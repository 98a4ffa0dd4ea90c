"""`poevp search`: an optimiser over scene keys within bounds, for an objective read from each
run's report.json, over one or more scenes, on a sweep's Dask machinery (apps/sweep/).

The optimiser is Optuna (Akiba et al., "Optuna: A Next-generation Hyperparameter Optimization
Framework", KDD 2019): its TPE sampler (Bergstra et al., NeurIPS 2011; the first
`startup_trials` trials drawn at random, constraints as in Optuna's constrained TPE) or random
search, seeded. Trials run in batches of as many trials as there are workers: a batch is asked
of the sampler, each of its trials runs its scenes as sweep points (a point folder
`points/<hash of the effective scene>/` each, radiance shared between points with the same
render inputs: apps/sweep/reuse.py), then the batch is told back in trial order. The sampler of
each batch is seeded with (seed, trials finished so far), so a search's trials depend only on
its seed and its results, not on which worker finished first, nor on whether it was stopped
and resumed in between.

State: the Optuna study lives in the search folder (`study.journal`, Optuna's JournalStorage:
an append-only log, safe when the process is killed); `search.json` records the question
(scenes, parameters, objective, sampler, seed, the scene after --set, the hashes of every file
the scenes read); a rerun with the same question resumes, another is refused. A trial that was
running when the search was killed is marked failed and asked again with the same values; its
points that finished are read from their folders, not run again. `--trials N` is the total:
rerunning with a larger N continues the search.

Outputs: `trials.parquet` / `trials.csv` (one row per trial: its values, the objective and each
scene's metric, the constraints, the point folders, whether their radiance was reused),
`search_plot.png` (the objective against the trial number, the best so far as a line) and
`best.json`; the best trial's settings are printed as a ready `--set` line. With `--refine`, the
best trial's Eq. 2 coefficients are then moved along the differentiable camera's gradient and
run as one more point per scene (`refined.json`, apps/search/refine.py).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

from poevp_optics.apps.search.space import Objective, Param, metric_value, parse_param
from poevp_optics.apps.sweep.cluster import worker_addresses
from poevp_optics.apps.sweep.execute import (ClusterSettings, DaskSession, execute_points, sigterm_noted,
                                             stop_if_terminated)
from poevp_optics.apps.sweep.sweep_grid import canonical, point_key
from poevp_optics.core.exceptions import SceneError
from poevp_optics.core.io import locked_dir, write_json
from poevp_optics.core.runtime import Terminated
from poevp_optics.scene.load import apply_overrides, load_scene, resolve_scene_path

JOB = "render"
STUDY = "poevp-search"
SAMPLERS = ("tpe", "random")


@dataclass(frozen=True)
class SearchScene:
    """One scene of a search: its TOML, the overrides every trial starts from (--set and the
    camera's scale) and its raw table (point folder names)."""

    toml: Path
    name: str
    base: tuple[str, ...]
    raw: dict


@dataclass(frozen=True)
class Question:
    """What a search asks: parameters, objective, sampler and its seed, trials in all."""

    params: tuple[Param, ...]
    objective: Objective
    sampler: str = "tpe"
    seed: int = 0
    startup_trials: int = 10
    trials: int = 40


# ---------------------------------------------------------------------------- checks before anything runs
def load_scenes(scenes: list[str], bases: list[list[str]]) -> list[SearchScene]:
    """The search's scenes with their base overrides; a scene given twice is refused."""
    import tomllib

    out, seen = [], set()
    for scene, base in zip(scenes, bases):
        toml = resolve_scene_path(scene).resolve()
        if toml in seen:
            raise SceneError(f"{scene}: the same scene is given twice")
        seen.add(toml)
        spec = load_scene(scene, list(base), cross_checks=False)
        out.append(SearchScene(toml, spec.name, tuple(base), tomllib.loads(toml.read_text())))
    return out


def parse_params(texts: list[str]) -> tuple[Param, ...]:
    params = tuple(parse_param(t) for t in texts)
    keys = [p.key for p in params]
    if not params:
        raise SceneError("--param: give at least one KEY=LOW:HIGH or KEY=v1,v2,...")
    if len(set(keys)) != len(keys):
        raise SceneError(f"--param: a key appears twice ({', '.join(keys)})")
    return params


def check_question(scenes: list[SearchScene], q: Question, *, yes: bool, cl: ClusterSettings) -> None:
    """Every parameter's bounds load on every scene (one line naming the key otherwise), and the
    largest point fits in memory (a LocalCluster) and the whole search within the run-size
    limits (apps/run/run_size.py): trials x scenes x the largest point."""
    from poevp_optics.apps.run import run_size

    if q.sampler not in SAMPLERS:
        raise SceneError(f"--sampler {q.sampler}: must be one of {', '.join(SAMPLERS)}")
    if q.trials < 1:
        raise SceneError(f"--trials {q.trials}: must be >= 1")
    specs = []
    for sc in scenes:
        lows = [f"{p.key}={p.extremes()[0]}" for p in q.params]
        highs = [f"{p.key}={p.extremes()[-1]}" for p in q.params]
        specs += [load_scene(sc.toml, [*sc.base, *lows], cross_checks=False),
                  load_scene(sc.toml, [*sc.base, *highs], cross_checks=False)]
        for p in q.params:
            for v in p.extremes()[1:-1]:
                specs.append(load_scene(sc.toml, [*sc.base, *lows, f"{p.key}={v}"], cross_checks=False))
    if q.trials * len(scenes) > run_size.MAX_SWEEP_RUNS:
        raise run_size.RunTooLarge(f"--trials {q.trials} over {len(scenes)} scenes: a search runs at most "
                                   f"{run_size.MAX_SWEEP_RUNS} points")
    sizes = [run_size.estimate(sp, JOB) for sp in specs]
    worst = run_size.RunSize(max(s.cpu_seconds for s in sizes), max(s.disk_bytes for s in sizes),
                             max(s.files for s in sizes))
    if cl.local:
        from poevp_optics.apps.run.memory import check_memory, estimate_run

        biggest = max(specs, key=lambda sp: estimate_run(sp, JOB).total_bytes)
        n = max(1, min(cl.workers or os.cpu_count() or 1, q.trials * len(scenes)))
        check_memory(biggest, JOB, workers=n, where=f"{scenes[0].toml} (largest search point, {n} at once)")
    run_size.check(worst.times(q.trials * len(scenes)), where=str(scenes[0].toml), yes=yes,
                   what=f"this search ({q.trials} trials x {len(scenes)} scenes)")


def search_record(scenes: list[SearchScene], q: Question, hashes: dict[str, str]) -> dict:
    """What identifies a search (module docstring); `--trials` is left out: a rerun may ask more."""
    return {"scenes": [str(s.toml) for s in scenes],
            "effective_scenes_sha256": [hashlib.sha256(canonical(apply_overrides(s.raw, list(s.base))).encode())
                                        .hexdigest() for s in scenes],
            "params": [canonical(p.__dict__) for p in q.params],
            "objective": {"metric": q.objective.metric, "direction": q.objective.direction,
                          "constraints": [c.text for c in q.objective.constraints]},
            "sampler": q.sampler, "seed": q.seed, "startup_trials": q.startup_trials,
            "inputs_sha256": {k: hashes[k] for k in sorted(hashes)}}


def _check_record(out: Path, record: dict) -> None:
    path = out / "search.json"
    if not path.is_file():
        return
    try:
        old = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise SceneError(f"{path}: the search record does not read ({type(e).__name__}); give another --out, "
                         f"or remove {out} to start over") from None
    diffs = [k for k in record if k != "inputs_sha256" and json.loads(json.dumps(old.get(k))) != record[k]]
    old_in = old.get("inputs_sha256") or {}
    diffs += [f"{f} changed" for f in sorted(set(old_in) | set(record["inputs_sha256"]))
              if old_in.get(f) != record["inputs_sha256"].get(f)]
    if diffs:
        raise SceneError(f"{out}: holds a different search or one whose inputs changed since it started "
                         f"({'; '.join(str(d) + ('' if ' ' in str(d) else ' differs') for d in diffs)}); "
                         f"give another --out, or remove {out} to start over")


# ---------------------------------------------------------------------------- the study
def open_study(out: Path, q: Question, n_done: int | None = None):
    """The Optuna study in `out` (created on first use), its sampler seeded with (seed, trials
    finished so far)."""
    import optuna
    from optuna.storages.journal import JournalFileBackend, JournalStorage

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = JournalStorage(JournalFileBackend(str(out / "study.journal")))
    seed = int(hashlib.sha256(f"{q.seed}:{n_done or 0}".encode()).hexdigest()[:8], 16)
    if q.sampler == "random":
        sampler = optuna.samplers.RandomSampler(seed=seed)
    else:
        kw = {}
        if q.objective.constraints and not hasattr(optuna.trial.Trial, "set_constraint"):   # Optuna 4
            kw["constraints_func"] = lambda t: t.user_attrs.get("constraints", [0.0] * len(q.objective.constraints))
        sampler = optuna.samplers.TPESampler(seed=seed, n_startup_trials=q.startup_trials, **kw)
    return optuna.create_study(storage=storage, study_name=STUDY, direction=q.objective.direction,
                               sampler=sampler, load_if_exists=True)


def evaluated(study) -> list:
    """The trials that ran to an end (complete or failed), without those interrupted and asked
    again (their repeat carries `repeats`)."""
    from optuna.trial import TrialState

    repeated = {t.user_attrs["repeats"] for t in study.trials if "repeats" in t.user_attrs}
    return [t for t in study.trials if t.state in (TrialState.COMPLETE, TrialState.FAIL) and t.number not in repeated]


def requeue_interrupted(study, log) -> int:
    """Trials left running by a killed search: marked failed and asked again with their values
    (those drawn before the kill; a trial stopped before its values were drawn is asked anew)."""
    from optuna.trial import TrialState

    stale = [t for t in study.trials if t.state == TrialState.RUNNING]
    for t in stale:
        study.enqueue_trial(dict(t.params), user_attrs={"repeats": t.number})
        study.tell(t.number, state=TrialState.FAIL)
    if stale:
        log(f"poevp search: {len(stale)} trial(s) stopped mid-run last time; asked again with the same values "
            "(their finished points are kept)")
    return len(stale)


# ---------------------------------------------------------------------------- one batch of trials
def trial_tasks(scenes, q: Question, trial, out: Path, hashes: dict) -> tuple[dict, list]:
    """The trial's values ({key: TOML literal}) and its points (row, overrides, refs, folder)."""
    values = {p.key: p.suggest(trial) for p in q.params}
    return values, settings_tasks(scenes, values, out, hashes, trial.number)


def settings_tasks(scenes, values: dict, out: Path, hashes: dict, trial) -> list:
    """The points of one setting of the searched keys ({key: TOML literal}), one per scene:
    (row, overrides, refs, folder `points/<hash of the effective scene>`)."""
    from poevp_optics.apps.sweep.bundle import scene_inputs, with_hashes

    sets = [f"{k}={v}" for k, v in values.items()]
    tasks = []
    for i, sc in enumerate(scenes):
        ov = (*sc.base, *sets)
        key = point_key(apply_overrides(sc.raw, list(ov)))
        refs = tuple(with_hashes(scene_inputs(load_scene(sc.toml, list(ov), cross_checks=False)), hashes))
        tasks.append(({"trial": trial, "scene": i, "point_key": key}, ov, refs, out / "points" / key))
    return tasks


def _point_result(folder: Path, res: dict | None, q: Question) -> dict:
    """A point's metric and constraint values from its report.json (or why it has none)."""
    if res is not None and res["row"].get("status") != "ok":
        return {"error": res["row"].get("error") or "failed"}
    try:
        report = json.loads((folder / "report.json").read_text())
    except (OSError, ValueError) as e:
        return {"error": f"no report ({type(e).__name__})"}
    out = {"value": metric_value(report, q.objective.metric),
           "constraints": [metric_value(report, c.metric) for c in q.objective.constraints],
           "reused": bool((res or {}).get("render", {}).get("reused")) if res else None,
           "seconds": (res or {}).get("row", {}).get("point_seconds", math.nan) if res else math.nan}
    return out


def tell_trial(study, trial, q: Question, values: dict, points: list[tuple[Path, dict]], scenes) -> dict:
    """Tell Optuna the trial's objective (the mean over scenes) and constraint violations (the
    worst scene's); returns its table row."""
    from optuna.trial import TrialState

    row = {"trial": trial.number, **{f"param.{k}": v for k, v in values.items()},
           "points": ";".join(f.name for f, _ in points)}
    errors = [f"{scenes[i].name}: {r['error']}" for i, (_, r) in enumerate(points) if "error" in r]
    if errors:
        trial.set_user_attr("error", errors[0])
        study.tell(trial, state=TrialState.FAIL)
        return {**row, "state": "failed", "objective": math.nan, "feasible": False, "error": "; ".join(errors)}
    vals = [r["value"] for _, r in points]
    objective = float(sum(vals) / len(vals))
    viol = [max(c.violation(r["constraints"][j]) for _, r in points) for j, c in enumerate(q.objective.constraints)]
    trial.set_user_attr("constraints", viol)
    if hasattr(trial, "set_constraint"):           # Optuna >= 5: what its samplers read
        for c, v in zip(q.objective.constraints, viol):
            trial.set_constraint(c.text, float(v))
    feasible = all(v <= 0 for v in viol)
    if not math.isfinite(objective):
        trial.set_user_attr("error", "objective is not a number")
        study.tell(trial, state=TrialState.FAIL)
        state = "failed"
    else:
        study.tell(trial, objective)
        state = "ok" if feasible else "infeasible"
    for sc, v in zip(scenes, vals):
        row[f"value.{sc.name}"] = v
    for c, v in zip(q.objective.constraints, viol):
        row[f"constraint.{c.text}"] = v
    return {**row, "state": state, "objective": objective, "feasible": feasible, "error": "",
            "reused_points": sum(bool(r.get("reused")) for _, r in points),
            "point_seconds": float(sum(r.get("seconds", 0.0) or 0.0 for _, r in points))}


def run_batch(study, scenes, q: Question, out: Path, k: int, ctx) -> list[dict]:
    """Ask `k` trials, run their points (those already in their folders are read), tell them."""
    trials = [study.ask() for _ in range(k)]
    asked = [(t, *trial_tasks(scenes, q, t, out, ctx.hashes)) for t in trials]
    results = run_tasks(scenes, [task for _, _, tasks in asked for task in tasks], out, ctx)
    rows = []
    for trial, values, tasks in asked:
        pts = [(f, _point_result(f, results.get(f.name), q)) for _, _, _, f in tasks]
        rows.append(tell_trial(study, trial, q, values, pts, scenes))
    return rows


def run_tasks(scenes, tasks: list, out: Path, ctx) -> dict[str, dict]:
    """Run the points of `tasks` not already in their folders (once each) on the search's Dask
    session, sharing renders; {folder name: run_point's result} of those that ran."""
    todo, seen = [], set()
    for task in tasks:
        if task[3].name not in seen and not (task[3] / "report.json").is_file():
            seen.add(task[3].name)
            todo.append(task)
    results: dict[str, dict] = {}

    def on_result(task, res):
        results[task[3].name] = res
        _stop_if_terminated(ctx)

    if todo:
        if ctx.reuse is not None:
            ctx.reuse.add_groups(_groups(scenes, todo))
        execute_points(todo, JOB, lambda t: ctx.plans[t[0]["scene"]], ctx.dask,
                       on_result=on_result, reuse=ctx.reuse,
                       progress=ctx.progress, log=ctx.log,
                       resume_hint=f"the finished trials are in {out}/trials.parquet: ")
    return results


def _groups(scenes, todo) -> dict[str, str]:
    """{point folder: render group} of a batch's points (apps/sweep/reuse.py)."""
    from poevp_optics.render.render_cache import render_group

    out = {}
    for _row, ov, refs, folder in todo:
        spec = load_scene(scenes[_row["scene"]].toml, list(ov), cross_checks=False)
        if spec.source.renders:
            out[str(folder)] = render_group(spec.resolved.render, {r.key: r.sha256 for r in refs})
    return out


@dataclass
class _Context:
    dask: DaskSession
    plans: list
    hashes: dict
    reuse: object
    progress: bool
    log: object
    term: dict


def _stop_if_terminated(ctx) -> None:
    stop_if_terminated(ctx.term)


def rows_from_study(study, q: Question, known: dict[int, dict]) -> list[dict]:
    """A row per trial: the table's own where it has one, else what the study holds (a trial
    told just before the search was killed, an interrupted one, a table that did not read)."""
    from optuna.trial import TrialState

    repeated = {t.user_attrs["repeats"] for t in study.trials if "repeats" in t.user_attrs}
    rows = []
    for t in study.trials:
        if t.state not in (TrialState.COMPLETE, TrialState.FAIL):
            continue
        if t.number in known:
            rows.append(known[t.number])
            continue
        state = ("interrupted" if t.number in repeated else "failed" if t.state == TrialState.FAIL
                 else "ok" if all(v <= 0 for v in t.user_attrs.get("constraints", [])) else "infeasible")
        rows.append({"trial": t.number, "state": state, "objective": t.value if t.value is not None else math.nan,
                     "feasible": state == "ok", "error": t.user_attrs.get("error", ""),
                     **{f"param.{p.key}": p.literal(t.params[p.key]) for p in q.params if p.key in t.params}})
    return rows


def search(scenes: list[str], bases: list[list[str]], q: Question, *, out: Path, cl: ClusterSettings,
           reuse_render: bool = True, progress: bool = True, yes: bool = False, log=print,
           refine: bool = False):
    """Run (or resume) the search (module docstring); returns (trials table, best trial or None,
    refined.json's dict or None). scenes: scene paths; bases: each scene's overrides (--set, the
    camera's scale); refine: after the trials, the gradient refinement of the best trial
    (apps/search/refine.py)."""
    from poevp_optics.apps.search.results import read_trials, write_best, write_trials
    from poevp_optics.apps.sweep.bundle import make_plan, scene_inputs, with_hashes

    sc = load_scenes(scenes, bases)
    check_question(sc, q, yes=yes, cl=cl)
    hashes: dict[str, str] = {}
    refs = [with_hashes(scene_inputs(load_scene(s.toml, list(s.base), cross_checks=False)), hashes) for s in sc]
    record = search_record(sc, q, {r.source: r.sha256 for rr in refs for r in rr})
    out = Path(os.path.abspath(out))
    plans = [make_plan("shared" if cl.local or cl.shared_fs else "bundle", s.toml, list(r)) for s, r in zip(sc, refs)]
    dask = DaskSession(cl, q.trials * len(sc), log)
    try:
        if not cl.local:
            dask.open()
        with locked_dir(out, kind="search", protect=tuple(p for s in sc for p in (s.toml, s.toml.parent))):
            _check_record(out, record)
            write_json(out / "search.json", record)
            with sigterm_noted() as term:
                ctx = _Context(dask, plans, hashes, None, progress, log, term)
                df, best = _search_loop(sc, q, out, ctx, reuse_render, read_trials, write_trials, write_best)
                refined = None
                if refine and best is not None:
                    refined = _refine(sc, q, out, best, ctx, reuse_render)
                else:
                    _drop_stale_refinement(out, best)
                return df, best, refined
    finally:
        dask.close()


def _drop_stale_refinement(out: Path, best: dict | None) -> None:
    """refined.json of another best trial than today's (more trials found a better one) goes."""
    path = out / "refined.json"
    try:
        old = json.loads(path.read_text())
    except (OSError, ValueError):
        path.unlink(missing_ok=True)
        return
    if best is None or old.get("from_trial") != best["trial"] or old.get("settings_before") != best["settings"]:
        path.unlink(missing_ok=True)


def _refine(sc, q: Question, out: Path, best: dict, ctx: _Context, reuse_render: bool) -> dict:
    """The best trial refined (apps/search/refine.py), its settings run as the trials run."""
    from poevp_optics.apps.search.refine import refine_best
    from poevp_optics.apps.sweep.reuse import RenderReuse

    def run_points(values: dict) -> list:
        if ctx.reuse is None and reuse_render:
            ctx.reuse = RenderReuse(out, {}, ctx.plans[0].mode == "shared", ctx.log)
        tasks = settings_tasks(sc, values, out, ctx.hashes, "refined")
        results = run_tasks(sc, tasks, out, ctx)
        return [(f, _point_result(f, results.get(f.name), q)) for _, _, _, f in tasks]

    ctx.log(f"poevp search: refining trial {best['trial']} by the differentiable camera")
    return refine_best(sc, q, out, best, run_points, log=ctx.log)


def _search_loop(sc, q: Question, out: Path, ctx: _Context, reuse_render: bool, read_trials, write_trials,
                 write_best):
    from poevp_optics.apps.search.results import plot_trials
    from poevp_optics.apps.sweep.reuse import RenderReuse

    log = ctx.log
    study = open_study(out, q)
    requeue_interrupted(study, log)
    known = {int(r["trial"]): r for r in read_trials(out)}
    rows = rows_from_study(study, q, known)
    n_done = len(evaluated(study))
    log(f"poevp search: {q.trials} trials over {len(sc)} scene(s), {n_done} already finished -> {out}")
    df = write_trials(rows, out) if rows else None
    try:
        while n_done < q.trials:
            if ctx.reuse is None and reuse_render:
                ctx.reuse = RenderReuse(out, {}, ctx.plans[0].mode == "shared", log)
            client = ctx.dask.open()
            batch = max(1, len(ctx.dask.cluster.workers) if ctx.dask.cluster is not None
                        else len(worker_addresses(client)))
            study = open_study(out, q, n_done)
            t0 = time.perf_counter()
            new = run_batch(study, sc, q, out, min(batch, q.trials - n_done), ctx)
            rows += new
            n_done = len(evaluated(study))
            df = write_trials(rows, out)
            _stop_if_terminated(ctx)
            best = df[df["state"] == "ok"]["objective"]
            log(f"poevp search: trials {new[0]['trial']}-{new[-1]['trial']} done in {time.perf_counter() - t0:.1f} s; "
                f"best so far {(best.max() if q.objective.direction == 'maximize' else best.min()) if len(best) else 'none'}")
    except (Terminated, KeyboardInterrupt):
        log(f"poevp search: interrupted; {n_done} finished trials are in {out}/trials.parquet and the study")
        raise
    if df is None:
        return None, None
    plot_trials(df, q.objective.metric, q.objective.direction, out / "search_plot.png")
    return df, write_best(df, q.objective.direction, q.objective.metric, out)
