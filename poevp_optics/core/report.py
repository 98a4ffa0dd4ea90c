"""`report.json`: scene, version, seed, per-stage seconds and error estimates, skipped stages."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from poevp_optics.core.io import write_json


def jsonable(obj):
    """Convert numpy scalars/arrays and tuples to JSON types; non-finite floats become None."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_report(out_dir: Path, report: dict) -> Path:
    path = Path(out_dir) / "report.json"
    write_json(path, jsonable(report))
    return path


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """'1 frame', '3 frames' (`plural`: an irregular plural, e.g. 'sequences x')."""
    return f"{n} {noun if n == 1 else (plural or noun + 's')}"
