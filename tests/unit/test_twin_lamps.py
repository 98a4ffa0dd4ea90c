"""A car's two lamps look alike: when the car moves by about half their spacing a frame, one
lamp's outline correlates as well with its twin's last place as with its own, and the plate's
window holds both lamps. Each light must still be matched to its own last place, at the car's
shift (region_motion.py `match_regions`: a tie goes to the shift the claimant's neighbours share;
a region left without a match tries its neighbours' shifts)."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.control.predictors.flow import SATURATED, region_matches


def frame(centres, shape=(120, 200)) -> np.ndarray:
    """An 8-bit frame: a Gaussian highlight (sigma 4 px, 8x over saturation: clipped to a disc of
    ~5.8 px radius) at each centre on a dark road of 10 DN."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    img = np.full(shape, 10.0)
    for cx, cy in np.asarray(centres).reshape(-1, 2):
        img += 2000.0 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * 4.0 ** 2))
    return np.clip(np.rint(img), 0, 255).astype(np.float32)


def car(x: float, y: float) -> np.ndarray:
    """Centres (px) of two lamps 80 px apart and a plate between them, 22 px lower."""
    return np.array([[x, y], [x + 80.0, y], [x + 40.0, y + 22.0]])


@pytest.mark.parametrize("v, dy", [(37.0, 0.0), (43.0, 0.0), (37.0, 3.0), (43.0, 3.0)])
def test_each_light_of_a_car_moving_half_its_lamp_spacing_keeps_its_own_match(v, dy):
    prev = frame(car(20.0, 50.0)) >= SATURATED
    cur = frame(car(20.0 + v, 50.0 + dy)) >= SATURATED
    _, stats, matches = region_matches(prev, cur)
    assert len(matches) == 3
    for k, m in matches.items():
        assert m.prev_label == k                        # labels run in scan order in both frames
        np.testing.assert_allclose(m.shift, (v, dy), atol=0.5)
