"""Wilson intervals, the lag artifact and image entropy against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from poevp_optics.analysis.metrics import entropy_8bit, local_entropy
from poevp_optics.analysis.statistics import lag_frames, wilson_interval


def test_wilson_interval_closed_forms():
    z = 1.959963984540054
    n = 10
    # k = 0: (0, z^2 / (n + z^2)); k = n: (n / (n + z^2), 1); k = n/2: 0.5 -+ z / (2 sqrt(n + z^2))
    assert_allclose(wilson_interval(0, n), (0.0, z * z / (n + z * z)), atol=1e-12)
    assert_allclose(wilson_interval(n, n), (n / (n + z * z), 1.0), atol=1e-12)
    h = z / (2 * math.sqrt(n + z * z))
    assert_allclose(wilson_interval(5, n), (0.5 - h, 0.5 + h), atol=1e-12)
    # published 95 % values (Newcombe 1998, Stat. Med. 17: 857, Table I method 3): 81/263
    assert_allclose(wilson_interval(81, 263), (0.2553, 0.3662), atol=5e-5)
    assert wilson_interval(0, 0) == (0.0, 1.0)
    with pytest.raises(ValueError):
        wilson_interval(3, 2)


def test_wilson_interval_covers_the_true_rate():
    """Coverage of the 95 % interval over 4000 binomial draws of n = 20, p = 0.3: the count of
    misses is binomial(4000, q) with q ~ 0.05 (Wilson's coverage at this n is 0.93-0.97), so
    the observed coverage lies in 0.95 -+ 0.02 plus 4 sigma = 4 sqrt(0.05 0.95 / 4000) = 0.014."""
    rng = np.random.default_rng(3)
    ks = rng.binomial(20, 0.3, 4000)
    cover = np.mean([lo <= 0.3 <= hi for lo, hi in (wilson_interval(int(k), 20) for k in ks)])
    assert abs(cover - 0.95) < 0.034


def test_lag_frames():
    assert lag_frames([True, True, False, False, True], 2) == 2
    assert lag_frames([True, True, True], 1) == 0
    assert lag_frames([True, False, False], 1) is None


def test_entropy_closed_forms():
    # every one of 256 levels equally often: log2(256) = 8 bits; 16 levels: 4 bits
    assert_allclose(entropy_8bit(np.arange(256).repeat(4)), 8.0, atol=1e-12)
    assert_allclose(entropy_8bit(np.arange(0, 256, 16).repeat(3)), 4.0, atol=1e-12)
    assert entropy_8bit(np.full((8, 8), 77)) == 0.0
    # two levels with p = 1/4, 3/4: -(p log2 p + q log2 q)
    img = np.array([0] * 25 + [200] * 75)
    assert_allclose(entropy_8bit(img), -(0.25 * math.log2(0.25) + 0.75 * math.log2(0.75)), atol=1e-12)


def test_local_entropy_closed_forms():
    assert_allclose(local_entropy(np.full((20, 20), 9), radius_px=3), 0.0, atol=1e-6)
    # checkerboard: a (2r+1)^2 window holds ((2r+1)^2 +- 1)/2 of each level
    r = 4
    board = (np.indices((40, 40)).sum(0) % 2) * 255
    p = 41 / 81
    h = -(p * math.log2(p) + (1 - p) * math.log2(1 - p))
    assert_allclose(local_entropy(board, radius_px=r)[10:30, 10:30], h, atol=1e-5)
