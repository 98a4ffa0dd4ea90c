"""The frame clock: when each frame starts, when the sensor integrates, when the DMD displays.

| key                  | type  | unit | default | meaning |
|----------------------|-------|------|---------|---------|
| fps                  | float | Hz   | 30      | frame rate; frame i starts at i / fps |
| frames               | int   | -    | 8       | frames in the run |
| exposure_s           | float | s    | 1/60    | sensor integration time t_I |
| exposure_offset_s    | float | s    | 0       | exposure start after the frame start |
| dmd_window_s         | float | s    | 1/60    | DMD display window t_D (the bit-planes) |
| dmd_window_offset_s  | float | s    | 0       | window start after the frame start |
| outside_window       | str   | -    | white   | mirrors all on ("white") or off ("dark") outside the window |

Source: the paper's Fig. 7 timing (t_I = 33.33 ms, t_D = 20 ms, white outside t_D).

Also here, because the light side (render/, sources/: where radiance nodes go) and the camera
(camera/dmd.py: the PWM integrals) must read one clock alike: the DMD's bit-plane `Schedule` of a
frame, the radiance node times (`node_times_s`, joined by `switch_times_s`), their quadrature
weights, and `ExposureClock`, which answers both for frame i.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from poevp_optics.core.params import param


@dataclass(frozen=True)
class TimingSpec:
    """[timing]: frame clock, sensor exposure and DMD display window (s, from frame start)."""

    fps: float = param(30.0, gt=0, max=1e6)
    frames: int = param(8, min=1, max=100000)
    exposure_s: float = param(1 / 60, gt=0, max=100.0)
    exposure_offset_s: float = param(0.0, min=0)
    dmd_window_s: float = param(1 / 60, gt=0, max=100.0)
    dmd_window_offset_s: float = param(0.0, min=0)
    outside_window: str = param("white", choices=("white", "dark"))

    def frame_start_s(self, index: int) -> float:
        return index / self.fps

    def exposure_window_s(self, index: int) -> tuple[float, float]:
        """[start, end] of frame `index`'s exposure (s)."""
        t0 = self.frame_start_s(index) + self.exposure_offset_s
        return t0, t0 + self.exposure_s


@dataclass(frozen=True)
class Schedule:
    """Absolute times (s) of the exposure and display window of one frame."""

    exposure_start_s: float
    exposure_s: float
    window_start_s: float
    window_s: float
    outside_on: bool
    bits: int
    msb_first: bool
    settle_s: float
    planes_from_s: float = -math.inf      # planes starting in [from, until) show the level's bit,
    planes_until_s: float = math.inf      # the others are off (a late mask: late_exposure_weights)

    @classmethod
    def for_frame(cls, dmd, timing: TimingSpec, frame_start_s: float) -> "Schedule":
        """dmd: the display's bits, bit_order and settle_s (camera/dmd.py DMDSpec, or `PlaneDisplay`)."""
        return cls(frame_start_s + timing.exposure_offset_s, timing.exposure_s,
                   frame_start_s + timing.dmd_window_offset_s, timing.dmd_window_s,
                   timing.outside_window == "white", dmd.bits, dmd.bit_order == "msb_first",
                   dmd.settle_s)

    def plane_intervals(self) -> list[tuple[int, float, float]]:
        """(bit, start_s, end_s) of each bit-plane, in display order."""
        n = (1 << self.bits) - 1
        order = range(self.bits - 1, -1, -1) if self.msb_first else range(self.bits)
        out, t = [], self.window_start_s
        for b in order:
            d = self.window_s * (1 << b) / n
            out.append((b, t, t + d))
            t += d
        return out


def node_times_s(t0_s: float, t1_s: float, k: int, extra_s=()) -> np.ndarray:
    """Times (s) of the radiance samples of the exposure [t0, t1]: its midpoint for K = 1, else
    K equally spaced nodes including both ends, joined by `extra_s` (e.g. the DMD's switching
    times, `switch_times_s`) that fall inside. Between nodes the radiance is taken as piecewise
    linear in time (hat-function quadrature, `on_time_table`)."""
    if k < 1:
        raise ValueError(f"K = {k}: need at least one radiance sample per exposure")
    if k == 1:
        return np.array([(t0_s + t1_s) / 2])
    t = t0_s + np.arange(k) * ((t1_s - t0_s) / (k - 1))
    t[-1] = t1_s
    extra = np.asarray(extra_s, dtype=np.float64)
    if extra.size:
        tol = 1e-9 * (t1_s - t0_s)
        inside = extra[(extra > t0_s + tol) & (extra < t1_s - tol)]
        t = np.sort(np.concatenate([t, inside]))
        t = t[np.concatenate([[True], np.diff(t) > tol])]
    return t


def switch_times_s(sched: "Schedule") -> np.ndarray:
    """Absolute times (s) at which mirrors may switch: the display window's edges and every
    bit-plane boundary. A mask level's on-time is a union of intervals between them, so radiance
    nodes there resolve even the shortest planes (a level lit only by its low bits integrates
    L(t) over a millisecond, which K uniform nodes alone resolve only for K >> T / 1 ms)."""
    out = [sched.window_start_s]
    out += [b for _, _, b in sched.plane_intervals()]
    return np.array(out)


def node_time_weights_s(exposure_s: float, nodes) -> np.ndarray:
    """Integral over the exposure of each node's hat function (s): the trapezoid weights
    (h_j-1 + h_j) / 2 (h/2 at the ends); t_I for a single node. They sum to t_I. `nodes`: an
    int K (uniform) or node times relative to the exposure start."""
    if np.isscalar(nodes):
        nodes = node_times_s(0.0, exposure_s, int(nodes))
    rel = np.asarray(nodes, dtype=np.float64)
    if rel.size == 1:
        return np.array([exposure_s])
    h = np.diff(rel)
    w = np.zeros(rel.size)
    w[:-1] += h / 2
    w[1:] += h / 2
    return w


@dataclass(frozen=True)
class PlaneDisplay:
    """What the clock needs of a DMD: its bit depth, plane order and mirror settle time (s)
    (the [dmd] keys of the same names, camera/dmd.py)."""

    bits: int
    bit_order: str
    settle_s: float


@dataclass(frozen=True)
class ExposureClock:
    """When frame i's exposure runs and at which times its radiance is sampled (s).

    subframes: K uniform nodes per exposure (both ends included; the midpoint for K = 1);
    planes: the DMD whose switching times join the nodes (render.pwm_nodes with a DMD in the
    path), or None."""

    timing: TimingSpec
    subframes: int
    planes: PlaneDisplay | None = None

    def frame_start_s(self, index: int) -> float:
        return self.timing.frame_start_s(index)

    def exposure_window_s(self, index: int) -> tuple[float, float]:
        return self.timing.exposure_window_s(index)

    def subframe_times_s(self, index: int) -> np.ndarray:
        """Times (s) of the radiance samples of frame `index`'s exposure: K uniform nodes joined,
        when K > 1 and a DMD is given, by its switching times inside the exposure (window edges,
        bit-plane boundaries: `switch_times_s`)."""
        t0, t1 = self.exposure_window_s(index)
        k = self.subframes
        extra = ()
        if k > 1 and self.planes is not None:
            extra = switch_times_s(Schedule.for_frame(self.planes, self.timing, self.frame_start_s(index)))
        return node_times_s(t0, t1, k, extra)

    def subframe_weights(self, index: int) -> np.ndarray:
        """Weight of each radiance sample in the exposure's time average (sums to 1)."""
        t = self.subframe_times_s(index)
        t0, t1 = self.exposure_window_s(index)
        w = node_time_weights_s(t1 - t0, t - t0)
        return w / w.sum()
