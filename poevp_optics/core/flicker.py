"""PWM-driven LED emitters: the drive waveform and its exact averages over time intervals.

Automotive LED lamps are dimmed by pulse-width modulation at a few hundred Hz (typ. 200-1000
Hz; e.g. the flicker studies of IEEE P2020 "Automotive Image Quality", 2022, and SAE/ISO
discussions of LED flicker mitigation). The drive is a square wave: on (1) for `duty` x period
from `phase_s` on, then `off_fraction` (0: fully off) for the rest. Radiance is linear in drive,
so a scene whose geometry is static is rendered once per emitter group and each sub-frame is
rest + mean drive over its sub-interval x the lamp's own image (render.py / loop.py).
"""

from __future__ import annotations

import numpy as np
from dataclasses import dataclass
from poevp_optics.core.params import param


@dataclass(frozen=True)
class FlickerSpec:
    """[flicker.<param>]: the emitter spectrum `$<param>` is PWM-driven (module docstring)."""

    frequency_hz: float = param(gt=0, max=1e7)
    duty: float = param(0.5, gt=0, max=1.0)
    phase_s: float = param(0.0, min=0)
    off_fraction: float = param(0.0, min=0, max=1.0)


def drive_integral(t: np.ndarray, frequency_hz: float, duty: float, phase_s: float,
                   off_fraction: float = 0.0) -> np.ndarray:
    """Integral of the drive from phase_s to t (s*drive), exact for a square wave."""
    period = 1.0 / frequency_hz
    u = np.asarray(t, dtype=np.float64) - phase_s
    n = np.floor(u / period)
    r = u - n * period
    on = np.minimum(r, duty * period)
    per_period = duty * period + off_fraction * (1 - duty) * period
    return n * per_period + on + off_fraction * (r - on)


def drive_mean(t0: np.ndarray, t1: np.ndarray, spec) -> np.ndarray:
    """Mean drive over [t0, t1] (arrays of interval ends) for a FlickerSpec."""
    t0, t1 = np.asarray(t0, float), np.asarray(t1, float)
    args = (spec.frequency_hz, spec.duty, spec.phase_s, spec.off_fraction)
    return (drive_integral(t1, *args) - drive_integral(t0, *args)) / (t1 - t0)


def on_intervals(t0: float, t1: float, spec) -> list[tuple[float, float]]:
    """The [start, end] pieces of [t0, t1] where the drive is on (for exact reference integrals)."""
    period = 1.0 / spec.frequency_hz
    k0 = int(np.floor((t0 - spec.phase_s) / period)) - 1
    out = []
    k = k0
    while True:
        a = spec.phase_s + k * period
        if a >= t1:
            break
        b = a + spec.duty * period
        lo, hi = max(a, t0), min(b, t1)
        if hi > lo:
            out.append((lo, hi))
        k += 1
    return out
