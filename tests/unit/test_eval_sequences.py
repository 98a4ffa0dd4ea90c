"""Test sequences of `poevp evaluate`: the plate moves at the asked image speed along each motion
kind (plate boxes from the scene's geometry, no rendering), and the test set is held apart from
the predictor's training set."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.apps.evaluate.eval_sequences import (SequenceSpec, calibrate, eval_overrides, node_times, nodes_for_speed,
                                             poses, with_poses)
from poevp_optics.apps.evaluate.evaluate import TEXTS, EvalConfig, check_config
from poevp_optics.apps.train.training_data import random_plate_text
from poevp_optics.analysis.recognition import normalise
from poevp_optics.camera.camera import Camera
from poevp_optics.core.exceptions import UserError
from poevp_optics.render.renderer import Renderer
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES


@pytest.fixture(scope="module")
def setup():
    spec = load_scene(SCENES / "highbeam_plate", eval_overrides((184, 320), 4, 8, "KA 7391"))
    cam = Camera.from_params(spec.resolved.camera)
    return spec, cam, calibrate(spec, cam.guard_px)


def _boxes(spec, cam, seq, cal):
    """Plate box at the start of each frame's exposure (Renderer.roi_box at the keyframed poses)."""
    t = node_times(spec, seq.frames)[:, 0]
    r = Renderer(with_poses(spec, np.arange(len(t), dtype=float), poses(seq, cal, spec.timing.fps, t)).resolved.render,
                 guard_px=cam.guard_px)
    out = []
    for i in range(len(t)):
        r.set_time(float(i))
        out.append(r.roi_box())
    return np.array(out, dtype=float)


def test_calibration_matches_the_pinhole_geometry(setup):
    """The XML camera: fov 10 deg across 320 px, plate 0.52 m wide at 14 m (scene.xml): f =
    160 / tan(5 deg) = 1829 px, so 1829 / 14 = 131 px per m across; the plate's box measures the
    range to +-1 px of its width (~68 px), i.e. +-1.5 %, +-0.2 m plus the box's bevel."""
    spec, cam, cal = setup
    f_px = 160 / np.tan(np.radians(5))
    assert abs(abs(cal.px_per_m) - f_px / 14.0) < 0.02 * f_px / 14.0
    assert 12.5 < cal.range_m < 14.5


@pytest.mark.parametrize("v", [4.0, 16.0, 40.0])
def test_lateral_speed_is_the_asked_pixels_per_frame(setup, v):
    """Box edges are integers (floor/ceil), so each step is v to +-1 px; the median is within 1 px."""
    spec, cam, cal = setup
    b = _boxes(spec, cam, SequenceSpec("KA 7391", "lateral", v, 6, 1), cal)
    assert abs(np.median(np.diff(b[:, 1])) - v) <= 1.0
    assert np.all(np.abs(np.diff(b[:, 0])) <= 1)                     # no vertical motion


def test_reversal_turns_and_approach_grows(setup):
    spec, cam, cal = setup
    b = _boxes(spec, cam, SequenceSpec("KA 7391", "reversal", 12.0, 8, 1, change=4), cal)
    dx = np.diff(b[:, 1])
    # +12 px/frame until frame 4, turning over two frames (mean -6 in the second), then -12
    assert np.all(dx[:4] > 10) and abs(dx[5] + 6) <= 1 and dx[6] < -10
    w = _boxes(spec, cam, SequenceSpec("KA 7391", "approaching", 4.0, 8, 1), cal)
    width = w[:, 3] - w[:, 1]
    # 12 m/s closing from ~14.6 m over 7 frames (2.8 m): the width grows by ~1.2x
    assert width[-1] / width[0] > 1.12
    r = _boxes(spec, cam, SequenceSpec("KA 7391", "receding", 4.0, 8, 1), cal)
    assert (r[-1, 3] - r[-1, 1]) < (r[0, 3] - r[0, 1])


def test_test_texts_are_not_training_texts():
    """Training texts (apps/train/training_data.random_plate_text) are 2 letters, a digit and 4 more:
    7 characters; every test text has 6, so none can be a training text."""
    rng = np.random.default_rng(0)
    train = {normalise(random_plate_text(rng)) for _ in range(2000)}
    assert {len(t) for t in train} == {7}
    assert all(len(normalise(t)) == 6 for t in TEXTS)
    assert not train & {normalise(t) for t in TEXTS}


def test_bad_configurations_name_the_flag():
    for bad, flag in ((dict(kinds=("sideways",)), "--kinds"), (dict(predictors=("magic",)), "--predictors"),
                      (dict(texts=()), "--texts"), (dict(speeds_px=(0,)), "--speeds"), (dict(search="sky"), "--search")):
        with pytest.raises(UserError, match=flag):
            check_config(EvalConfig(**bad))


@pytest.mark.parametrize("speed", [4.0, 16.0, 32.0, 48.0])
def test_nodes_keep_the_plate_within_half_a_pixel_between_samples(setup, speed):
    """A fast plate is sampled densely enough within its 2 ms exposure that the node sum is a
    blur, not separate sharp copies: image displacement between consecutive nodes <= 0.5 px
    (closed form: speed x 2 ms x fps / (K - 1)), and K is the smallest such count (>= 2)."""
    spec, _, cal = setup
    seq = SequenceSpec("KA 7391", "lateral", speed, 3, 1)
    k = nodes_for_speed(speed, spec.timing.fps)
    times = node_times(spec, seq.frames, k)
    x_px = poses(seq, cal, spec.timing.fps, times.ravel())[:, 0].reshape(times.shape) * cal.px_per_m
    step = np.abs(np.diff(x_px, axis=1)).max()
    blur = speed * 0.002 * spec.timing.fps
    assert step == pytest.approx(blur / (k - 1), rel=1e-6)
    assert step <= 0.5 + 1e-9
    assert k == 2 or blur / (k - 2) > 0.5
