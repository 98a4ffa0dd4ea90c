"""Motion of shapes and emitters: displacement (m) from their XML pose over time.

| key               | type            | unit  | meaning |
|-------------------|-----------------|-------|---------|
| kind              | str             | -     | "linear", "keyframes", "static" or "traffic" |
| start_offset_m    | [x, y, z]       | m     | linear: offset at t = 0 |
| velocity_m_per_s  | [x, y, z]       | m/s   | linear: velocity |
| times_s           | [t...]          | s     | keyframes: times, strictly increasing |
| offsets_m         | [[x, y, z]...]  | m     | keyframes: offsets, held outside the span |
| attached          | [id...]         | -     | other XML ids moving with this one |
| vehicle           | str             | -     | traffic: the [vehicle.<id>] whose simulated path this is (sources/traffic.py) |

kind "traffic": the [traffic] model (sources/traffic.py) drives the vehicle; `velocity_m_per_s`
is then its velocity when the simulation starts, and the loader replaces the entry by the
`keyframes` of its simulated path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poevp_optics.core.params import param


@dataclass(frozen=True)
class MotionSpec:
    """[motion.<id>]: displacement (m) of a shape or emitter from its XML pose over time."""

    kind: str = param("linear", choices=("linear", "keyframes", "static", "traffic"))
    start_offset_m: tuple[float, float, float] = param((0.0, 0.0, 0.0), length=3)
    velocity_m_per_s: tuple[float, float, float] = param((0.0, 0.0, 0.0), length=3)
    times_s: tuple[float, ...] = param((), min=0)
    offsets_m: tuple[tuple[float, float, float], ...] = param((), length=3)
    attached: tuple[str, ...] = param(())               # other XML ids moving with this one
    vehicle: str = param("")                            # kind "traffic": the vehicle it moves

    def offset_m(self, t_s: float) -> np.ndarray:
        """Displacement (m) at time `t_s`: linear in t, or piecewise linear between keyframes
        (held constant outside the keyframe span)."""
        if self.kind == "static":
            return np.zeros(3)
        if self.kind == "traffic":
            raise ValueError("a 'traffic' motion moves only once the scene loader has simulated it "
                             "(sources/traffic.py traffic_motions)")
        if self.kind == "linear":
            return np.asarray(self.start_offset_m) + np.asarray(self.velocity_m_per_s) * t_s
        offs = np.asarray(self.offsets_m, dtype=float)
        return np.array([np.interp(t_s, self.times_s, offs[:, i]) for i in range(3)])

    @property
    def is_static(self) -> bool:
        if self.kind == "static":
            return True
        if self.kind == "traffic":
            return False
        if self.kind == "linear":
            return not any(self.velocity_m_per_s)
        offs = np.asarray(self.offsets_m, dtype=float)
        return bool(np.all(offs == offs[0]))
