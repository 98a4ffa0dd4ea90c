"""scenes/city_night without rendering: its three plates lie in the camera's field at three
distances, the road-world parts are bound, and the mono render is exact although the LED and
sodium street lights have different spectra (every reflectance is flat).

The camera: a pinhole at (0.7, 1.15, 0) looking at (1.5, 1.3, 30), 12 deg across 1920 pixels
(16:9); a plate centre p projects to column W/2 - f (p - c).right / (p - c).fwd, f = (W / 2) /
tan(6 deg) (x is to the left in the world, so image columns grow toward -x)."""

from __future__ import annotations

import math

import numpy as np

from poevp_optics.render.renderer import plan_spectra
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES

#: sources/vehicles.py presets: plate centre heights (m) of the sedan, SUV and van; recess depth - 2 mm.
PLATE_Y = {"sedan": 0.55, "suv": 0.62, "van": 0.60}
PLATE_Z = 0.030 - 0.002


def test_three_plates_in_view_at_three_distances():
    spec = load_scene(SCENES / "city_night")
    h, w = spec.render.resolution
    cam, target = np.array([0.7, 1.15, 0.0]), np.array([1.5, 1.3, 30.0])
    fwd = (target - cam) / np.linalg.norm(target - cam)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    f_px = (w / 2) / math.tan(math.radians(6.0))
    dists = []
    for ident, v in spec.vehicle.items():
        x, z = v.position_m
        p = np.array([x, PLATE_Y[v.kind], z + PLATE_Z])
        d = p - cam
        col = w / 2 + f_px * np.dot(d, right) / np.dot(d, fwd)
        row = h / 2 - f_px * np.dot(d, up) / np.dot(d, fwd)
        assert 0.520 * f_px / np.linalg.norm(d) / 2 < col < w - 0.520 * f_px / np.linalg.norm(d) / 2, (ident, col)
        assert 0 < row < h, (ident, row)
        assert v.plate_text
        dists.append(float(np.linalg.norm(d)))
    assert len(dists) == 3 and max(dists) > 2 * min(dists)


def test_world_parts_bound_and_mono_exact():
    spec = load_scene(SCENES / "city_night", ["render.resolution=[46, 80]", "timing.frames=1"])
    plan = plan_spectra(spec.resolved.render)
    assert plan.mode == "mono" and "flat" in plan.reason
    for ident in spec.furniture:
        assert f"furniture_{ident}_matrix" in plan.xml_params
    bound = {"street_led_distribution", "street_hps_distribution", "sign_sheeting", "stud_sheeting"}
    assert bound <= set(plan.xml_params)
    assert plan.xml_params["sign_sheeting"] == "en12899_1:RA2"
    assert spec.flicker["signal_red"].frequency_hz == 90.0 and spec.geometry_static
