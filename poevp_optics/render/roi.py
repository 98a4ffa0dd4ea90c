"""Regions of interest of a render: which shapes get extra samples, their image boxes, and the
view of each plate (distance, how much of it the camera sees).

`render.roi_shape` takes:

| value        | meaning |
|--------------|---------|
| ""           | no ROI |
| a shape id   | that shape's projected box is the ROI (one plate: the scene's own `[plate]` or a vehicle's) |
| "plates"     | every [vehicle.<id>] plate in the XML (the rectangle placed by `$vehicle_<id>_plate_matrix`) |

With "plates" each plate in view gets its own box at each pose, its own `render.roi_spp`
samples (exposures.add_roi_samples), its own Monte Carlo error and its own record in the run's
report (`per_frame[i].plates`, `plates`). The run's single ROI (`roi`, `saturated_fraction_roi`,
`plate_white_fraction`, ...) is then the nearest plate in view. A plate is in view when its box
lies on the film and the camera sees part of it: of `VIEW_GRID` x `VIEW_GRID` points on the plate,
those whose ray from the camera reaches the plate before anything else (`PlateView.visible_fraction`;
a car ahead can hide a plate whose box is on the film). Which pixels of its box show the plate
(`PlateView.pixels`): the camera ray through each pixel's centre whose first hit lies on the plate
(inside its bounding box, grown by VIEW_TOLERANCE_M along its normal), so a plate's white is measured on the plate
itself and not on the car that hides part of it (apps/run/plates.py).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from poevp_optics.core.exceptions import SceneError

#: `render.roi_shape` value selecting every vehicle plate.
ALL_PLATES = "plates"
#: Points per side of the grid on a plate whose rays test its visibility (inset half a cell).
VIEW_GRID = 3
#: A ray reaches the plate when it hits nothing nearer than the plate point minus this (m): the
#: plate is 2 mm proud of its recess floor (sources/vehicles.py PLATE_PROUD_M).
VIEW_TOLERANCE_M = 0.01


@dataclass(frozen=True)
class RoiTarget:
    """One ROI: its label in the report (the vehicle id, or the shape id), the XML shape id, and
    the plate text where the scene gives one ("" otherwise)."""

    label: str
    shape_id: str
    text: str = ""


@dataclass(frozen=True)
class PlateView:
    """A plate seen from the camera at one pose: its image box (y0, x0, y1, x1, end-exclusive,
    rendered grid; None off the film), its centre's distance from the camera (m) and the share
    of its test points the camera sees (0..1)."""

    box: tuple[int, int, int, int] | None
    distance_m: float
    visible_fraction: float
    pixels: np.ndarray | None = None   # bool, the box's shape: the pixel's centre ray hits the plate first

    @property
    def in_view(self) -> bool:
        return self.box is not None and self.visible_fraction > 0


def vehicle_plate_shapes(xml_path: Path) -> dict[str, str]:
    """{vehicle id: shape id} of the XML's shapes placed by `$vehicle_<id>_plate_matrix`."""
    root = ET.parse(xml_path).getroot()
    out = {}
    for shape in root.iter("shape"):
        for m in shape.iter("matrix"):
            v = (m.get("value") or "").strip()
            if v.startswith("$vehicle_") and v.endswith("_plate_matrix") and shape.get("id"):
                out[v[len("$vehicle_"):-len("_plate_matrix")]] = shape.get("id")
    return out


def roi_targets(scene) -> list[RoiTarget]:
    """The ROIs `render.roi_shape` selects (module table), in the scene file's vehicle order;
    SceneError (one line naming the key) when "plates" finds no vehicle plate."""
    sel = scene.render.roi_shape
    if not sel:
        return []
    vehicles = getattr(scene, "vehicle", {}) or {}
    if sel != ALL_PLATES:
        text = next((v.plate_text for k, v in vehicles.items()
                     if vehicle_plate_shapes(scene.xml_path).get(k) == sel), "") if vehicles else ""
        return [RoiTarget(sel, sel, text or getattr(scene.plate, "text", ""))]
    shapes = vehicle_plate_shapes(scene.xml_path)
    out = [RoiTarget(k, shapes[k], v.plate_text) for k, v in vehicles.items() if k in shapes]
    if not out:
        raise SceneError(f"{scene.toml_path}: render.roi_shape: \"plates\" selects every [vehicle.<id>] plate, but "
                         f"{scene.xml_path.name} places none (no shape whose to_world is $vehicle_<id>_plate_matrix "
                         "for a [vehicle] of this scene)")
    return out


def pool_samples(mean, var, count, box, m2, v2, n2):
    """Pool `n2` more samples per pixel (mean m2, variance of the mean v2) into the pixels of
    `box` of (mean, var), whose pixels hold `count` samples each (an array: pixels another ROI
    already pooled hold more): mean (n1 m1 + n2 m2) / (n1 + n2), variance
    (n1^2 v1 + n2^2 v2) / (n1 + n2)^2 (independent unbiased estimates of the same pixel
    integral). In place; returns nothing."""
    y0, x0, y1, x1 = box
    n1 = count[y0:y1, x0:x1]
    a, b = n1 / (n1 + n2), n2 / (n1 + n2)
    mean[y0:y1, x0:x1] = a * mean[y0:y1, x0:x1] + b * m2
    var[y0:y1, x0:x1] = a * a * var[y0:y1, x0:x1] + b * b * v2
    count[y0:y1, x0:x1] = n1 + n2


def plate_view(renderer, shape, box) -> PlateView:
    """`PlateView` of `shape` at the renderer's current pose (module docstring): the distance
    from the camera's centre of projection to the shape's bounding-box centre, and the share of
    VIEW_GRID^2 points inset on the box's face toward the camera that a ray from the camera
    reaches before hitting anything else."""
    mi = renderer.mi
    bb = shape.bbox()
    lo, hi = np.array(bb.min, dtype=np.float64).ravel(), np.array(bb.max, dtype=np.float64).ravel()
    centre = 0.5 * (lo + hi)
    origin = np.array(renderer.sensor.world_transform().translation(), dtype=np.float64).ravel()[:3]
    dist = float(np.linalg.norm(centre - origin))
    g = (np.arange(VIEW_GRID) + 0.5) / VIEW_GRID
    thin = int(np.argmin(hi - lo))                          # the plate's normal axis
    axes = [k for k in range(3) if k != thin]
    pts = np.repeat(centre[None, :], VIEW_GRID * VIEW_GRID, axis=0)
    a, b = np.meshgrid(g, g)
    pts[:, axes[0]] = lo[axes[0]] + a.ravel() * (hi[axes[0]] - lo[axes[0]])
    pts[:, axes[1]] = lo[axes[1]] + b.ravel() * (hi[axes[1]] - lo[axes[1]])
    d = pts - origin[None, :]
    t = np.linalg.norm(d, axis=1)
    d /= t[:, None]
    ray = mi.Ray3f(mi.Point3f(*[mi.Float(np.full(len(t), origin[k], np.float32)) for k in range(3)]),
                   mi.Vector3f(*[mi.Float(d[:, k].astype(np.float32)) for k in range(3)]))
    si = renderer.mi_scene.ray_intersect(ray)
    hit_t = np.array(si.t, dtype=np.float64).ravel()
    valid = np.array(si.is_valid(), dtype=bool).ravel()
    seen = valid & (hit_t >= t - VIEW_TOLERANCE_M)
    return PlateView(box, dist, float(np.mean(seen)), plate_pixels(renderer, lo, hi, box))


def plate_pixels(renderer, lo, hi, box) -> np.ndarray | None:
    """Which pixels of `box` (y0, x0, y1, x1 on the rendered grid, guard band included) show the
    plate whose world bounding box is [lo, hi] (m) at the current pose: the camera ray through
    the pixel's centre (film fractions over the rendered grid, as the light pilot's,
    render/lights.py) hits first a point inside that box grown by VIEW_TOLERANCE_M along its
    thinnest axis (the plate's normal: the plate stands 2 mm proud of its recess, whose floor
    around the plate is not the plate). Bool array of the box's shape; None without a box."""
    if box is None:
        return None
    mi = renderer.mi
    h, w = (n + 2 * renderer.guard_px for n in renderer.scene.render.resolution)
    y0, x0, y1, x1 = box
    ys, xs = np.meshgrid(np.arange(y0, y1) + 0.5, np.arange(x0, x1) + 0.5, indexing="ij")
    half = mi.Float(np.full(ys.size, 0.5, np.float32))      # mid-band wavelength, lens centre
    ray, _ = renderer.sensor.sample_ray(mi.Float(0.0), half,
                                        mi.Point2f(mi.Float((xs.ravel() / w).astype(np.float32)),
                                                   mi.Float((ys.ravel() / h).astype(np.float32))),
                                        mi.Point2f(half, half))
    si = renderer.mi_scene.ray_intersect(ray)
    p = np.array(si.p, dtype=np.float64).reshape(3, -1) if np.array(si.p).shape[0] == 3 else np.array(si.p).T
    valid = np.array(si.is_valid(), dtype=bool).ravel()
    tol = np.zeros(3)
    tol[int(np.argmin(hi - lo))] = VIEW_TOLERANCE_M
    inside = np.all((p >= (lo - tol)[:, None]) & (p <= (hi + tol)[:, None]), axis=0)
    return (valid & inside).reshape(ys.shape)


def project_box(renderer, shape) -> tuple[int, int, int, int] | None:
    """Image box (y0, x0, y1, x1), end-exclusive, of `shape`'s bounding box at the renderer's
    current pose on its rendered grid (guard band included; None: off the film): the box's
    corners projected by the camera."""
    import drjit as dr

    mi = renderer.mi
    bb = shape.bbox()
    lo, hi = np.array(bb.min).ravel(), np.array(bb.max).ravel()
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    it = dr.zeros(mi.Interaction3f, len(corners))
    it.p = mi.Point3f(corners[:, 0], corners[:, 1], corners[:, 2])
    ds, _ = renderer.sensor.sample_direction(it, mi.Point2f(0.5, 0.5))
    uv = np.array(ds.uv).reshape(2, -1) if np.array(ds.uv).shape[0] == 2 else np.array(ds.uv).T
    visible = np.array(ds.pdf).ravel() > 0
    if not np.any(visible):
        return None
    h, w = (n + 2 * renderer.guard_px for n in renderer.scene.render.resolution)
    u, v = uv[0][visible], uv[1][visible]
    x0, x1 = int(np.clip(np.floor(u.min()), 0, w)), int(np.clip(np.ceil(u.max()), 0, w))
    y0, y1 = int(np.clip(np.floor(v.min()), 0, h)), int(np.clip(np.ceil(v.max()), 0, h))
    if x1 <= x0 or y1 <= y0:
        return None
    return y0, x0, y1, x1


def plates_pilot_moments(renderer, frame) -> dict[str, float]:
    """The light-selection pilot's moments with every plate in view a region of its own beside
    the frame's (`frame`: render/lights.py pilot_moments over the film), combined by
    lights.roi_weighted_moments; the frame's alone when no plate is in view. Returns (moments,
    the nearest plate's box area in px, 0 without one: the renderer's re-selection trigger)."""
    from poevp_optics.render.lights import roi_weighted_moments

    boxes = list(renderer.roi_boxes().values())
    if not boxes:
        return frame[0], 0
    box = renderer.roi_box()
    regions = [box_pilot_moments(renderer, b) for b in boxes]
    return roi_weighted_moments([frame, *regions]), (box[2] - box[0]) * (box[3] - box[1])


def box_pilot_moments(renderer, box) -> tuple[dict[str, float], float]:
    """render/lights.py pilot_moments over the pixel box (y0, x0, y1, x1 on the rendered grid,
    guard band included) at the current pose."""
    from poevp_optics.render.lights import pilot_moments

    h, w = (n + 2 * renderer.guard_px for n in renderer.scene.render.resolution)
    y0, x0, y1, x1 = box
    return pilot_moments(renderer.mi, renderer.mi_scene, renderer.sensor, renderer.scene.render.seed,
                         (x0 / w, y0 / h, x1 / w, y1 / h))


def own_light_weights(renderer, label: str, box) -> dict[str, float] | None:
    """The emitters' sampling weights for the ROI `label`'s own box renders under a light
    selection with `roi_own` (render/lights.py `power_roi`): p_i ~ sqrt(E[f_i^2]) from the pilot
    over `box` alone (y0, x0, y1, x1 on the rendered grid), at least ROI_FLOOR x the largest. Kept
    per label until the frame's selection changes (Renderer.select_lights: a new pose's pilot);
    None for any other selection."""
    from poevp_optics.render.lights import LIGHT_SELECTIONS, ROI_FLOOR, weights_from_moments

    if not LIGHT_SELECTIONS[renderer.scene.render.light_selection].roi_own or renderer.light_weights is None:
        return None
    selection, cache = renderer.__dict__.get("_own_weights", (None, {}))
    if selection is not renderer.light_weights:             # the frame re-selected: a new pose
        cache = {}
        renderer.__dict__["_own_weights"] = (renderer.light_weights, cache)
    if label not in cache:
        weights = weights_from_moments(box_pilot_moments(renderer, box)[0])
        cache[label] = {k: max(weights.get(k, 1.0), ROI_FLOOR) for k in renderer.light_weights}
    return cache[label]
