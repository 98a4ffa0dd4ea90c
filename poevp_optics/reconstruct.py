"""DN -> radiance estimate through the known per-pixel exposure; flags, never Inf/NaN.

estimate = ((DN - offset) / gain - dark electrons) / (effective exposure x etendue x throughput)
in the ground truth's unit (e- s-1 m-2 sr-1, time-averaged over the exposure).

Flags (float32 bit field in the EXR channel `flags`):
  1 saturated: DN at the top code or electrons at full well; the estimate is a lower bound.
  2 under-exposed: expected SNR < 1 (signal electrons below the temporal noise
    sqrt(signal + dark + read^2 + (1/gain)^2 / 12)); the estimate is noise-dominated.
  4 unexposed: effective exposure below 1e-30 s (mask 0 with an ideal, leak-free DMD); the
    estimate is set to 0 instead of dividing by zero.
"""

from __future__ import annotations

import numpy as np

from .sensor import SensorParams

SATURATED, UNDEREXPOSED, UNEXPOSED = 1, 2, 4


def reconstruct(dn: np.ndarray, exposure_s: np.ndarray, p: SensorParams, etendue_m2_sr: float,
                throughput: float, exposure_window_s: float, dark_current_on: bool = True):
    """Return (radiance estimate float32, flags float32, signal electrons float64)."""
    dn = np.asarray(dn, dtype=np.float64)
    expo = np.asarray(exposure_s, dtype=np.float64)
    dark_e = p.dark_current_e_per_s * exposure_window_s if dark_current_on else 0.0
    electrons = (dn - p.offset_dn) / p.gain_dn_per_e
    signal = np.maximum(electrons - dark_e, 0.0)
    scale = expo * etendue_m2_sr * throughput                 # electrons per unit radiance
    unexposed = expo < 1e-30
    est = np.where(unexposed, 0.0, signal / np.where(unexposed, 1.0, scale))
    saturated = (dn >= p.max_dn - 0.5) | (electrons >= p.full_well_e * (1 - 1e-6))
    noise = np.sqrt(signal + dark_e + p.read_noise_e ** 2 + (1.0 / p.gain_dn_per_e) ** 2 / 12.0)
    under = signal < noise
    flags = (saturated * SATURATED) | (under * UNDEREXPOSED) | (unexposed * UNEXPOSED)
    est = np.nan_to_num(est, nan=0.0, posinf=np.finfo(np.float32).max, neginf=0.0)
    return est.astype(np.float32), flags.astype(np.float32), signal
