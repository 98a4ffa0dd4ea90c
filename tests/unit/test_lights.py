"""Light selection weights (render/lights.py): p_i ~ sqrt(E[f_i^2]), floored, and the choice
minimises the one-sample estimator's second moment sum_i E[f_i^2] / p_i."""

from __future__ import annotations

import numpy as np

from poevp_optics.render.lights import FLOOR, weights_from_moments


def test_weights_are_sqrt_of_second_moments_with_a_floor():
    w = weights_from_moments({"beam": 4.0, "beam2": 1.0, "sky": 1e-12, "off": 0.0})
    assert w["beam"] == 1.0 and abs(w["beam2"] - 0.5) < 1e-12
    assert w["sky"] == FLOOR and w["off"] == FLOOR
    assert weights_from_moments({"a": 0.0, "b": 0.0}) == {"a": 1.0, "b": 1.0}


def test_sqrt_weights_minimise_the_second_moment():
    m = np.array([9.0, 1.0, 0.04])
    w = np.array(list(weights_from_moments(dict(zip("abc", m))).values()))

    def second_moment(p):
        p = p / p.sum()
        return float(np.sum(m / p))

    best = second_moment(w)
    rng = np.random.default_rng(0)
    for _ in range(200):                      # any other selection does no better
        assert second_moment(w * np.exp(rng.normal(0, 0.3, 3))) >= best * (1 - 1e-12)
    assert best < second_moment(np.ones(3))   # and uniform selection is worse


def test_roi_weighted_moments_minimise_the_sum_of_relative_variances():
    """Two regions (frame, ROI): p_i ~ sqrt(sum_g E_g[f_i^2] / M_g^2) minimises
    sum_g (sum_i E_g[f_i^2] / p_i - M_g^2) / M_g^2; a region without signal is left out."""
    from poevp_optics.render.lights import roi_weighted_moments

    frame = ({"left": 1.0, "right": 1.0, "sky": 0.01}, 1.5)
    roi = ({"left": 9.0, "right": 1.0, "sky": 1e-6}, 4.0)   # a plate returning 3x more of the left beam
    comb = roi_weighted_moments([frame, roi, ({"left": 0.0, "right": 0.0, "sky": 0.0}, 0.0)])
    for k in ("left", "right", "sky"):
        assert abs(comb[k] - (frame[0][k] / 1.5 ** 2 + roi[0][k] / 4.0 ** 2)) < 1e-12
    w = np.array([weights_from_moments(comb)[k] for k in ("left", "right", "sky")])

    def objective(p):
        p = p / p.sum()
        return sum(sum(m[k] / q for k, q in zip(("left", "right", "sky"), p)) / mean ** 2 - 1.0
                   for m, mean in (frame, roi))

    best = objective(w)
    rng = np.random.default_rng(1)
    for _ in range(200):
        assert objective(w * np.exp(rng.normal(0, 0.3, 3))) >= best * (1 - 1e-12)
    assert best < objective(np.array([1.0, 1.0, 1.0]))
