"""`poevp search`'s question: the scene keys it varies and their bounds (`--param`), the objective
it maximises or minimises and the constraints a trial must meet, all read from each run's
report.json.

`--param` syntax (KEY any dotted scene key, as `--set` takes it):

| form                 | what Optuna samples                                  |
|----------------------|------------------------------------------------------|
| `KEY=LOW:HIGH`       | a float uniformly in [LOW, HIGH]; an integer when both are integers |
| `KEY=log:LOW:HIGH`   | a float log-uniformly in [LOW, HIGH] (both > 0)       |
| `KEY=v1,v2,...`      | one of the values (TOML syntax, as `--grid` takes them) |

A metric (`--maximize`, `--minimize`, `--constraint`) is a dotted path into report.json:
`metrics.plate_white_after_init.in_band_fraction`, `metrics.saturated_fraction_roi.encoded`,
`timing_budget.late_frames` (a list counts its entries: the frames whose mask came late). A
constraint is `METRIC<=BOUND` or `METRIC>=BOUND`; it must hold on every scene of the search. The
objective over several scenes is the mean of each scene's value.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from poevp_optics.apps.sweep.sweep_grid import is_number, split_values, toml_literal
from poevp_optics.core.exceptions import SceneError, UserError
from poevp_optics.scene.load import parse_override

PARAM_HELP = "KEY=LOW:HIGH | KEY=log:LOW:HIGH | KEY=v1,v2,..."


@dataclass(frozen=True)
class Param:
    """One searched key. kind: `float`, `int`, `log` or `choice`; low, high: the bounds (not
    `choice`); choices: the values as TOML literals (`choice`)."""

    key: str
    kind: str
    low: float = 0.0
    high: float = 0.0
    choices: tuple[str, ...] = ()

    def suggest(self, trial) -> str:
        """The trial's value of this key (Optuna `suggest_*`) as a TOML literal for `--set`."""
        if self.kind == "choice":
            return trial.suggest_categorical(self.key, list(self.choices))
        if self.kind == "int":
            return str(trial.suggest_int(self.key, int(self.low), int(self.high)))
        return toml_literal(float(trial.suggest_float(self.key, self.low, self.high, log=self.kind == "log")))

    def literal(self, value) -> str:
        """A value Optuna stored for this key as a TOML literal."""
        if self.kind == "choice":
            return str(value)
        return str(int(value)) if self.kind == "int" else toml_literal(float(value))

    def extremes(self) -> list[str]:
        """The values that bound this key (low and high, or every choice), TOML literals."""
        if self.kind == "choice":
            return list(self.choices)
        return [self.literal(self.low), self.literal(self.high)]


def parse_param(text: str) -> Param:
    """`--param KEY=...` -> Param (module docstring); SceneError naming the flag when malformed."""
    key, eq, vals = text.partition("=")
    key, vals = key.strip(), vals.strip()
    if not eq or not key or not vals:
        raise SceneError(f"--param {text}: expected {PARAM_HELP}")
    parts = vals.split(":")
    if parts[0] == "log" and len(parts) == 3 and all(is_number(p) for p in parts[1:]):
        lo, hi = float(parts[1]), float(parts[2])
        if not (0 < lo < hi) or not math.isfinite(hi):
            raise SceneError(f"--param {text}: a log range needs 0 < LOW < HIGH")
        return Param(key, "log", lo, hi)
    if len(parts) == 2 and all(is_number(p) for p in parts):
        lo, hi = float(parts[0]), float(parts[1])
        if not (lo < hi) or not (math.isfinite(lo) and math.isfinite(hi)):
            raise SceneError(f"--param {text}: needs LOW < HIGH, both finite")
        ints = all(re.fullmatch(r"-?\d+", p.strip()) for p in parts)
        return Param(key, "int" if ints else "float", lo, hi)
    values = [toml_literal(parse_override(f"{key}={v}")[1]) for v in split_values(vals)]
    if len(values) < 2:
        raise SceneError(f"--param {text}: give two or more values, or a range LOW:HIGH (a single value "
                         "is a --set)")
    if len(set(values)) != len(values):
        raise SceneError(f"--param {text}: repeated values")
    return Param(key, "choice", choices=tuple(values))


# ---------------------------------------------------------------------------- objective and constraints
@dataclass(frozen=True)
class Constraint:
    """`metric op bound` with op `<=` or `>=`; `violation(value)` <= 0 when it holds."""

    metric: str
    op: str
    bound: float

    @property
    def text(self) -> str:
        return f"{self.metric}{self.op}{self.bound:g}"

    def violation(self, value: float) -> float:
        return value - self.bound if self.op == "<=" else self.bound - value


def parse_constraint(text: str) -> Constraint:
    m = re.fullmatch(r"\s*([A-Za-z_][\w.:()\-,]*)\s*(<=|>=)\s*(\S+)\s*", text)
    if not m or not is_number(m.group(3)):
        raise SceneError(f"--constraint {text}: expected METRIC<=NUMBER or METRIC>=NUMBER "
                         "(e.g. timing_budget.late_frames<=0)")
    return Constraint(m.group(1), m.group(2), float(m.group(3)))


@dataclass(frozen=True)
class Objective:
    """The metric a search optimises, its direction (`maximize`/`minimize`) and its constraints."""

    metric: str
    direction: str
    constraints: tuple[Constraint, ...] = ()

    def better(self, a: float, b: float) -> bool:
        return a > b if self.direction == "maximize" else a < b


class MetricError(UserError):
    """A metric path that report.json does not hold (a typo in --maximize / --constraint)."""


def metric_value(report: dict, path: str) -> float:
    """The number at dotted `path` in a run's report (a list: its length; a bool: 0 or 1; None: NaN).
    MetricError naming the keys there when the path does not exist."""
    obj = report
    walked = []
    for part in path.split("."):
        if not isinstance(obj, dict) or part not in obj:
            where = ".".join(walked) or "report.json"
            keys = sorted(k for k in obj if not str(k).startswith("_")) if isinstance(obj, dict) else []
            raise MetricError(f"{path}: a run's report.json has no {part!r} under {where}"
                              + (f" (it has: {', '.join(keys[:30])})" if keys else ""))
        obj = obj[part]
        walked.append(part)
    if obj is None:
        return math.nan
    if isinstance(obj, bool):
        return float(obj)
    if isinstance(obj, (int, float)):
        return float(obj)
    if isinstance(obj, (list, tuple)):
        return float(len(obj))
    raise MetricError(f"{path}: is a {type(obj).__name__} in report.json, not a number or a list")
