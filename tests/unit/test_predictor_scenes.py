"""benchmarks/predictor_scenes.py: the switched-pixel score in closed form, the scoring loop on a
hand-made moving square, the library scenes apart from every shipped predictor's training data,
and one small render of a library scene through the camera's LDR twin."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks.predictor_scenes import scene_frames, score, summary, tables
from benchmarks.scene_library import LIBRARY
from poevp_optics.analysis.prediction_metrics import switched_right


def _square(x0, shape=(32, 64), size=8):
    img = np.full(shape, 20.0, np.float32)
    if x0 is not None:
        img[12:12 + size, x0:x0 + size] = 255.0
    return img


def test_switched_pixels_in_closed_form():
    """An 8x8 clipped square moving 4 px: 2 x 8 x 4 = 64 pixels switch. The exact prediction
    gets all right, `hold` none, a prediction 2 px short half (the 16 + 16 pixels between),
    one that lost the square the 32 that went out; nothing switched: NaN."""
    prev, truth = _square(10), _square(14)
    assert switched_right(truth, prev, truth) == 1.0
    assert switched_right(prev, prev, truth) == 0.0
    assert switched_right(_square(12), prev, truth) == pytest.approx(0.5)
    assert switched_right(_square(None), prev, truth) == pytest.approx(0.5)
    assert np.isnan(switched_right(truth, truth, truth))


class _Shift:
    """A predictor that moves the newest frame by `dx` px (a constant-velocity model)."""

    def __init__(self, dx):
        self.dx = dx

    def __call__(self, hist):
        return np.roll(hist[-1], self.dx, axis=1)


def test_scoring_a_square_moving_at_constant_speed():
    """A square moving 3 px a frame: the 3 px shift scores 1 everywhere; hold scores the IoU of
    two 8x8 squares 3 px apart, 40 / 88, undimmed 24 / 64 and switched 0; the page's tables
    name the best predictors."""
    frames = np.stack([_square(4 + 3 * t) for t in range(9)]).astype(np.uint8)
    rows, seconds = score(frames, {"hold": lambda h: h[-1], "shift": _Shift(3)}, "square")
    assert len(rows) == 2 * (9 - 4) and len(seconds["hold"]) == 5
    s = summary(rows, ["square"], ["hold", "shift"])
    assert s["shift"]["all"]["iou"]["mean"] == 1.0 and s["shift"]["all"]["switched"]["worst"] == 1.0
    assert s["hold"]["square"]["iou"]["mean"] == pytest.approx(40 / 88)
    assert s["hold"]["square"]["undimmed"]["mean"] == pytest.approx(24 / 64)
    assert s["hold"]["square"]["switched"]["mean"] == 0.0
    page = tables(s, ["square"], ["hold", "shift"])
    assert "highest mean IoU `shift`" in page and "lowest undimmed fraction `shift`" in page


def test_library_scenes_are_not_in_any_shipped_predictors_training():
    """Every shipped predictor's record names where its training data came from, and no library
    scene is among them (the benchmark's claim that these scenes are unseen)."""
    from poevp_optics.control.predictors.track_net import default_weights, read_track_net
    from poevp_optics.core.paths import ASSETS_DIR

    sources = {n: json.loads((ASSETS_DIR / "predictor" / f"{n}.json").read_text())["dataset"]["source"]
               for n in ("dmvfn", "dmvfn_lite")}
    _, _, meta = read_track_net(default_weights())
    sources["track_net"] = meta["command"]
    assert "highbeam_plate" in sources["dmvfn"] and "highbeam_plate" in sources["dmvfn_lite"]
    assert "train_track" in sources["track_net"]                 # analysis/motion_paths.py's paths
    for name, src in sources.items():
        assert not [s for s in LIBRARY if s in src], f"{name} was trained on {src}"


def test_ldr_twin_of_a_library_scene_saturates_more_under_brighter_beams():
    """night_road at 1/12 of its mirrors: 8-bit frames of the scaled size, and our beams x 10
    saturate more pixels and raise the mean signal in every frame (what our beams light gets
    brighter, the other lamps stay as they are)."""
    one, _ = scene_frames("night_road", 1 / 12, 1.0, frames=5)
    ten, _ = scene_frames("night_road", 1 / 12, 10.0, frames=5)
    assert one.shape == ten.shape == (5, 90, 160) and one.dtype == np.uint8
    sat1, sat10 = (one >= 255).sum(axis=(1, 2)), (ten >= 255).sum(axis=(1, 2))
    assert np.all(sat10 > sat1) and np.all(ten.mean(axis=(1, 2)) > one.mean(axis=(1, 2)))
