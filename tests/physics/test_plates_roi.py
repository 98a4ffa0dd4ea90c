"""Every plate in view its own ROI (`render.roi_shape = "plates"`, render/roi.py): each plate's
box, distance and visibility at the pose, its own extra samples pooled only there, its own MC
error, and the report's per-plate summary; a scene without vehicle plates refused in one line.

Independent references: the plate centre's distance from the vehicle's [vehicle] position and
plate height (sources/vehicles.py's layout: rear face at position_m, plate centre RECESS_DEPTH_M -
PLATE_PROUD_M inside it) and the camera origin in the XML; the pooled variance against
(n1^2 v1 + n2^2 v2) / (n1 + n2)^2 of the two independent renders.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from poevp_optics.core.exceptions import SceneError
from poevp_optics.core.seeds import render_seeds
from poevp_optics.render.renderer import Renderer
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES


@pytest.fixture(scope="module")
def fog():
    spec = load_scene(SCENES / "fog_highway", ['render.roi_shape="plates"', "render.resolution=[180,320]",
                                               "render.roi_spp=8", "render.spp=2",
                                               'render.light_selection="power"'])   # pooled with the frame's
    r = Renderer(spec.resolved.render)
    r.set_time(0.0)
    return spec, r


def _camera_origin(xml_path) -> np.ndarray:
    """The camera's position from the XML's <lookat origin=...> (the scenes place it so)."""
    root = ET.parse(xml_path).getroot()
    look = next(root.iter("sensor")).find(".//lookat")
    defaults = {d.get("name"): d.get("value") for d in root.iter("default")}
    origin = look.get("origin")
    origin = defaults.get(origin[1:], origin) if origin.startswith("$") else origin
    return np.array([float(v) for v in origin.replace(",", " ").split()])


def test_each_plate_in_view_has_its_box_distance_and_visibility(fog):
    spec, r = fog
    assert [t.label for t in r.roi_labels] == ["truck", "car"]
    assert [t.text for t in r.roi_labels] == ["KS TR 482", "DA CK 715"]
    views = r.plate_views()
    cam = _camera_origin(spec.xml_path)
    from poevp_optics.sources.vehicles import RECESS_DEPTH_M, PLATE_PROUD_M, shape_of

    for ident in ("truck", "car"):
        v = spec.vehicle[ident]
        x, z = v.position_m
        centre = np.array([x, shape_of(v).plate_height_m, z + RECESS_DEPTH_M - PLATE_PROUD_M])
        assert views[ident].in_view and views[ident].visible_fraction == 1.0
        # the bounding box's centre is the rectangle's: float32 geometry, 1 mm
        assert views[ident].distance_m == pytest.approx(float(np.linalg.norm(centre - cam)), abs=1e-3)
    boxes = r.roi_boxes()
    assert set(boxes) == {"truck", "car"} and boxes["truck"] != boxes["car"]
    # the run's single ROI is the nearest plate's (the truck at 40 m, the car at 50 m)
    assert r.roi_box() == boxes["truck"]


def test_each_plate_gets_its_own_samples_pooled_there_only(fog):
    from poevp_optics.render.exposures import ROI_MARGIN_PX, add_roi_samples

    spec, r = fog
    scene = r.scene
    m, v = r.render_with_error(render_seeds(3, 0, 0, 2), 2)
    n1 = r.last_used_spp
    mm, vv = add_roi_samples(scene, r, 0, 0, m, v, n1)
    touched = np.zeros(m.shape, bool)
    for y0, x0, y1, x1 in r.roi_boxes().values():
        touched[max(0, y0 - ROI_MARGIN_PX):y1 + ROI_MARGIN_PX, max(0, x0 - ROI_MARGIN_PX):x1 + ROI_MARGIN_PX] = True
    assert np.array_equal(mm[~touched], m[~touched]) and np.array_equal(vv[~touched], v[~touched])
    for label, (y0, x0, y1, x1) in r.roi_boxes().items():
        # pooled n1 = 2 with n2 = 8: the variance falls to (n1^2 v1 + n2^2 v2) / (n1 + n2)^2 with
        # v2 ~ v1 n1 / n2 (same estimator, 4x the samples) -> (4 + 16) / 100 = 0.2 of v1, about;
        # a factor 2 margin for the 2-split estimates' scatter over a box of ~30 pixels
        ratio = np.mean(vv[y0:y1, x0:x1]) / np.mean(v[y0:y1, x0:x1])
        assert ratio < 0.4, (label, ratio)


def test_plates_needs_vehicle_plates_one_line_naming_the_key():
    spec = load_scene(SCENES / "highbeam_plate", ['render.roi_shape="plates"', "render.resolution=[46,80]"])
    with pytest.raises(SceneError) as e:
        Renderer(spec.resolved.render)
    msg = str(e.value)
    assert "render.roi_shape" in msg and "\n" not in msg


def test_plate_summary_counts_frames_in_band_after_the_white_frames():
    from types import SimpleNamespace

    from poevp_optics.apps.run.plates import plate_summary, plates_markdown

    spec = SimpleNamespace(mask=SimpleNamespace(band_low=0.4, band_high=0.9))
    whites = [1.0, 1.0, 0.5, 0.95, 0.6, None]            # frames 0-1 white init; frame 5 out of view

    def rec(i, w):
        return {"id": "a", "text": "AB 12", "in_view": w is not None, "distance_m": 10.0 + i, "visible_fraction": 1.0,
                "height_px": 12 - i if w is not None else None, "rel_error": 0.01 * (i + 1) if w is not None else None,
                "white": {"ldr": 1.0, "encoded": w} if w is not None else None,
                "in_band": (0.4 <= w <= 0.9) if w is not None else None}

    per_frame = [{"index": i, "init": i < 2, "plates": [rec(i, w)]} for i, w in enumerate(whites)]
    s = plate_summary(spec, per_frame)["per_plate"]["a"]
    assert s["frames"] == 6 and s["frames_in_view"] == 5
    assert s["frames_after_init_in_view"] == 3 and s["frames_in_band_after_init"] == 2
    assert s["in_band_fraction_after_init"] == pytest.approx(2 / 3)
    assert s["white_encoded_mean"] == pytest.approx((0.5 + 0.95 + 0.6) / 3)
    assert s["distance_m"] == [10.0, 14.0] and s["height_px"] == [8.0, 12.0]
    assert s["rel_error_max"] == pytest.approx(0.05)
    md = plates_markdown({"scene": "x", "metrics": {"plates": plate_summary(spec, per_frame)}})
    assert "| a | AB 12 | 5/6 |" in md and "2/3 (67 %)" in md


def test_a_stored_render_keeps_its_plates(tmp_path):
    """The render cache (render/render_cache.py) stores and reads back each plate's record."""
    from poevp_optics.core.frame import RenderedExposure
    from poevp_optics.render.render_cache import load_exposure, save_exposure

    plates = ({"id": "a", "text": "OB 180 I", "shape": "a_plate", "box": (3, 4, 9, 20), "distance_m": 22.4,
               "visible_fraction": 1.0, "rel_error": 0.05},
              {"id": "b", "text": "", "shape": "b_plate", "box": None, "distance_m": 40.0, "visible_fraction": 0.0,
               "rel_error": None})
    img = np.ones((12, 24), np.float32)
    ex = RenderedExposure.build(0, 0.0, 0.028, np.array([0.014]), (img,), img, np.zeros_like(img), (3, 4, 9, 20),
                                plates=plates)
    save_exposure(tmp_path / "x.npz", ex)
    assert load_exposure(tmp_path / "x.npz").plates == plates
