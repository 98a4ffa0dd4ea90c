"""Shared helpers for benchmark scripts: output folder, Markdown tables, machine line.

Where a benchmark writes: `out/benchmarks/` of this checkout by default, so that running one never
rewrites the committed results; with `--results` (what `make bench` passes) into
`benchmarks/results/`, the measured numbers the documentation's Results pages show.
"""

from __future__ import annotations

import os
import platform
import resource
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: The committed results (the site's Results pages): written only with --results.
RESULTS = ROOT / "benchmarks" / "results"
#: A benchmark's default output folder (git-ignored).
OUT = ROOT / "out" / "benchmarks"


def add_results_flag(ap) -> None:
    """`--results` on a benchmark's argparse parser (see `output_folder`)."""
    ap.add_argument("--results", action="store_true",
                    help=f"write into benchmarks/results/ (the committed results, as `make bench` does) "
                         f"instead of {OUT.relative_to(ROOT)}/")


def output_folder(results: bool) -> Path:
    """benchmarks/results/ with --results, else out/benchmarks/ (created)."""
    folder = RESULTS if results else OUT
    folder.mkdir(parents=True, exist_ok=True)
    return folder


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


def save_figure(fig, path: Path) -> Path:
    """`fig` written atomically to `path` (format from its suffix)."""
    from poevp_optics.core.io import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, bbox_inches="tight", format=path.suffix.lstrip("."))
    return path


def save_text(path: Path, text: str) -> Path:
    """`text` written atomically to `path`."""
    from poevp_optics.core.io import atomic_path

    path = Path(path)
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


def cpu_seconds(children: bool = False) -> float:
    """User + system CPU seconds of this process (with `children`, plus its finished children)."""
    who = [resource.RUSAGE_SELF, *([resource.RUSAGE_CHILDREN] if children else [])]
    return sum(r.ru_utime + r.ru_stime for r in map(resource.getrusage, who))
