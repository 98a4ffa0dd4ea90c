"""Shared helpers for benchmark scripts: results folder, Markdown tables, machine line."""

from __future__ import annotations

import os
import platform
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def machine_line() -> str:
    import drjit as dr
    import mitsuba as mi

    return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
            f"Mitsuba {mi.__version__}, DrJit {dr.__version__}, {dr.thread_count()} DrJit threads")


def markdown_table(header: list[str], rows: list[list]) -> str:
    def fmt(v):
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def save_figure(fig, name: str) -> Path:
    from poevp_optics.core.io import atomic_path

    path = RESULTS / name
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, bbox_inches="tight", format=path.suffix.lstrip("."))
    return path


def save_text(name: str, text: str) -> Path:
    from poevp_optics.core.io import atomic_path

    path = RESULTS / name
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return path


def timed(fn, repeats: int = 5):
    """(median wall seconds over `repeats` warm calls, the last call's result); one warm-up call."""
    import time

    import numpy as np

    fn()
    ts, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)), out
