"""`render.light_selection = "power_roi"` (render/lights.py, render/roi.py own_light_weights,
render/exposures.py add_roi_samples): a ROI's own box renders draw the emitters by its own pilot
region's weights, p_i ~ sqrt(E[f_i^2]) normalised to a largest of 1 and floored, and the box's
pixels take those renders alone; with `power` the box's samples pool with the frame's by count.
A stand-in renderer records the weights each box render ran with."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from poevp_optics.render import lights
from poevp_optics.render.exposures import add_roi_samples


class Params(dict):
    def update(self, *a, **k):          # Mitsuba's SceneParameters.update(): nothing to push here
        if a or k:
            super().update(*a, **k)


class FakeRenderer:
    def __init__(self, selection):
        self.scene = SimpleNamespace(render=SimpleNamespace(light_selection=selection, roi_spp=28, seed=3,
                                                            resolution=(10, 12)),
                                     accuracy=SimpleNamespace(mc_splits=2))
        self.guard_px, self.mi, self.mi_scene, self.sensor = 0, None, None, None
        self.light_weights = {"near": 0.2, "far": 1.0}        # the frame's: the far lamp dominates it
        self.params = Params({"near.sampling_weight": 0.2, "far.sampling_weight": 1.0})
        self.roi_labels = (SimpleNamespace(label="car"),)
        self.used = []

    def roi_boxes(self):
        return {"car": (3, 4, 6, 9)}

    def render_box_with_error(self, seeds, spp, box):
        self.used.append({k: self.params[f"{k}.sampling_weight"] for k in ("near", "far")})
        y0, x0, y1, x1 = box
        return np.full((y1 - y0, x1 - x0), 2.0), np.full((y1 - y0, x1 - x0), 0.01), 28


@pytest.fixture
def pilot(monkeypatch):
    boxes = []

    def fake(mi, scene, sensor, seed=0, box=None):
        boxes.append(box)
        return {"near": 4.0, "far": 0.0}, 1.0               # only the near lamp lights the plate
    monkeypatch.setattr(lights, "pilot_moments", fake)
    return boxes


def test_power_roi_box_takes_its_own_weights_and_renders_alone(pilot):
    r = FakeRenderer("power_roi")
    mean, var = add_roi_samples(r.scene, r, 0, 0, np.full((10, 12), 10.0), np.full((10, 12), 4.0), 4)
    assert r.used == [{"near": 1.0, "far": lights.ROI_FLOOR}]  # sqrt(4) / sqrt(4); 0 floored
    assert r.params == {"near.sampling_weight": 0.2, "far.sampling_weight": 1.0}   # restored
    assert pilot == [(3 / 12, 2 / 10, 10 / 12, 7 / 10)]      # the box with its 1 px margin, film fractions
    inside = np.zeros((10, 12), bool)
    inside[2:7, 3:10] = True
    assert np.all(mean[inside] == 2.0) and np.allclose(var[inside], 0.01)
    assert np.all(mean[~inside] == 10.0) and np.all(var[~inside] == 4.0)


def test_power_pools_the_box_with_the_frame_by_count(pilot):
    r = FakeRenderer("power")
    mean, var = add_roi_samples(r.scene, r, 0, 0, np.full((10, 12), 10.0), np.full((10, 12), 4.0), 4)
    assert r.used == [{"near": 0.2, "far": 1.0}] and pilot == []
    assert np.allclose(mean[4, 5], (4 * 10.0 + 28 * 2.0) / 32)
    assert np.allclose(var[4, 5], (4 / 32) ** 2 * 4.0 + (28 / 32) ** 2 * 0.01)
