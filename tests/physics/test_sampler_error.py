"""The Monte Carlo error estimate stays honest with randomised QMC samplers (render/samplers.py).

The estimate is the spread of two independent-seed renders (replicates, `mc_splits` = 2 as in
the scenes); the true error is the RMS difference to a high-spp reference of the unbiased
`independent` sampler, its own (estimated) variance subtracted. Both are means over pixels of
per-pixel squares, pooled over R repeats; each has a relative standard deviation of about
sqrt(2 / (R P_eff)) (chi-square, 1 dof per pixel, P_eff = (sum v)^2 / sum v^2 for unequal pixel
variances v: the plate's few bright pixels dominate), so log(estimate / true) scatters by
sigma ~ sqrt(1 / (2 R P_eff) + 1 / (2 R P_eff)) = sqrt(1 / (R P_eff)). The test requires the
factor-1.5 band to be at least 5 sigma wide, so a miss is a dishonest estimate, not
bad luck.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from poevp_optics.core.seeds import render_seeds
from poevp_optics.render.progressive import rel_error
from poevp_optics.render.renderer import DEFAULT_SAMPLER, Renderer
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES

RES = "[92,160]"
SPPS = (4, 16, 128)           # even halves that multijitter renders exactly (32 -> 35)
REPEATS = 4
REF_SPP = 12288            # the reference's variance under 0.3x the 128-spp error (0.33x at 8192 with the plate font)


def _renderer(sampler: str, splits: int = 2):
    spec = load_scene(SCENES / "highbeam_plate", [f"render.resolution={RES}", f"render.sampler='{sampler}'",
                                                  f"render.mc_splits={splits}", f"render.spp={max(splits, 16)}"])
    r = Renderer(spec.resolved.render)
    r.set_time(float(spec.subframe_times_s(0)[0]))
    return r


def _p_eff(v: np.ndarray) -> float:
    v = v.astype(np.float64).ravel()
    return float(v.sum() ** 2 / np.sum(v * v))


@pytest.fixture(scope="module")
def reference():
    r = _renderer("independent", splits=16)
    mean, var = r.render_with_error(render_seeds(99, 0, 0, 16), REF_SPP)
    return mean.astype(np.float64), var


@pytest.mark.parametrize("sampler", sorted({DEFAULT_SAMPLER, "independent"}))
def test_estimated_error_matches_true_error(sampler, reference):
    ref, ref_var = reference
    r = _renderer(sampler)
    norm = float(np.mean(ref))
    for spp in SPPS:
        est2 = sq = v_sum = 0.0
        for rep in range(REPEATS):
            mean, var = r.render_with_error(render_seeds(7, rep, spp, 2), spp)
            assert r.last_used_spp == spp                      # no rounding at these counts
            est2 += rel_error(mean, var) ** 2 / REPEATS
            sq += float(np.mean((mean.astype(np.float64) - ref) ** 2)) / REPEATS
            v_sum = v_sum + var / REPEATS
        assert np.mean(ref_var) < 0.3 * sq, "reference too noisy for this spp"
        true = math.sqrt(sq - float(np.mean(ref_var))) / norm
        sigma = math.sqrt(1.0 / (REPEATS * _p_eff(v_sum)))
        assert 5 * sigma < math.log(1.5), (sampler, spp, sigma)
        ratio = math.sqrt(est2) / true
        assert abs(math.log(ratio)) < math.log(1.5), (sampler, spp, math.sqrt(est2), true)
