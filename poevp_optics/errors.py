"""Per-run error budget: each stage's relative error estimate, the total and what to raise.

| term            | estimate | setting that lowers it |
|-----------------|----------|------------------------|
| render_mc       | RMS Monte Carlo standard error / mean radiance (independent-seed splits) | render.spp |
| temporal        | K vs K/2 sub-frames on one frame, Richardson for the midpoint rule (order 2): E_K ~ (M_K - M_K/2) / 3, with the MC noise of both renders subtracted in quadrature | render.subframes |
| psf_truncation  | energy of the PSF outside its support (relay.py) | relay.support_px / relay.support_energy |
| poisson_sampler | exact samplers (Knuth below 10 e-, PTRS above, float64 uniforms; Hormann 1993); counts are stored as float32: exact to 2^24 e-, then 2^-24 relative | - |
| quantisation    | ADC step / sqrt(12) over the mean signal above black (DN) | sensor.bits |

Total: root sum of squares (the terms are independent). The temporal term is 0 for static
scenes (K = 1 is exact) and for PWM lamps on static geometry (integrated exactly).
"""

from __future__ import annotations

import math
import time

import numpy as np

ADVICE = {"render_mc": "raise render.spp", "temporal": "raise render.subframes",
          "psf_truncation": "raise relay.support_energy (or relay.support_px)",
          "poisson_sampler": "nothing to raise (exact sampler)", "quantisation": "raise sensor.bits"}
POISSON_BOUND = 2.0 ** -24


def temporal_error(spec, renderer, frame_index: int, mean_k: np.ndarray, var_k: np.ndarray,
                   roi=None, seeds=None) -> dict:
    """Richardson estimate of the K-sub-frame quadrature error on one frame (extra K/2 renders)."""
    from .loop import _seeds
    from .metrics import crop

    k = spec.render.subframes
    if spec.geometry_static or k < 2:
        why = ("static scene: one radiance sample is exact" if spec.is_static else
               "PWM lamps on static geometry: exact integration" if spec.geometry_static else
               "K = 1: no K/2 to compare with (raise render.subframes to estimate it)")
        return {"rel": 0.0 if spec.geometry_static else None, "method": why, "seconds": 0.0}
    t0 = time.perf_counter()
    half = k // 2
    a, b = spec.exposure_window_s(frame_index)
    times = a + (np.arange(half) + 0.5) * (b - a) / half
    acc = spec.accuracy
    subs, var = [], None
    for j, t in enumerate(times):
        renderer.set_time(float(t))
        m, v = renderer.render_with_error(_seeds(spec.render.seed, frame_index, 5000 + j, acc.mc_splits), acc.spp)
        subs.append(m.astype(np.float64))
        var = v if var is None else var + v
    mean_h = np.mean(subs, axis=0)
    var_h = var / half ** 2
    diff = crop(mean_k.astype(np.float64) - mean_h, roi)
    noise = crop(var_k + var_h, roi)
    excess = float(np.mean(diff ** 2) - np.mean(noise))
    scale = float(np.mean(crop(mean_k, roi)))
    rel = math.sqrt(max(excess, 0.0)) / 3.0 / scale if scale > 0 else None
    resolved = excess > 0
    return {"rel": rel, "resolved": bool(resolved), "frame": frame_index, "k": k, "k_half": half,
            "method": "Richardson, K vs K/2 midpoint rules on one frame (order 2), MC noise removed"
                      + ("" if resolved else "; below the MC noise: 0 means 'not resolved'"),
            "seconds": time.perf_counter() - t0, "renders": half * acc.mc_splits}


def quantisation_rel(mean_signal_dn: float | None) -> float | None:
    if mean_signal_dn is None or mean_signal_dn <= 0:
        return None
    return (1.0 / math.sqrt(12.0)) / mean_signal_dn


def budget(terms: dict) -> dict:
    """{'name': {'rel': x, ...}} -> the same with 'total', 'dominant' and 'advice'."""
    vals = {k: v.get("rel") for k, v in terms.items() if v.get("rel") is not None}
    total = math.sqrt(sum(x * x for x in vals.values())) if vals else None
    dominant = max(vals, key=vals.get) if vals else None
    return {**terms, "total": {"rel": total, "definition": "root sum of squares of the terms"},
            "dominant": dominant, "advice": ADVICE.get(dominant, "")}
