"""Region trackers (`track`, `track_net`), the clip marker through every predictor and loop mode,
and `dmvfn` without shipped weights (issue 26)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from poevp_optics.analysis.motion_paths import PathSpec, centres, render_sequence, saturated_centroid
from poevp_optics.control.loop_step import CLIP_MARKER, resize_keeping_clip
from poevp_optics.control.predictors import make_predictor
from poevp_optics.control.predictors.dmvfn import WeightsError
from poevp_optics.control.predictors.track import closed_form_displacement, region_tracks
from poevp_optics.control.predictors.track_net import TrackNetPredictor, default_weights, read_track_net
from poevp_optics.control.predictors.track_net_model import TrackNet, load_track_net, numpy_layers, save_track_net


def test_closed_forms_of_the_extrapolation():
    # constant velocity, constant acceleration (Newton forward difference), least-squares quadratic
    np.testing.assert_allclose(closed_form_displacement([(3.0, -1.0)]), (3.0, -1.0))
    np.testing.assert_allclose(closed_form_displacement([(12.0, 0.0), (10.0, 0.0)]), (14.0, 0.0))
    # positions of a quadratic x(u) = 10 u + u^2 at u = -3..0: displacements (newest first) 9, 7, 5;
    # the least-squares quadratic is exact: next displacement x(1) - x(0) = 11
    np.testing.assert_allclose(closed_form_displacement([(9.0, 0), (7.0, 0), (5.0, 0)]), (11.0, 0.0), atol=1e-12)
    # a reversal (change larger than the speed) is not read as acceleration: last displacement
    np.testing.assert_allclose(closed_form_displacement([(-10.0, 0.0), (10.0, 0.0)]), (-10.0, 0.0))


def test_measured_chain_is_the_path():
    """The tracker follows a region back three frames: its displacements equal the path's
    (sub-pixel phase correlation of the outlines; tolerance 0.6 px: the rounded, clipped edges)."""
    path = PathSpec("accelerating", 12.0, 30.0, frames=5)
    seq = render_sequence(path, (184, 320), seed=3)
    tracks, labels = region_tracks(list(seq.frames[:4]))
    plate = next(t for t in tracks if labels[int(seq.centre_px[3, 1]), int(seq.centre_px[3, 0])] == t.label)
    truth = np.diff(seq.centre_px[:4], axis=0)[::-1]              # d_t, d_{t-1}, d_{t-2}
    assert len(plate.displacements) == 3
    np.testing.assert_allclose(np.asarray(plate.displacements), truth, atol=0.6)


@pytest.mark.parametrize("kind", ["curved", "accelerating", "braking"])
def test_track_beats_constant_velocity_on_changing_motion(kind):
    """Where the velocity changes, constant acceleration over the chain is closer than `flow`'s
    constant velocity: flow's error is the change of displacement per frame (>= 2 px here)."""
    seq = render_sequence(PathSpec(kind, 32.0, 200.0, frames=6, turn_rad=0.15), (368, 640), seed=5)
    errs = {}
    for name in ("flow", "track"):
        p = make_predictor(name)
        pred = p(list(seq.frames[1:5]))
        got = saturated_centroid(pred, seq.centre_px[5], radius=150)
        errs[name] = float(np.hypot(*(got - saturated_centroid(seq.frames[5], seq.centre_px[5]))))
    step_change = float(np.hypot(*np.diff(np.diff(seq.centre_px[3:6], axis=0), axis=0)[0]))
    assert step_change > 2.0
    assert errs["track"] < errs["flow"] / 1.5, errs


def test_track_net_has_no_preferred_direction():
    """Rotating or mirroring every displacement of the chains rotates or mirrors the prediction
    (invariant features, coefficients on the displacements): exact to float32 rounding."""
    torch.manual_seed(0)
    net = TrackNet()
    for p in net.parameters():
        torch.nn.init.normal_(p, std=0.3)                   # a non-trivial network
    disp = torch.randn(64, 3, 2) * 20
    valid = (torch.rand(64, 3) > 0.2).float()
    valid[:, 0] = 1
    resp = torch.rand(64, 3)
    out = net(disp, valid, resp)
    for m in (torch.tensor([[0.0, -1.0], [1.0, 0.0]]), torch.tensor([[-1.0, 0.0], [0.0, 1.0]]),
              torch.tensor([[0.6, -0.8], [0.8, 0.6]])):
        np.testing.assert_allclose(net(disp @ m.T, valid, resp).detach(), (out @ m.T).detach(), atol=1e-3)


def test_track_net_weights_round_trip_and_errors(tmp_path):
    net = TrackNet()
    path = tmp_path / "t.safetensors"
    save_track_net(net, path, {"note": "x"})
    loaded, meta = load_track_net(path)
    assert meta["note"] == "x"
    for (k, v), (_, w) in zip(net.state_dict().items(), loaded.state_dict().items()):
        assert torch.equal(v, w), k
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(path.read_bytes()[:100])
    with pytest.raises(WeightsError, match="not a readable safetensors"):
        load_track_net(bad)
    with pytest.raises(WeightsError, match="not found"):
        load_track_net(tmp_path / "none.safetensors")


def test_shipped_track_net_weights_load_with_their_record():
    model, meta = load_track_net(default_weights())
    assert {"command", "data", "split", "budget", "test"} <= set(meta)
    layers, _, record = read_track_net(default_weights())
    assert record == meta
    for (w, b), (tw, tb) in zip(layers, numpy_layers(model)):
        np.testing.assert_array_equal(w, tw)
        np.testing.assert_array_equal(b, tb)
    pred = TrackNetPredictor(layers, default_weights(), meta)
    d = pred.describe()
    assert d["weights"] == "assets/predictor/track_net.safetensors" and len(d["weights_sha256"]) == 16


def test_track_net_weights_read_without_torch_refuse_a_wrong_shape(tmp_path):
    """The loop's reader (NumPy) refuses weights of another shape, NaN weights and a cut file in
    one line naming the file, like the torch reader."""
    net = TrackNet()
    path = tmp_path / "t.safetensors"
    save_track_net(net, path, {"note": "x"})
    layers, cfg, meta = read_track_net(path)
    assert meta == {"note": "x"} and cfg == net.cfg and [w.shape for w, _ in layers] == [(64, 15), (64, 64), (3, 64)]
    from poevp_optics.control.predictors.track_net import TrackNetConfig
    from poevp_optics.control.predictors.track_net_model import TrackNet as Net

    other = tmp_path / "other.safetensors"
    save_track_net(Net(TrackNetConfig(hidden=32)), other, {})
    raw = other.read_bytes().replace(b'\\"hidden\\": 32', b'\\"hidden\\": 64')
    assert raw != other.read_bytes()
    other.write_bytes(raw)
    with pytest.raises(WeightsError, match=f"{other.name}: weights do not match the model: net.0.bias"):
        read_track_net(other)
    with torch.no_grad():
        net.net[2].weight[3, 4] = float("nan")
    save_track_net(net, path, {})
    with pytest.raises(WeightsError, match="NaN or Inf \\(1 of 4096 values of net.2.weight\\)"):
        read_track_net(path)
    path.write_bytes(path.read_bytes()[:100])
    with pytest.raises(WeightsError, match="not a readable safetensors"):
        read_track_net(path)


def test_the_loop_predicts_with_track_net_without_torch():
    """A run with `track_net` (the default scene's predictor) loads its weights, predicts and
    computes its mask without importing torch (1.7-3 s a process)."""
    import subprocess
    import sys

    code = ("import sys, numpy as np\n"
            "from poevp_optics.control.predictors import make_predictor\n"
            "from poevp_optics.control.masks import target_levels\n"
            "p = make_predictor('track_net')\n"
            "f = [np.zeros((64, 96), np.float32) for _ in range(4)]\n"
            "for i, x in enumerate(f): x[20:30, 10 + 5 * i:20 + 5 * i] = 255.0\n"
            "out = p(f)\n"
            "lv = target_levels(out * 40.0, 1e4, 0.5, np.linspace(0.01, 1.0, 8))\n"
            "assert out[20:30, 30:40].min() == 255.0 and lv.shape == out.shape, (out.max(), lv.shape)\n"
            "print(p.describe()['parameters'], 'torch' in sys.modules)\n")
    got = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert got.returncode == 0, got.stderr
    n_params = (15 * 64 + 64) + (64 * 64 + 64) + (64 * 3 + 3)        # MLP 15 -> 64 -> 64 -> 3
    assert got.stdout.split() == [str(n_params), "False"], got.stdout


def test_dmvfn_without_weights_refuses_in_one_line(monkeypatch, tmp_path):
    import poevp_optics.core.paths as paths

    monkeypatch.setattr(paths, "PREDICTOR_WEIGHTS_DIR", tmp_path)   # a checkout without the full weights
    with pytest.raises(WeightsError) as e:
        make_predictor("dmvfn")
    msg = str(e.value)
    assert "not shipped" in msg and "predictor.weights" in msg and len(msg.splitlines()) == 1


def test_shipped_full_dmvfn_weights_carry_their_record_and_load_as_float32():
    """The full DMVFN's shipped weights (trained on a GPU, stored as float16) load into the
    float32 network value for value, and their metadata holds the command, data and budget."""
    import json

    from safetensors import safe_open

    import poevp_optics.control.predictors.dmvfn as dm

    path = dm.default_weights("dmvfn")
    model, meta = dm.load_weights(path, expect=dm.FULL)
    training = meta["training"]
    assert training["command"].startswith("poevp train-predictor --name dmvfn")
    assert len(training["dataset"]["sha256"]) == 64 and training["steps"] > 0 and training["train_seconds"] > 0
    with safe_open(str(path), framework="pt") as f:
        stored = {k: f.get_tensor(k) for k in f.keys()}
    state = model.state_dict()
    assert {t.dtype for t in stored.values() if t.is_floating_point()} == {torch.float16}
    for k, t in stored.items():
        assert state[k].dtype == torch.float32 and torch.equal(state[k], t.float())
    assert json.loads(json.dumps(meta["validation"]))["model"]["highlight_frames"] > 0


# ----------------------------------------------------------------------------- the clip marker
def _history(mode: str, shape=(92, 160), x0=30, step=6, n=4):
    """Frames of a 16x24 px clipped region moving `step` px/frame on a gradient, as each loop
    mode hands them to the predictor: open/raw at the 8-bit clip (255), demodulated lifted above
    it (a clipped pixel's estimate times the mask's clipped gain, here 22 x 255)."""
    h, w = shape
    top = 255.0 if mode in ("open", "raw") else 255.0 * 22
    frames = []
    for t in range(n):
        f = np.tile(np.linspace(20, 120, w, dtype=np.float32), (h, 1))
        f[40:56, x0 + step * t:x0 + step * t + 24] = top
        frames.append(f)
    return frames


@pytest.mark.parametrize("mode", ["open", "raw", "demodulated"])
@pytest.mark.parametrize("name", ["hold", "flow", "track", "track_net", "dmvfn_lite"])
def test_a_clipped_region_stays_clipped_through_prediction_and_resize(name, mode):
    """Whatever the predictor and loop mode, the region clipped in the inputs is still at least
    the clip marker over >= 90 % of its area in the prediction placed on the sensor grid
    (resized x1.5 bilinear, as the loop does; an unclipped 254 would let the law read it as a
    measurement)."""
    hist = _history(mode)
    pred = make_predictor(name)(hist)
    on_sensor = resize_keeping_clip(pred, (138, 240))
    area_sensor = 16 * 24 * 1.5 * 1.5
    assert np.count_nonzero(on_sensor >= CLIP_MARKER) >= 0.9 * area_sensor, name


def test_resize_keeping_clip_marks_half_clipped_footprints():
    img = np.zeros((4, 4), np.float32)
    img[:, :2] = 255.0
    img[:, 2] = 200.0
    out = resize_keeping_clip(img, (2, 2))                # area average: left half clipped
    assert (out[:, 0] >= CLIP_MARKER).all() and (out[:, 1] < CLIP_MARKER).all()


def test_track_net_training_is_reproducible():
    """Same command, same data hash and the same weights (seeded data, init and batches; the
    shipped weights' record names the command and the hashes)."""
    from poevp_optics.apps.train.train_track import train_track_net

    kw = dict(train_sequences=6, val_sequences=2, test_sequences=2, frames=6, steps=30, progress=False)
    a, b = train_track_net(**kw), train_track_net(**kw)
    assert a["data"] == b["data"] and a["data"]["train"]["samples"] > 10
    assert a["val"] == b["val"] and a["loss_last_200"] == b["loss_last_200"]


def test_track_net_splits_hold_other_data():
    """Train and test splits of equal size (the same number of samples, so only their content
    can tell their hashes apart) hash differently and share no measured chain, while the train
    split built again from its seeds hashes the same and shares every chain (so both checks
    detect a split drawn from another split's seeds)."""
    from poevp_optics.apps.train.train_track import data_hash, synthetic_split, to_tensors

    train, test = (synthetic_split(s, 3, 6, progress=False)[0] for s in ("train", "test"))
    again = synthetic_split("train", 3, 6, progress=False)[0]
    n = min(len(train), len(test))
    assert n >= 8
    h = lambda samples: data_hash(to_tensors(samples[:n]))
    assert h(train) != h(test) and h(train) == h(again)
    chains = lambda samples: {to_tensors([x])["disp"].numpy().tobytes() for x in samples}
    assert not chains(train) & chains(test) and chains(train) == chains(again)


def test_closed_form_growth():
    """Constant growth continues (geometric mean of the last two ratios); one ratio, ratios
    that disagree, or ratios within the 1 % deadband (outline noise) are no growth; limited to
    1.25 a frame."""
    from poevp_optics.control.predictors.track import closed_form_growth

    assert closed_form_growth((1.1, 1.1, 1.1)) == pytest.approx(1.1)
    assert closed_form_growth((1.21, 1.0 / 0.9)) == pytest.approx(np.sqrt(1.21 / 0.9))
    assert closed_form_growth((0.9, 0.9)) == pytest.approx(0.9)
    assert closed_form_growth((1.1,)) == 1.0 and closed_form_growth((1.1, 0.95)) == 1.0
    assert closed_form_growth((1.005, 1.005)) == 1.0 and closed_form_growth((1.5, 1.5)) == 1.25


@pytest.mark.parametrize("name", ["track", "track_net"])
@pytest.mark.parametrize("rate", [1.1, 1.25])
def test_a_growing_light_is_predicted_grown(name, rate):
    """A clipped lamp growing 10 or 25 % a frame about a fixed centre (an approaching car's
    lamp): the prediction's saturated region is the next frame's, IoU >= 0.9, where `flow` and
    `hold` (no growth) keep last frame's size (IoU 1/rate^2 at best for an ellipse scaled by
    rate: 0.83 and 0.64)."""
    from poevp_optics.analysis.prediction_metrics import saturated_iou
    from tests.unit.test_region_matching import lamps

    frames = [lamps([(160.0, 92.0)], axes=(10.0 * rate ** t, 6.0 * rate ** t)) for t in range(5)]
    got = saturated_iou(make_predictor(name)(frames[:4]), frames[4])
    held = saturated_iou(make_predictor("flow")(frames[:4]), frames[4])
    assert got >= 0.9 and held < 1.02 / rate ** 2, (got, held)


def test_track_net_numpy_forward_equals_the_model():
    """The loop's NumPy inference equals the torch model (float32 rounding), stopped chains
    (newest displacement under STOP_PX: predicted to stand) and missing displacements included."""
    from poevp_optics.control.predictors.track_net import STOP_PX, numpy_forward

    torch.manual_seed(1)
    net = TrackNet()
    for p in net.parameters():
        torch.nn.init.normal_(p, std=0.3)
    disp = torch.randn(200, 3, 2) * 20
    disp[:20, 0] *= 0.5 / disp[:20, 0].norm(dim=-1, keepdim=True)   # newest displacement 0.5 px: stopped
    valid = (torch.rand(200, 3) > 0.2).float()
    valid[:, 0] = 1
    resp = torch.rand(200, 3)
    with torch.no_grad():
        want = net(disp, valid, resp).numpy()
    got = numpy_forward(numpy_layers(net), disp.numpy(), valid.numpy(), resp.numpy())
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-3)
    stopped = disp[:, 0].norm(dim=-1).numpy() < STOP_PX
    assert stopped.sum() == 20
    np.testing.assert_array_equal(got[stopped], 0.0)


@pytest.mark.parametrize("name", ["track", "track_net"])
def test_measurements_kept_between_calls_change_no_prediction(name, monkeypatch):
    """A tracker called on a sliding history keeps each frame's and frame pair's measurements
    (track.py `MeasureCache`): its predictions equal, bit for bit, a fresh tracker's on each
    history, and each call after the first measures one new frame pair, not three."""
    from poevp_optics.analysis.traffic_paths import draw_scene
    from poevp_optics.control.predictors import track as track_mod

    calls = []
    measure = track_mod.measure_pair
    monkeypatch.setattr(track_mod, "measure_pair", lambda *a: calls.append(1) or measure(*a))
    frames = draw_scene("crossing", 24.0, 4242).frames[:10]
    kept = make_predictor(name)
    for t in range(4, len(frames)):
        hist = list(frames[t - 4:t])
        before = len(calls)
        got = kept(hist)
        assert len(calls) - before == (3 if t == 4 else 1)
        np.testing.assert_array_equal(got, make_predictor(name)(hist))


@pytest.mark.parametrize("name", ["flow", "track", "track_net"])
def test_the_memory_estimate_bounds_a_predictor_call(name):
    """The run's memory estimate (apps/run/memory.py) counts a predictor call's peak of NumPy
    memory (tracemalloc) at 368x640 on several crossing lights, the trackers' kept measurements
    of the last four frames included."""
    import tracemalloc

    from poevp_optics.analysis.traffic_paths import draw_scene
    from poevp_optics.apps.run.memory import FLOW_BYTES_PER_PX, TRACK_BYTES_PER_PX

    frames = draw_scene("crossing", 24.0, 4243).frames[:10]
    h, w = frames[0].shape
    p = make_predictor(name)
    tracemalloc.start()
    try:
        base, peak = tracemalloc.get_traced_memory()[0], 0
        for t in range(4, len(frames)):
            tracemalloc.reset_peak()
            p(list(frames[t - 4:t]))
            peak = max(peak, tracemalloc.get_traced_memory()[1] - base)
    finally:
        tracemalloc.stop()
    bound = (FLOW_BYTES_PER_PX if name == "flow" else TRACK_BYTES_PER_PX) * h * w
    assert 0.3 * bound < peak <= bound, (name, peak / (h * w))
