"""`poevp sweep`'s grid: the `--grid KEY=VALUES` syntax (apps/sweep/sweep.py's docstring), each point's
scene overrides and the key that names a point's folder (a hash of its effective scene table)."""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np

from poevp_optics.apps.run.run_size import MAX_SWEEP_RUNS, RunTooLarge
from poevp_optics.core.exceptions import SceneError
from poevp_optics.scene.load import parse_override


SEED_KEYS = ("render.seed", "sensor.seed")
GRID_HELP = "KEY=v1,v2,... | KEY=start:stop:num | KEY=log:start:stop:num"


# ---------------------------------------------------------------------------- grid
def split_values(text: str) -> list[str]:
    """Split at commas that are not inside brackets or quotes."""
    out, depth, quote, cur = [], 0, None, ""
    for ch in text:
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append(cur.strip())
            cur = ""
            continue
        cur += ch
    out.append(cur.strip())
    return [v for v in out if v != ""]


def is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def parse_grid(text: str) -> tuple[str, list]:
    """'key=values' -> (key, [python values]); see the module docstring for the syntax."""
    key, eq, vals = text.partition("=")
    key, vals = key.strip(), vals.strip()
    if not eq or not key or not vals:
        raise SceneError(f"--grid {text}: expected {GRID_HELP}")
    parts = vals.split(":")
    count = parts[-1] if len(parts) in (3, 4) and all(is_number(p) for p in parts[-3:]) else None
    if count is not None and count.isdigit() and int(count) > MAX_SWEEP_RUNS:
        raise RunTooLarge(f"--grid {text}: {int(count)} values; a sweep runs at most {MAX_SWEEP_RUNS} "
                          "points x seeds: give fewer")
    if parts[0] == "log" and len(parts) == 4 and all(is_number(p) for p in parts[1:]):
        a, b, n = float(parts[1]), float(parts[2]), parts[3]
        if not n.isdigit() or int(n) < 1 or a <= 0 or b <= 0:
            raise SceneError(f"--grid {text}: a log range needs start, stop > 0 and an integer count")
        values = [float(v) for v in np.geomspace(a, b, int(n))]
    elif len(parts) == 3 and all(is_number(p) for p in parts):
        if not parts[2].isdigit() or int(parts[2]) < 1:
            raise SceneError(f"--grid {text}: the count of start:stop:num must be a positive integer")
        lin = np.linspace(float(parts[0]), float(parts[1]), int(parts[2]))
        ints = all(p.lstrip("-").isdigit() for p in parts[:2]) and np.allclose(lin, np.round(lin))
        values = [int(round(v)) for v in lin] if ints else [float(v) for v in lin]
    else:
        values = [parse_override(f"{key}={v}")[1] for v in split_values(vals)]
    if not values:
        raise SceneError(f"--grid {text}: no values")
    if len({json.dumps(v) for v in values}) != len(values):
        raise SceneError(f"--grid {text}: repeated values")
    return key, values


def toml_literal(v) -> str:
    """A value as a TOML literal for `--set key=...`. NumPy scalars (a results table's cells) are
    written as the Python values they hold: NumPy 2 writes repr(np.float64(0.02)) as
    'np.float64(0.02)', which is no TOML."""
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_literal(x) for x in v) + "]"
    return str(v)


def point_overrides(keys, values, seed: int) -> list[str]:
    out = [f"{k}={toml_literal(v)}" for k, v in zip(keys, values)]
    return out + [f"{k}={seed}" for k in SEED_KEYS if k not in keys]


def canonical(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def point_key(raw_table: dict) -> str:
    """A point's name: hash of its effective scene table (after every override), so the same
    point gets the same folder whatever order its overrides were given in."""
    return hashlib.sha1(canonical(raw_table).encode()).hexdigest()[:12]
