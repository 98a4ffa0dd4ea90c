"""`poevp sweep`'s state on disk: the record `sweep.json` (what identifies a sweep, the hashes of
the files its points read) and the table `results.parquet` / `.csv`, both checked when a sweep
resumes (a damaged one: one line naming it, or rebuilt from the points' reports with
--rebuild), and the whole sweep's run size within the limits (apps/run/run_size.py)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from poevp_optics.apps.sweep.sweep_grid import canonical
from poevp_optics.core.exceptions import UserError
from poevp_optics.core.io import atomic_path


def write_table(rows: list[dict], out: Path):
    import pandas as pd

    df = pd.DataFrame(rows)
    df = df.sort_values(["point", "seed"], kind="stable").reset_index(drop=True)
    with atomic_path(out / "results.parquet") as tmp:
        df.to_parquet(tmp, index=False)
    with atomic_path(out / "results.csv") as tmp:
        df.to_csv(tmp, index=False)
    return df


def read_table(out: Path):
    import pandas as pd

    p = out / "results.parquet"
    return pd.read_parquet(p) if p.is_file() else None


def sweep_record(toml: Path, job: str, seeds: int, grid: dict, base_raw: dict, point_refs) -> dict:
    """What identifies a sweep, and the hashes of every file its points read."""
    files = {r.source: r.sha256 for refs in point_refs for r in refs}
    return {"scene": str(toml), "job": job, "seeds": seeds,
            "grid": {k: grid[k] for k in sorted(grid)},
            "effective_scene_sha256": hashlib.sha256(canonical(base_raw).encode()).hexdigest(),
            "inputs_sha256": {f: files[f] for f in sorted(files)}}


def record_differences(old: dict, new: dict) -> list[str]:
    out = []
    for key in ("scene", "job", "seeds", "grid", "effective_scene_sha256"):
        if json.loads(json.dumps(old.get(key))) != json.loads(json.dumps(new[key])):
            what = {"effective_scene_sha256": "the scene after --set overrides"}.get(key, key)
            out.append(f"{what} differs")
    old_in, new_in = old.get("inputs_sha256") or {}, new["inputs_sha256"]
    for f in sorted(set(old_in) | set(new_in)):
        if old_in.get(f) != new_in.get(f):
            out.append(f"{f} {'changed' if f in old_in and f in new_in else 'is new' if f in new_in else 'is no longer read'}")
    return out


RECORD_KEYS = {"scene": str, "job": str, "seeds": int, "grid": dict, "effective_scene_sha256": str,
               "inputs_sha256": dict}
TABLE_COLUMNS = ("point", "seed", "point_key", "status", "error")


class SweepStateError(UserError):
    """A sweep folder's record or table that does not read: one line naming the file."""


def read_record(path: Path, rebuild: bool) -> dict | None:
    """sweep.json parsed and of the right shape (RECORD_KEYS); None when it is not and
    `rebuild` (it is then written anew), else SweepStateError."""
    try:
        rec = json.loads(path.read_text())
        bad = [k for k, t in RECORD_KEYS.items() if not isinstance(rec.get(k), t)] if isinstance(rec, dict) else ["{}"]
        problem = f"keys missing or of the wrong type: {', '.join(bad)}" if bad else None
    except (OSError, ValueError, RecursionError) as e:
        problem = f"does not read as JSON ({type(e).__name__}: {' '.join(str(e).split())[:120]})"
    if problem is None:
        return rec
    if rebuild:
        return None
    raise SweepStateError(f"{path}: the sweep record {problem}; rerun with --rebuild to rebuild it and the "
                          "table from the points' own reports, or give another --out")


def read_table_checked(out: Path, rebuild: bool, keys: set[str]):
    """results.parquet parsed, with the columns a sweep writes (TABLE_COLUMNS) and only rows of
    this sweep's points; None when absent, or when it does not read and `rebuild`."""
    p = out / "results.parquet"
    if not (p.is_file() or p.is_symlink()):
        return None
    try:
        df = read_table(out)
        missing = [c for c in TABLE_COLUMNS if c not in df.columns]
        problem = f"columns missing: {', '.join(missing)}" if missing else None
        if problem is None and not set(df["point_key"]) <= keys:
            problem = "holds rows of points that are not this sweep's"
        if problem is None and not df["status"].isin(["ok", "failed"]).all():
            problem = "holds a status other than ok/failed"
    except Exception as e:  # noqa: BLE001 - pyarrow raises its own errors for a damaged file
        problem = f"does not read as a table ({type(e).__name__}: {' '.join(str(e).split())[:120]})"
    if problem is None:
        return df
    if rebuild:
        return None
    raise SweepStateError(f"{p}: the results table {problem}; rerun with --rebuild to rebuild it from "
                          "the points' own reports (points/*/report.json), or give another --out")


def check_sweep_size(specs, job: str, seeds: int, where: Path, yes: bool) -> list:
    """The whole sweep's run size (each point x seeds) within the limits; returns each point's
    size (one seed) for the free-space check of the runs still to do (_run_sweep)."""
    from poevp_optics.apps.run import run_size

    sizes = [run_size.estimate(sp, job) for sp in specs]
    total = run_size.RunSize(0.0, 0, 0)
    for size in sizes:
        total = total + size.times(seeds)
    run_size.check(total, where=str(where), yes=yes, what=f"this sweep ({len(specs)} points x {seeds} seeds)")
    return sizes
