"""Frozen parameter dataclasses with bounds, validated from plain tables (TOML, dicts).

Every stage module declares its parameters as a frozen dataclass whose fields carry their
bounds (`param(default, min=..., gt=..., choices=REGISTRY, ...)`); `parse_params` builds one from
a table and checks every key: unknown keys, wrong types, non-finite or out-of-range values,
choices (a tuple or a core.registry.Registry). A test builds a stage from a small dict, no
scene file needed:

    dmd = parse_params(DMDSpec, {"bits": 6, "contrast_ratio": 500.0})

Errors are `ParamError`s naming the dotted key; the scene loader prefixes the file.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import field
from typing import Any, get_args, get_origin, get_type_hints

from poevp_optics.core.exceptions import ParamError


def param(default: Any = dataclasses.MISSING, **meta):
    """Dataclass field with validation metadata: min, max, gt, lt, choices, length; `unset`
    (a value outside the bounds that means "from the preset") and `why` (said when a bound
    fails: what the bound protects)."""
    if isinstance(default, (list, dict)):
        raise TypeError("use tuples for defaults")
    return field(default=default, metadata=meta)


class Where:
    """Where values come from (a file, with its overrides), for one-line messages; `error`: the
    exception class raised (the scene loader uses SceneError)."""

    def __init__(self, origin: str = "", error: type[ParamError] = ParamError):
        self.origin = str(origin)
        self.error = error

    def fail(self, key: str, msg: str) -> ParamError:
        return self.error(f"{self.origin}: {key}: {msg}" if self.origin else f"{key}: {msg}")


def _check_number(where, key, value, meta, want_int):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise where.fail(key, f"expected {'an integer' if want_int else 'a number'}, got {value!r}")
    if want_int and not isinstance(value, int):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise where.fail(key, f"expected an integer, got {value!r}")
    if not math.isfinite(value):
        raise where.fail(key, f"must be finite, got {value!r}")
    if "unset" in meta and value == meta["unset"]:
        return int(value) if want_int else float(value)
    lo, hi = meta.get("min"), meta.get("max")
    hint = (f" (or {meta['unset']}: the preset's value)" if "unset" in meta else "") + \
        (f": {meta['why']}" if "why" in meta else "")
    if "gt" in meta and not value > meta["gt"]:
        raise where.fail(key, f"must be > {meta['gt']}{hint}, got {value!r}")
    if "lt" in meta and not value < meta["lt"]:
        raise where.fail(key, f"must be < {meta['lt']}{hint}, got {value!r}")
    if lo is not None and value < lo:
        what = "negative times are not allowed" if key.endswith("_s") and lo == 0 else f"must be >= {lo}"
        raise where.fail(key, f"{what}{hint}, got {value!r}")
    if hi is not None and value > hi:
        raise where.fail(key, f"must be <= {hi}{hint}, got {value!r}")
    return int(value) if want_int else float(value)


def _check_tuple(where, key, value, tp, meta):
    args = get_args(tp)
    if not isinstance(value, (list, tuple)):
        raise where.fail(key, f"expected an array, got {value!r}")
    inner = args[0]
    if len(args) == 2 and args[1] is Ellipsis:
        inner_meta = dict(meta)
        if get_origin(inner) is not tuple:
            inner_meta.pop("length", None)
        return tuple(check_value(where, f"{key}[{i}]", v, inner, inner_meta) for i, v in enumerate(value))
    if len(value) != len(args):
        raise where.fail(key, f"expected {len(args)} values, got {len(value)}")
    inner_meta = {k: v for k, v in meta.items() if k != "length"}
    return tuple(check_value(where, f"{key}[{i}]", v, a, inner_meta)
                 for i, (v, a) in enumerate(zip(value, args)))


def check_value(where: Where, key: str, value: Any, tp, meta) -> Any:
    """One value against its field type and bounds; returns the value as the field holds it."""
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise where.fail(key, f"expected a table, got {value!r}")
        return parse_params(tp, value, key, where)
    if get_origin(tp) is tuple:
        return _check_tuple(where, key, value, tp, meta)
    if tp is bool:
        if not isinstance(value, bool):
            raise where.fail(key, f"expected true or false, got {value!r}")
        return value
    if tp is int or tp is float:
        return _check_number(where, key, value, meta, tp is int)
    if tp is str:
        if not isinstance(value, str):
            raise where.fail(key, f"expected a string, got {value!r}")
        if "choices" in meta and value not in meta["choices"]:
            raise where.fail(key, f"must be one of {', '.join(map(repr, meta['choices']))}, got {value!r}")
        return value
    raise TypeError(f"unsupported field type {tp}")  # programming error


def parse_params(cls, table: dict, prefix: str = "", where: Where | None = None):
    """Build the frozen dataclass `cls` from `table`, checking every key (module docstring)."""
    where = where or Where()
    hints = get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    dot = f"{prefix}." if prefix else ""
    for k in table:
        if k not in fields:
            raise where.fail(f"{dot}{k}", f"unknown key (known: {', '.join(fields)})")
    kwargs = {}
    for name, f in fields.items():
        key = f"{dot}{name}"
        if name in table:
            kwargs[name] = check_value(where, key, table[name], hints[name], f.metadata)
        elif f.default is dataclasses.MISSING:
            raise where.fail(key, "required key is missing")
    return cls(**kwargs)
