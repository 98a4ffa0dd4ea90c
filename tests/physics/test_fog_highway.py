"""scenes/fog_highway at a small scale: the truck's plate, lit by our high beams through the fog and
seen through it, is dimmed by the fog's transmittance on both legs.

Our beams reach the plate over d_lamp and its light returns to the camera over d_cam, both
through fog of extinction sigma = ln(20) / V (V = 150 m, the scene's meteorological optical range),
so with the droplets' albedo set to 0 (extinction only, no veil of scattered light) the plate's
image is the clear-air one times exp(-sigma d_cam) x exp(-sigma d_lamp), the latter averaged over
our two lamps (each contributes about half). The plate's box is rendered with and without fog at
t = 0 (render/renderer.py, the box alone), in 8 independent-seed parts whose spread gives the
standard error; the street lights' share of the plate's light (< 0.2 %: they light it from 10 m up
and 7 m aside, and its sheeting returns their light toward them) is covered by a 1 % allowance.
"""

from __future__ import annotations

import math

import numpy as np

from poevp_optics.render.renderer import Renderer
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES

SMALL = ["render.resolution=[92, 160]", "timing.frames=1", "render.roi_spp=0", "weather.fog_albedo=0.0"]


def _plate_box_mean(visibility_m: float, spp: int = 512):
    spec = load_scene(SCENES / "fog_highway", [*SMALL, f"weather.fog_visibility_m={visibility_m}"])
    r = Renderer(spec.resolved.render)
    r.set_time(0.0)
    box = r.roi_box()
    y0, x0, y1, x1 = box
    # the plate's own pixels: the inner part of its box (the box is the plate's pixel cover)
    means = np.array([float(np.asarray(r.render_box(s, spp // 8, box), np.float64)[1:-1, 1:-1].mean())
                      for s in range(1, 9)])
    return means.mean(), means.std(ddof=1) / math.sqrt(len(means)), box


def test_plate_seen_through_fog_is_dimmed_on_both_legs():
    clear, clear_se, box = _plate_box_mean(0.0, spp=64)
    fog, fog_se, box_fog = _plate_box_mean(150.0)
    assert box == box_fog and box[3] - box[1] >= 8
    sigma = math.log(20.0) / 150.0
    plate = np.array([0.0, 0.80, 40.0 + 0.028])          # sources/vehicles.py: truck plate height, recess depth
    cam = np.array([0.7, 1.15, 0.0])
    lamps = [np.array([0.7, 0.65, 0.0]), np.array([-0.7, 0.65, 0.0])]
    t_lamp = np.mean([math.exp(-sigma * np.linalg.norm(plate - p)) for p in lamps])
    expected = math.exp(-sigma * np.linalg.norm(plate - cam)) * t_lamp
    got = fog / clear
    se = math.hypot(fog_se / clear, got * clear_se / clear)
    # 5.4 standard errors (Student's t, 7 dof, 99.9 %) plus the street lights' 1 %
    assert abs(got - expected) <= 5.4 * se + 0.01 * expected, (got, expected, se)
    print(f"plate through V = 150 m fog: {got:.4f} +- {se:.4f} of clear air, exp(-sigma (d_cam + d_lamp)) = {expected:.4f}")
