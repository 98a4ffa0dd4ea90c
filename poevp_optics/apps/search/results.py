"""`poevp search`'s outputs: the trials table, the plot of the objective against the trials, the
best trial and its ready `--set` line (apps/search/search.py writes them after every batch)."""

from __future__ import annotations

import math
import shlex
from pathlib import Path

import numpy as np

from poevp_optics.core.io import atomic_path, write_json


def write_trials(rows: list[dict], out: Path):
    """trials.parquet and trials.csv, one row per trial in trial order (atomically)."""
    import pandas as pd

    df = pd.DataFrame(rows).sort_values("trial", kind="stable").reset_index(drop=True)
    with atomic_path(out / "trials.parquet") as tmp:
        df.to_parquet(tmp, index=False)
    with atomic_path(out / "trials.csv") as tmp:
        df.to_csv(tmp, index=False)
    return df


def read_trials(out: Path) -> list[dict]:
    """The rows of trials.parquet ([] when there is none or it does not read: rebuilt)."""
    import pandas as pd

    p = out / "trials.parquet"
    try:
        return pd.read_parquet(p).to_dict("records") if p.is_file() else []
    except Exception:  # noqa: BLE001 - a damaged table is rebuilt from the study and the points
        return []


def best_row(df, direction: str) -> dict | None:
    """The best feasible trial's row (ties: the earliest), or None."""
    ok = df[(df["state"] == "ok")] if "state" in df else df.iloc[:0]
    if ok.empty:
        return None
    i = ok["objective"].idxmax() if direction == "maximize" else ok["objective"].idxmin()
    return ok.loc[i].to_dict()


def set_line(row: dict) -> str:
    """The trial's values as `--set KEY=VALUE` arguments, quoted for a POSIX shell."""
    return " ".join(f"--set {shlex.quote(f'{k[6:]}={v}')}" for k, v in row.items() if k.startswith("param."))


def write_best(df, direction: str, metric: str, out: Path) -> dict | None:
    """best.json: the best feasible trial, its objective and its `--set` line; None if none."""
    row = best_row(df, direction)
    if row is None:
        (out / "best.json").unlink(missing_ok=True)
        return None
    best = {"trial": int(row["trial"]), "objective": float(row["objective"]), "metric": metric,
            "direction": direction,
            "settings": {k[6:]: v for k, v in row.items() if k.startswith("param.")},
            "set_line": set_line(row), "points": str(row.get("points", "")).split(";")}
    write_json(out / "best.json", best)
    return best


def plot_trials(df, metric: str, direction: str, path: Path) -> Path | None:
    """The objective of every trial against its number (infeasible: crosses), the best feasible
    so far as a step line."""
    from poevp_optics.core.runtime import pyplot

    plt = pyplot()
    done = df[df["state"].isin(["ok", "infeasible"])] if "state" in df else df.iloc[:0]
    if done.empty:
        return None
    fig, ax = plt.subplots(figsize=(6.5, 4))
    ok, bad = done[done["state"] == "ok"], done[done["state"] == "infeasible"]
    ax.plot(ok["trial"], ok["objective"], "o", label="trial")
    if not bad.empty:
        ax.plot(bad["trial"], bad["objective"], "x", color="0.5", label="trial breaking a constraint")
    if not ok.empty:
        pick = np.maximum.accumulate if direction == "maximize" else np.minimum.accumulate
        trials = np.arange(int(df["trial"].min()), int(df["trial"].max()) + 1)
        series = np.full(len(trials), -math.inf if direction == "maximize" else math.inf)
        for t, v in zip(ok["trial"], ok["objective"]):
            series[int(t) - trials[0]] = v
        best = pick(series)
        keep = np.isfinite(best)
        ax.step(trials[keep], best[keep], where="post", label="best so far")
    ax.set(xlabel="trial", ylabel=metric, title=f"{direction} {metric}")
    ax.legend(loc="best", fontsize=8)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png", bbox_inches="tight")
    plt.close(fig)
    return path
