"""Which pixels show a plate (render/roi.py `plate_pixels`) and the plate's white measured on them
(apps/run/plates.py `seen_on_sensor`, analysis/metrics.py `plate_white_fraction`): a car ahead
hiding part of a plate is left out of its white.

Independent references: the plate's face (its bounding box's four corners on the face toward the
camera) projected by the camera's own projection (`sensor.sample_direction`, not the camera rays
`plate_pixels` casts) and its area by the shoelace formula; the grid-test visible fraction of
render/roi.py (`plate_view`, 3 x 3 rays at the plate's points); pixel counts set by the test for
the white.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from poevp_optics.render.renderer import Renderer
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES


def _face_area_px(r, shape) -> float:
    """Image area (px) of the plate's face toward the camera: its four corners projected by
    sensor.sample_direction, shoelace formula."""
    import drjit as dr

    mi = r.mi
    bb = shape.bbox()
    lo, hi = np.array(bb.min, dtype=np.float64).ravel(), np.array(bb.max, dtype=np.float64).ravel()
    thin = int(np.argmin(hi - lo))
    a, b = [k for k in range(3) if k != thin]
    c = 0.5 * (lo + hi)
    corners = []
    for u, v in ((lo[a], lo[b]), (hi[a], lo[b]), (hi[a], hi[b]), (lo[a], hi[b])):
        p = c.copy()
        p[a], p[b] = u, v
        corners.append(p)
    corners = np.array(corners)
    it = dr.zeros(mi.Interaction3f, 4)
    it.p = mi.Point3f(corners[:, 0], corners[:, 1], corners[:, 2])
    ds, _ = r.sensor.sample_direction(it, mi.Point2f(0.5, 0.5))
    uv = np.array(ds.uv)
    uv = uv.reshape(2, -1) if uv.shape[0] == 2 else uv.T
    x, y = uv[0], uv[1]
    return 0.5 * abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))


@pytest.fixture(scope="module")
def toll():
    spec = load_scene(SCENES / "toll_or_junction", ['render.resolution=[360,640]'])
    r = Renderer(spec.resolved.render)
    shapes = {t.label: s for t, s in r._roi_shapes}
    return spec, r, shapes


def test_a_plate_in_full_view_shows_on_its_projected_area(toll):
    spec, r, shapes = toll
    r.set_time(spec.timing.frame_start_s(2))
    for label in ("near", "mid", "far"):
        v = r.plate_views()[label]
        assert v.visible_fraction == 1.0
        area = _face_area_px(r, shapes[label])
        h, w = v.pixels.shape
        assert (h, w) == (v.box[2] - v.box[0], v.box[3] - v.box[1])
        # pixel centres inside the projected rectangle: its area within half its perimeter
        tol = 0.5 * 2 * (h + w) + 1
        assert abs(int(v.pixels.sum()) - area) <= tol, (label, int(v.pixels.sum()), area)


def test_a_plate_hidden_by_a_car_ahead_shows_only_where_it_is_seen(toll):
    spec, r, shapes = toll
    r.set_time(spec.timing.frame_start_s(20))          # a nearer car hides most of the far plate
    v = r.plate_views()["far"]
    assert 0.0 < v.visible_fraction < 0.75
    share = v.pixels.sum() / _face_area_px(r, shapes["far"])
    # the 3 x 3 grid resolves the hidden share to about one column (1/3)
    assert abs(share - v.visible_fraction) <= 0.25, (share, v.visible_fraction)
    assert 0.0 < share < 0.8


def test_the_white_is_measured_on_the_seen_pixels_through_the_registration():
    from poevp_optics.apps.run.plates import seen_on_sensor
    from poevp_optics.analysis.metrics import plate_white_fraction
    from poevp_optics.camera.registration import RegistrationSpec, mirror_coords

    mirror_shape, sensor_shape = (60, 100), (40, 80)       # a guard band of 10 mirrors
    reg = RegistrationSpec(offset_px=[3.0, -2.0])
    camera = SimpleNamespace(sensor_to_mirror=lambda sx, sy: mirror_coords(reg, sx, sy, mirror_shape, sensor_shape))
    mbox = (20, 30, 32, 70)                                 # the plate's box on the mirror grid
    seen = np.zeros((12, 40), bool)
    seen[:, :24] = True                                      # a car ahead hides its right 16 columns
    rows = tuple("".join("1" if c else "0" for c in r) for r in seen)
    # sensor = mirror - (10, 10) + offset (dx = 3, dy = -2): the box lands at y 8..20, x 23..63
    sbox = (8, 23, 20, 63)
    img = np.zeros(sensor_shape, np.uint8)
    img[8:20, 23:47] = 120                                   # the plate's white where seen
    img[8:20, 47:63] = 40                                    # the car ahead, darker
    img[14, 23:47:4] = 10                                    # some ink
    got = seen_on_sensor(camera, {"box": mbox, "seen": rows}, sbox)
    assert got.shape == (12, 40) and got.sum() == 12 * 24 and got[:, :24].all()
    assert plate_white_fraction(img, sbox, seen=got) == pytest.approx(120 / 255)
    # most of it hidden (3 of 40 columns seen): over the whole box the car ahead is the white
    img[8:20, 26:63] = 40
    seen[:, 3:] = False
    rows = tuple("".join("1" if c else "0" for c in r) for r in seen)
    got = seen_on_sensor(camera, {"box": mbox, "seen": rows}, sbox)
    assert got.sum() == 12 * 3
    assert plate_white_fraction(img, sbox, seen=got) == pytest.approx(120 / 255)
    assert plate_white_fraction(img, sbox) == pytest.approx(40 / 255)
    # a stored render without the rows: the whole box counts, as before
    assert seen_on_sensor(camera, {"box": mbox, "seen": None}, sbox) is None


def test_a_plates_mc_error_is_over_its_own_pixels():
    """progressive.rel_error with the plate's pixels: RMS standard error / mean over those pixels
    only, computed here by hand; the car ahead (dark, noisy) is left out."""
    from poevp_optics.render.progressive import rel_error

    mean = np.full((10, 20), 2.0)
    var = np.full((10, 20), 0.04 ** 2)                   # 2 % per pixel on the plate
    mean[2:8, 12:18], var[2:8, 12:18] = 0.1, 0.05 ** 2    # the car ahead: 50 % per pixel
    box = (2, 4, 8, 18)
    seen = np.ones((6, 14), bool)
    seen[:, 8:] = False
    assert rel_error(mean, var, box, seen) == pytest.approx(0.04 / 2.0)
    whole = np.sqrt((48 * 0.04 ** 2 + 36 * 0.05 ** 2) / 84) / ((48 * 2.0 + 36 * 0.1) / 84)
    assert rel_error(mean, var, box) == pytest.approx(whole)
