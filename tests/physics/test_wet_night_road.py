"""scenes/wet_night_road at a small scale: the road world's parts render together, the plate of the
car ahead is where its geometry puts it, and the wet road mirrors the oncoming lamps.

Rendered directly (render/renderer.py, no camera chain) over the scene's 12-deg field, at t = 0.
The plate's image box must be the perspective projection of the 520 x 110 mm plate 40 m ahead
(its width w f / d in pixels, f = (W / 2) / tan(6 deg)). The oncoming SUV's
low-beam lenses are the brightest pixels above the horizon; below them, on the road between us
and the SUV, the wet asphalt holds their mirror image: the column under each lamp is many times
brighter with the water film (wetness 1) than on the dry road (wetness 0), while the road far
from the lamps' columns stays within a factor of the dry one.
"""

from __future__ import annotations

import math

import numpy as np

from poevp_optics.render.renderer import Renderer
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES

H, W = 46, 80
SMALL = [f"render.resolution=[{H}, {W}]", "timing.frames=1", "render.roi_spp=0"]


def _render(wetness: float, spp: int = 16):
    spec = load_scene(SCENES / "wet_night_road", [*SMALL, f"weather.wetness={wetness}"])
    r = Renderer(spec.resolved.render)
    r.set_time(0.0)
    mean, _ = r.render_with_error([3, 4], spp)
    return spec, r, np.asarray(mean, np.float64)


def test_plate_box_is_the_projected_plate():
    """At the 1/6-scale camera's 184 x 320 pixels (no render needed: the box is the projection of
    the plate's bounding box): the plate 40 m ahead is w f / d ~ 20 px wide and h f / d ~ 4 px tall."""
    spec = load_scene(SCENES / "wet_night_road", ["render.resolution=[184, 320]", "timing.frames=1"])
    r = Renderer(spec.resolved.render)
    r.set_time(0.0)
    y0, x0, y1, x1 = r.roi_box()
    f_px = (320 / 2) / math.tan(math.radians(6.0))
    cam = np.array([0.7, 1.15, 0.0])
    plate = np.array([0.0, 0.55, 40.0 + 0.028])          # sources/vehicles.py: sedan plate height, recess depth
    d = float(np.linalg.norm(plate - cam))
    # the box covers the plate's pixels: its projected size plus at most one pixel on each side
    assert 0.520 * f_px / d <= x1 - x0 <= 0.520 * f_px / d + 2, (x0, x1, 0.520 * f_px / d)
    assert 0.110 * f_px / d <= y1 - y0 <= 0.110 * f_px / d + 2, (y0, y1, 0.110 * f_px / d)
    # and sits where the plate's centre projects (the camera looks at (0, 0.5, 25))
    fwd = np.array([0.0, 0.5, 25.0]) - cam
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    v = plate - cam
    col = 160 + f_px * np.dot(v, right) / np.dot(v, fwd)
    row = 92 - f_px * np.dot(v, up) / np.dot(v, fwd)
    assert abs((x0 + x1) / 2 - col) <= 1.0 and abs((y0 + y1) / 2 - row) <= 1.0, ((y0, x0, y1, x1), row, col)


def test_wet_road_mirrors_the_oncoming_lamps():
    _, _, wet = _render(1.0)
    _, _, dry = _render(0.0)
    horizon = H // 2 - 3                                 # the camera looks 1.5 deg down: horizon ~ row 20
    top = wet[:horizon]
    lamp_cols = np.argsort(top.max(axis=0))[-2:]         # the two low-beam lenses: the brightest columns
    assert top.max() > 50 * np.median(wet)
    rows = slice(horizon + 4, H - 4)                     # the road between us and the SUV
    for c in lamp_cols:
        ratio = wet[rows, c].sum() / dry[rows, c].sum()
        assert ratio > 3.0, (c, ratio)
    far = [c for c in range(W) if min(abs(c - lc) for lc in lamp_cols) > 6 and c > 50]
    assert wet[rows][:, far].sum() < 3.0 * dry[rows][:, far].sum()
