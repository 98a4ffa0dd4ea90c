"""The ground truth of each frame: radiance samples over the exposure and their time average.

A static scene is rendered once and reused for every frame (K = 1 is exact). Static geometry
with PWM lamps renders each emitter group once (the scene without the flickering lamps, and each
lamp alone) and hands the camera those images as a `basis`, whose exposures it integrates exactly
against the lamps' drive: no time samples. A moving scene is sampled at the frame's radiance
nodes (`RenderScene.subframe_times_s`: K uniform nodes with both ends, joined by the DMD's switching
times); its time average uses the nodes' hat-function weights. Monte Carlo error: every sample
is split into `mc_splits` independent-seed renders (renderer.py).
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from poevp_optics.core.frame import RenderedExposure
from poevp_optics.core.seeds import render_seeds
from poevp_optics.render.progressive import Replicates, Target, max_box_error, rel_error, render_to_target

__all__ = ["RenderedExposure", "rel_error", "render_exposures", "render_sample", "flicker_bases"]


def union_box(a, b):
    """The smallest box holding boxes a and b (None: no box)."""
    if a is None:
        return b
    if b is None:
        return a
    return (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


def render_sample(scene, renderer, frame: int, sample: int, rel_target: float = 0.0,
                  reps: Replicates | None = None):
    """One radiance sample at the renderer's pose: (mean, variance of the mean, spp used, target
    met or None, replicates or None). rel_target 0: `render.spp` in `mc_splits` renders."""
    acc = scene.accuracy
    if not rel_target > 0:
        m, v = renderer.render_with_error(render_seeds(scene.render.seed, frame, sample, acc.mc_splits), acc.spp)
        used = renderer.last_used_spp
        if scene.render.roi_spp > 0:
            m, v = add_roi_samples(scene, renderer, frame, sample, m, v, used)
        return m, v, used, None, None
    target = Target(rel_target, acc.max_spp, renderer.roi_box(),
                    tuple(renderer.roi_boxes().values()) if renderer.multi_roi else ())
    reps, met = render_to_target(renderer, lambda n: render_seeds(scene.render.seed, frame, sample, n),
                                 acc.spp, acc.mc_splits, target, reps)
    return reps.mean.astype(np.float32), reps.variance_of_mean(), reps.spp, met, reps


#: render_seeds' sample index offset of the ROI box renders (apart from every frame sample's).
ROI_STREAM = 1 << 20
#: Pixels added around the ROI shape's projected box (its bounding box is conservative already).
ROI_MARGIN_PX = 1


def add_roi_samples(scene, renderer, frame: int, sample: int, mean, var, spp: int):
    """`render.roi_spp` more samples per pixel over each ROI's box at the current pose
    (Renderer.roi_boxes: the ROI shape, or every plate in view; Renderer.render_box, own seeds
    per ROI), pooled with the frame's `spp` there (render/roi.py pool_samples; where two boxes
    overlap the second pools with the count the first left). The frame's pixels elsewhere keep
    `spp`: the effort goes where the error target is. With `render.light_selection = "power_roi"`
    each box's renders pick the emitters by its own pilot (render/roi.py own_light_weights) and
    the box's pixels take those renders alone: the frame's samples there drew the emitters by the
    frame's weights and, pooled by count, would dominate the variance (wet_night_road's plate: a
    relative error of 1.25 per frame sample against 0.19 per box sample). Returns (mean, var)."""
    boxes = renderer.roi_boxes()
    if not boxes:
        return mean, var
    from poevp_optics.render.lights import LIGHT_SELECTIONS, set_sampling_weights
    from poevp_optics.render.roi import own_light_weights, pool_samples

    order = [t.label for t in renderer.roi_labels]
    h, w = mean.shape
    mean = mean.astype(np.float64).copy()
    var = np.asarray(var, dtype=np.float64).copy()
    count = np.full(mean.shape, float(spp))
    boxes = {label: (max(0, y0 - ROI_MARGIN_PX), max(0, x0 - ROI_MARGIN_PX), min(h, y1 + ROI_MARGIN_PX),
                     min(w, x1 + ROI_MARGIN_PX)) for label, (y0, x0, y1, x1) in boxes.items()}
    if LIGHT_SELECTIONS[scene.render.light_selection].roi_own:
        for y0, x0, y1, x1 in boxes.values():        # the frame's samples there drew other lamps
            count[y0:y1, x0:x1] = 0.0
    swapped = False
    for label, box in boxes.items():
        k = order.index(label)           # the plate's own stream: the first ROI keeps ROI_STREAM's
        seeds = render_seeds(scene.render.seed, frame, ROI_STREAM * (k + 1) + sample, scene.accuracy.mc_splits)
        own = own_light_weights(renderer, label, box)      # light_selection "power_roi": the ROI's own
        if own is not None:
            set_sampling_weights(renderer.params, own)
            swapped = True
        m2, v2, n2 = renderer.render_box_with_error(seeds, scene.render.roi_spp, box)
        pool_samples(mean, var, count, box, m2, v2, n2)
    if swapped:                                      # the frame's own weights back for its next render
        set_sampling_weights(renderer.params, renderer.light_weights)
    return mean.astype(np.float32), var


class PlateTrack:
    """Per ROI label over one exposure's poses: the union of its in-view boxes, its distances
    (m) and visible fractions at each pose (render/roi.py PlateView); `records` gives each
    plate's entry of RenderedExposure.plates with its own MC error."""

    def __init__(self, renderer):
        self.renderer = renderer
        self.targets = renderer.roi_labels if renderer.multi_roi else ()
        self.boxes = {t.label: None for t in self.targets}
        self.dist = {t.label: [] for t in self.targets}
        self.seen = {t.label: [] for t in self.targets}
        self.pixels = {t.label: [] for t in self.targets}

    def add_pose(self) -> None:
        """Record the renderer's current pose."""
        if not self.targets:
            return
        for label, v in self.renderer.plate_views().items():
            self.dist[label].append(v.distance_m)
            self.seen[label].append(v.visible_fraction if v.box is not None else 0.0)
            if v.in_view:
                self.boxes[label] = union_box(self.boxes[label], v.box)
                if v.pixels is not None:
                    self.pixels[label].append((v.box, v.pixels))

    def seen_pixels(self, label: str, box) -> np.ndarray | None:
        """The pixels of the union `box` that show the plate at any pose (render/roi.py
        PlateView.pixels), bool of the box's shape; None out of view."""
        if box is None or not self.pixels[label]:
            return None
        y0, x0, y1, x1 = box
        seen = np.zeros((y1 - y0, x1 - x0), bool)
        for (by0, bx0, by1, bx1), px in self.pixels[label]:
            seen[by0 - y0:by1 - y0, bx0 - x0:bx1 - x0] |= px
        return seen

    def records(self, mean, var) -> tuple:
        """({id, text, shape, box, distance_m, visible_fraction, seen, rel_error}, ...) in the
        scene's order: distance and visible fraction averaged over the poses; seen, the box's
        pixels showing the plate at any pose (`seen_pixels`), one string of '0'/'1' per row (a
        stored render keeps it as text); rel_error (progressive.rel_error) over those pixels of
        the plate's box; box, seen and rel_error None out of view."""
        out = []
        for t in self.targets:
            box = self.boxes[t.label]
            seen = self.seen_pixels(t.label, box)
            out.append({"id": t.label, "text": t.text, "shape": t.shape_id, "box": box,
                        "distance_m": float(np.mean(self.dist[t.label])),
                        "visible_fraction": float(np.mean(self.seen[t.label])),
                        "seen": None if seen is None else tuple("".join("1" if v else "0" for v in row) for row in seen),
                        "rel_error": rel_error(mean, var, box, seen) if box is not None else None})
        return tuple(out)


def flicker_bases(scene, renderer):
    """Static geometry with PWM lamps: the image without the flickering lamps and one image per
    flickering lamp (radiance is linear in each lamp's drive), each rendered once (to the
    target, when one is set). Returns ({name: (mean, var, spp, met)}, roi)."""
    from poevp_optics.render.renderer import Renderer

    emissive = {n for n, e in scene.spectra.items() if e.kind != "reflectance"}
    groups = [("rest", frozenset(scene.flicker))] + [(p, frozenset(emissive - {p})) for p in scene.flicker]
    out = {}
    for j, (name, zero) in enumerate(groups):
        r = Renderer(scene, zero_params=zero, guard_px=renderer.guard_px)
        out[name] = render_sample(scene, r, 0, 1000 + j, scene.accuracy.target_rel_error)[:4]
        renderer.stats.calls += r.stats.calls
        renderer.stats.seconds += r.stats.seconds
    return out, renderer.roi_box()


def _exposure(i, t0, t1, times, subs, mean, var, roi, track: PlateTrack | None = None, **extra) -> RenderedExposure:
    if track is not None and track.targets:
        extra["plates"] = track.records(mean, var)
    return RenderedExposure.build(i, t0, t1, times, subs, mean, var, roi, rel_error(mean, var),
                                  rel_error(mean, var, roi), **extra)


def _met(flags) -> bool | None:
    flags = [f for f in flags if f is not None]
    return all(flags) if flags else None


def _lamp_exposure(scene, i, t0, t1, bases, roi, track=None):
    from poevp_optics.sources.flicker import drive_mean

    rest_m, rest_v = bases["rest"][:2]
    mean, var = rest_m.astype(np.float64), rest_v.astype(np.float64)
    for p, fl in scene.flicker.items():
        d = float(drive_mean(np.array([t0]), np.array([t1]), fl)[0])
        mean, var = mean + d * bases[p][0], var + d * d * bases[p][1]
    names = ("rest", *scene.flicker)
    subs = tuple(bases[n][0] for n in names)
    return _exposure(i, t0, t1, np.array([(t0 + t1) / 2]), subs, mean.astype(np.float32), var, roi, track,
                     basis=names, spp=tuple(bases[n][2] for n in names), target_met=_met(bases[n][3] for n in names))


def _combine(samples, weights):
    """Time average and its MC variance of the samples [(mean, var, ...)] with `weights`."""
    mean = sum(w * s[0].astype(np.float64) for w, s in zip(weights, samples))
    var = sum(w * w * s[1] for w, s in zip(weights, samples))
    return mean, var


def _moving_exposure(scene, renderer, i, t0, t1):
    times = scene.subframe_times_s(i)
    weights = scene.subframe_weights(i)              # time average of the piecewise-linear L(t)
    target = scene.accuracy.target_rel_error
    share = target / float(np.sqrt(np.sum(weights ** 2))) if target > 0 else 0.0
    samples, roi = [], None
    track = PlateTrack(renderer)
    for k, t in enumerate(times):
        renderer.set_time(float(t))
        samples.append(render_sample(scene, renderer, i, k, share))
        roi = union_box(roi, renderer.roi_box())
        track.add_pose()
    mean, var = _combine(samples, weights)

    def frame_error(mean, var):          # every plate in view is held to the target: the worst decides
        if track.targets:
            return max_box_error(mean, var, [b for b in track.boxes.values() if b is not None] or [roi])
        return rel_error(mean, var, roi)

    for _ in range(3):                              # tighten while the frame misses the target
        err = frame_error(mean, var)
        if not target > 0 or err is None or err <= target or all(s[3] is False for s in samples):
            break
        share *= target / err
        for k, t in enumerate(times):
            renderer.set_time(float(t))
            samples[k] = render_sample(scene, renderer, i, k, share, samples[k][4])
        mean, var = _combine(samples, weights)
    met = None if not target > 0 else bool(frame_error(mean, var) is not None and frame_error(mean, var) <= target)
    return _exposure(i, t0, t1, times, tuple(s[0] for s in samples), mean.astype(np.float32), var, roi, track,
                     subframe_variances=tuple(s[1] for s in samples), spp=tuple(s[2] for s in samples),
                     target_met=met, subframe_weights=tuple(float(w) for w in weights))


def render_exposures(scene, renderer, progress: bool = True):
    """Yield a `RenderedExposure` per frame (module docstring)."""
    acc = scene.accuracy
    static = bases = None
    track = PlateTrack(renderer)         # static geometry: the plates' one pose
    for i in tqdm(range(scene.timing.frames), desc=f"render {scene.name}", unit="frame",
                  disable=not progress or None, leave=False):
        t0, t1 = scene.exposure_window_s(i)
        if scene.is_static:
            if static is None:
                static = (*render_sample(scene, renderer, 0, 0, acc.target_rel_error)[:4], renderer.roi_box())
                track.add_pose()
            mean, var, spp, met, roi = static
            yield _exposure(i, t0, t1, np.array([(t0 + t1) / 2]), (mean,), mean, var, roi, track,
                            spp=(spp,), target_met=met)
        elif scene.geometry_static:                   # flickering lamps, nothing moves
            if bases is None:
                bases, roi0 = flicker_bases(scene, renderer)
                track.add_pose()
            yield _lamp_exposure(scene, i, t0, t1, bases, roi0, track)
        else:
            yield _moving_exposure(scene, renderer, i, t0, t1)
