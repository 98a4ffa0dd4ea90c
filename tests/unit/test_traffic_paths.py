"""The held-out traffic benchmark cannot be memorised from the training data: its generator's
shapes lie outside the training ranges, and none of its displacement chains (with the next step,
normalised by speed, turned and mirrored to one heading: what the rotation-invariant model sees)
is a training chain.

"Equal" is within `EQUAL` (0.1 % of the speed, Chebyshev over the eight numbers): the fixed-shape
generator the model used to be trained on gave its benchmark chains that were training chains to
1e-12 (`test_the_check_finds_the_fixed_shape_benchmark_in_its_training_set`, the check's power).
Chains that constant velocity or constant acceleration continue to within `GENERIC` (1 % of the
speed) are left out: straight lines and steady accelerations are in every generator and hold
nothing to memorise; the chains checked are those whose next step is an event."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from poevp_optics.analysis import traffic_paths as tp
from poevp_optics.analysis.motion_paths import KINDS, TRAINING_SHAPES, PathSpec, centres

EQUAL = 1e-3
GENERIC = 1e-2
TRAIN_PATHS = 1200                      # the shipped model's train split (apps/train/train_track.py)


def chains(track: np.ndarray) -> np.ndarray:
    """(M, 8) normalised chains (d_t, d_{t-1}, d_{t-2}, d_{t+1}) of a (T, 2) track: divided by
    the largest of the three measured lengths (>= 1 px, else left out), turned so d_t (or the
    longest) points along +x and mirrored so the first non-zero y after it is >= 0; chains that
    constant velocity or constant acceleration continue within GENERIC are left out."""
    d = np.diff(np.asarray(track, np.float64), axis=0)
    out = []
    for t in range(2, len(d) - 1):
        c = np.stack([d[t], d[t - 1], d[t - 2], d[t + 1]])
        s = np.linalg.norm(c[:3], axis=1).max()
        if s < 1.0:
            continue
        c = c / s
        if min(np.abs(c[3] - c[0]).max(), np.abs(c[3] - (2 * c[0] - c[1])).max()) <= GENERIC:
            continue
        ref = c[np.argmax(np.linalg.norm(c[:3], axis=1))] if np.linalg.norm(c[0]) < 0.1 else c[0]
        a = np.arctan2(ref[1], ref[0])
        rot = np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])
        c = c @ rot.T
        ys = c[:, 1][np.abs(c[:, 1]) > 1e-9]
        if ys.size and ys[0] < 0:
            c[:, 1] = -c[:, 1]
        out.append(c.ravel())
    return np.asarray(out).reshape(-1, 8)


def training_chains(fixed_shapes: bool = False) -> np.ndarray:
    """Chains of the train split's paths (apps/train/train_track.py `random_path`, its seeds,
    10 frames); fixed_shapes: each path with motion_paths' default shapes (the generator the
    model used to be trained on: only kind, speed, heading and turn drawn)."""
    from poevp_optics.apps.train.train_track import SPLIT_SEEDS, random_path

    out = []
    for i in range(TRAIN_PATHS):
        path, _ = random_path(np.random.default_rng(SPLIT_SEEDS["train"] + i), 10)
        if fixed_shapes:
            path = PathSpec(path.kind, path.speed_px, path.heading_deg, path.frames, path.turn_rad)
        out.append(chains(centres(path, np.arange(path.frames))))
    return np.concatenate(out)


def nearest(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Chebyshev distance of each row of `a` to its nearest row of `b`."""
    return cKDTree(b).query(a, p=np.inf)[0]


def test_benchmark_shapes_lie_outside_the_training_ranges():
    assert tp.check_disjoint(TRAINING_SHAPES) == []
    overlapping = {**TRAINING_SHAPES, "width_frames": (3.0, 12.5)}
    assert tp.check_disjoint(overlapping) and "width_frames" in tp.check_disjoint(overlapping)[0]


def test_no_benchmark_chain_is_a_training_chain():
    """Every light of every benchmark scene (the cases benchmarks/predictor_traffic.py scores):
    no informative chain within EQUAL of a training chain."""
    train = training_chains()
    bench = []
    for family, v, seed in tp.bench_cases():
        scene = tp.draw_scene(family, v, seed, rendered=False)
        bench += [chains(tr) for tr in tp.light_tracks(scene)]
    bench = np.concatenate(bench)
    assert len(bench) > 500 and len(train) > 2000
    dist = nearest(bench, train)
    assert dist.min() > EQUAL, f"{int((dist <= EQUAL).sum())} benchmark chains are training chains"


def test_the_check_finds_the_fixed_shape_benchmark_in_its_training_set():
    """The motion_paths benchmark with its fixed shapes (reversal, swerve, lane change at 4-48
    px/frame, four headings) against training drawn with those fixed shapes: its chains are
    training chains (what made that benchmark memorisable)."""
    train = training_chains(fixed_shapes=True)
    bench = np.concatenate([chains(centres(PathSpec(k, float(v), h, 8), np.arange(8)))
                            for k in ("reversal", "swerve", "lane_change") for v in (4, 8, 16, 24, 32, 48)
                            for h in (0.0, 90.0, 180.0, 270.0)])
    assert len(bench) > 50
    assert np.mean(nearest(bench, train) <= EQUAL) > 0.9
    assert set(KINDS) >= {"reversal", "swerve", "lane_change"}


def test_scenes_hold_several_lights_and_every_family():
    """Each family draws several lights per frame (the main vehicle's lamps and plate, standing
    lights), the approach grows and the shake moves every light together."""
    for i, family in enumerate(tp.FAMILIES):
        scene = tp.draw_scene(family, 24.0, tp.BENCH_SEED + i, rendered=False)
        assert len(tp.light_tracks(scene)) >= 9
    grow = tp.draw_scene("approach", 16.0, tp.BENCH_SEED, rendered=False)
    g = grow.draws["growth_per_frame"]
    np.testing.assert_allclose(grow.vehicles[0].scale[1:] / grow.vehicles[0].scale[:-1], g)
    shake = tp.draw_scene("shake", 16.0, tp.BENCH_SEED, rendered=False)
    still = tp.light_tracks(shake)[-1]                      # the parked car's plate: only the camera moves it
    np.testing.assert_allclose(still - still[0], shake.global_px - shake.global_px[0], atol=1e-9)
    with pytest.raises(ValueError, match="traffic family"):
        tp.draw_scene("teleport", 8.0, 1)
