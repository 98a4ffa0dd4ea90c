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


def dn_to_electrons(dn: np.ndarray, p: SensorParams) -> np.ndarray:
    """Electrons behind each DN, dark signal included (offset removed, divided by gain), in
    the dtype of `dn`."""
    t = dn.dtype.type
    return (dn - t(p.offset_dn)) * t(1.0 / p.gain_dn_per_e)


def is_saturated(dn: np.ndarray, electrons: np.ndarray, p: SensorParams) -> np.ndarray:
    """DN at the top code or electrons at full well: the value is only a lower bound."""
    t = dn.dtype.type
    return (dn >= t(p.max_dn - 0.5)) | (electrons >= t(p.full_well_e * (1 - 1e-6)))


def reconstruct(dn: np.ndarray, exposure_s: np.ndarray, p: SensorParams, etendue_m2_sr: float,
                throughput: float, exposure_window_s: float, dark_current_on: bool = True):
    """Return (radiance estimate float32, flags float32, signal electrons float32).

    float32 throughout (DN are exact integers; the products and one division keep ~1e-7
    relative error, far below shot noise); 3x faster than float64 at 720x1280.
    """
    f32 = np.float32
    dn = np.asarray(dn, dtype=f32)
    expo = np.asarray(exposure_s, dtype=f32)
    dark_e = f32(p.dark_current_e_per_s * exposure_window_s if dark_current_on else 0.0)
    electrons = dn_to_electrons(dn, p)
    signal = np.maximum(electrons - dark_e, f32(0.0))
    scale = expo * f32(etendue_m2_sr * throughput)            # electrons per unit radiance
    unexposed = expo < f32(1e-30)
    est = signal / np.where(unexposed | ~(scale > 0), f32(1.0), scale)
    est[unexposed] = 0.0
    saturated = is_saturated(dn, electrons, p)
    noise2 = signal + dark_e + f32(p.read_noise_e ** 2 + (1.0 / p.gain_dn_per_e) ** 2 / 12.0)
    under = signal * signal < noise2                          # SNR < 1
    flags = (saturated * SATURATED) | (under * UNDEREXPOSED) | (unexposed * UNEXPOSED)
    np.minimum(est, np.finfo(f32).max, out=est)               # never Inf
    return est, flags.astype(f32), signal
