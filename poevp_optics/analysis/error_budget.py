"""Per-run error budget: each stage's relative error estimate, the total and what to raise.

| term            | estimate | setting that lowers it |
|-----------------|----------|------------------------|
| render_mc       | RMS Monte Carlo standard error / mean radiance (independent-seed splits) | render.spp |
| temporal        | the frame's radiance nodes vs the same plus every interval's midpoint, on one frame, on the encoded plane with the frame's actual mask (and the white one: `rel_ldr`): E ~ (4/3)(P_nodes - P_refined) for the order-2 hat quadrature, MC noise of the difference subtracted in quadrature | render.subframes |
| psf_truncation  | energy of the PSF outside its support (relay.py) | relay.support_px / relay.support_energy |
| poisson_sampler | exact samplers (Knuth below 10 e-, PTRS above, float64 uniforms; Hormann 1993); counts are stored as float32: exact to 2^24 e-, then 2^-24 relative | - |

Total: root sum of squares (the terms are independent). These are numerical errors of the
simulation. Modelled sensor physics (ADC quantisation, shot noise) is not an error of the
simulation: the report lists it apart, under `physics_noise` (`physics_noise` below). The temporal term is 0 for static
scenes (K = 1 is exact) and for PWM lamps on static geometry (integrated exactly).
"""

from __future__ import annotations

import math
import time

import numpy as np

ADVICE = {"render_mc": "raise render.spp", "temporal": "raise render.subframes",
          "psf_truncation": "raise relay.support_energy (or relay.support_px)",
          "poisson_sampler": "nothing to raise (exact sampler)"}
POISSON_BOUND = 2.0 ** -24


def quantisation_rel(mean_signal_dn: float | None) -> float | None:
    """ADC rounding noise, step / sqrt(12), relative to a mean signal above black (DN)."""
    if mean_signal_dn is None or mean_signal_dn <= 0:
        return None
    return (1.0 / math.sqrt(12.0)) / mean_signal_dn


def physics_noise(mean_signal_dn: float | None, mean_signal_e: float | None, bits: int) -> dict:
    """Modelled sensor noise at the ROI's mean signal (relative): not a numerical error of the
    simulation, listed apart from the error budget."""
    shot = 1.0 / math.sqrt(mean_signal_e) if mean_signal_e and mean_signal_e > 0 else None
    return {"quantisation": {"rel": quantisation_rel(mean_signal_dn), "bits": bits,
                             "definition": "ADC step / sqrt(12) over the mean signal above black"},
            "shot": {"rel": shot, "definition": "1 / sqrt(mean signal electrons)"},
            "note": "modelled physics of the camera, not error of the simulation: raise sensor.bits "
                    "or the exposure to lower them in the camera itself"}


def budget(terms: dict) -> dict:
    """{'name': {'rel': x, ...}} -> the same with 'total', 'dominant' and 'advice'."""
    vals = {k: v.get("rel") for k, v in terms.items() if v.get("rel") is not None}
    total = math.sqrt(sum(x * x for x in vals.values())) if vals else None
    dominant = max(vals, key=vals.get) if vals else None
    return {**terms, "total": {"rel": total, "definition": "root sum of squares of the terms"},
            "dominant": dominant, "advice": ADVICE.get(dominant, "")}
