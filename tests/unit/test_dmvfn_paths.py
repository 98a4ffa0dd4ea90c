"""DMVFN training on motion-path frames: the frames, the saturation loss, half-float weights, and
weights kept when validation is cut short."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from poevp_optics.apps.train import path_frames as pf
from poevp_optics.apps.train import train as train_mod


def _regions(frame: np.ndarray) -> int:
    import cv2

    n, _ = cv2.connectedComponents((frame >= 255).astype(np.uint8), connectivity=8)
    return n - 1


def test_path_frames_are_reproducible_split_apart_and_hold_several_highlights():
    a = pf.path_frames("train", 12, 4, (92, 160))
    assert a.shape == (12, 4, 92, 160) and a.dtype == np.uint8
    # the same draws whatever the number of worker processes
    assert np.array_equal(a, pf.path_frames("train", 12, 4, (92, 160), workers=2))
    # sequence i is a function of its split and index alone
    assert np.array_equal(pf.path_sequence("train", 5, 4, (92, 160)), a[5])
    # validation draws other paths, texts and noise: no validation sequence repeats a training one
    v = pf.path_frames("val", 12, 4, (92, 160))
    assert not any(np.array_equal(x, y) for x in v for y in a)
    # 1-3 cars per sequence: over 12 sequences some first frame shows more than one highlight
    counts = [_regions(s[0]) for s in a]
    assert max(counts) >= 2 and min(counts) >= 1
    with pytest.raises(ValueError, match="split 'tests'"):
        pf.path_frames("tests", 2)


def _square(h, w, y0, x0, n, value):
    img = torch.zeros(1, 1, h, w)
    img[..., y0:y0 + n, x0:x0 + n] = value
    return img


def test_saturation_loss_is_one_minus_the_soft_iou_of_two_squares():
    """Predicted square of 1.0 (soft weight s = sigmoid((1 - 0.985) / 0.004)) overlapping a true
    saturated square by k pixels: loss = 1 - s k / (s |A| + |B| - s k), computed here by hand."""
    s = 1.0 / (1.0 + math.exp(-(1.0 - 0.985) / 0.004))
    pred = _square(40, 40, 5, 5, 10, 1.0)         # |A| = 100
    true = _square(40, 40, 10, 10, 10, 1.0)       # |B| = 100, overlap 5 x 5 = 25
    want = 1.0 - s * 25 / (s * 100 + 100 - s * 25)
    got = train_mod.saturated_iou_loss(pred, true).item()
    assert got == pytest.approx(want, rel=1e-5)
    # the same square predicted: only the soft weight's shortfall remains (float32: a few ulp of 1)
    assert train_mod.saturated_iou_loss(true, true).item() == pytest.approx(1.0 - s, abs=1e-6)
    # a value 10 DN below the clip predicted where the truth clips counts nearly nothing
    assert train_mod.saturated_iou_loss(true * 245 / 255, true).item() > 0.99
    # no saturated pixel in the truth: no term (and a gradient of zero, not NaN)
    p = pred.clone().requires_grad_(True)
    loss = train_mod.saturated_iou_loss(p, true * 0.5)
    loss.backward()
    assert loss.item() == 0.0 and torch.all(p.grad == 0)


def test_half_float_weights_are_the_float32_weights_rounded(tmp_path):
    from safetensors import safe_open

    from poevp_optics.control.predictors.dmvfn import LITE, DMVFN, load_weights, save_weights

    torch.manual_seed(3)
    model = DMVFN(LITE)
    save_weights(model, tmp_path / "w16.safetensors", {"note": "x"}, float16=True)
    save_weights(model, tmp_path / "w32.safetensors", {"note": "x"})
    with safe_open(str(tmp_path / "w16.safetensors"), framework="pt") as f:
        dtypes = {f.get_slice(k).get_dtype() for k in f.keys()}
    assert dtypes == {"F16"}
    assert (tmp_path / "w16.safetensors").stat().st_size < 0.55 * (tmp_path / "w32.safetensors").stat().st_size
    loaded, meta = load_weights(tmp_path / "w16.safetensors", expect=LITE)
    assert meta["note"] == "x"
    for (k, a), (_, b) in zip(model.state_dict().items(), loaded.state_dict().items()):
        assert b.dtype == torch.float32 and torch.equal(b, a.half().float()), k


def _bars(n, frames, seed, resolution, progress=True):
    rng = np.random.default_rng(seed)
    out = np.full((n, frames, *resolution), 30, np.uint8)
    for i in range(n):
        x0 = int(rng.integers(4, 20))
        for t in range(frames):
            out[i, t, 10:20, x0 + 4 * t:x0 + 4 * t + 8] = 255
    return out


def test_trained_weights_are_kept_when_validation_is_cut_short(tmp_path, monkeypatch):
    """A run stopped during validation (here: validation raises) leaves its trained weights,
    loadable, with the training record and no validation; a run that validates replaces them
    with the validated record. The saturation term is in the run's loss and record."""
    from poevp_optics.control.predictors.dmvfn import LITE, load_weights

    monkeypatch.setattr(train_mod, "build_dataset", _bars)
    kw = dict(minutes=5, sequences=2, frames=4, val_sequences=1, batch=2, resolution=(32, 64), progress=False,
              max_steps=3, saturation_weight=0.05, weights_out=tmp_path / "w.safetensors")

    def cut(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(train_mod, "evaluate", cut)
    with pytest.raises(KeyboardInterrupt):
        train_mod.train("dmvfn_lite", out=tmp_path / "a", **kw)
    _, meta = load_weights(tmp_path / "w.safetensors", expect=LITE)
    assert meta["validation"] is None and meta["training"]["steps"] == 3
    assert meta["training"]["loss"] == "multiscale_l1 + 0.05 * (1 - saturated soft IoU)"
    monkeypatch.undo()
    monkeypatch.setattr(train_mod, "build_dataset", _bars)
    rec = train_mod.train("dmvfn_lite", out=tmp_path / "a", data_seconds=2.5, **kw)
    assert 2.5 <= rec["data_seconds"] < 60       # the caller's time making the frames is counted
    _, meta = load_weights(tmp_path / "w.safetensors", expect=LITE)
    assert meta["validation"]["model"]["highlight_frames"] == rec["validation"]["model"]["highlight_frames"] > 0
    assert json.loads((tmp_path / "w.json").read_text())["validation"] == meta["validation"]
    with pytest.raises(ValueError, match="saturation_weight"):
        train_mod.train("dmvfn_lite", out=tmp_path / "b", **{**kw, "saturation_weight": float("nan")})


def test_train_predictor_path_data_refuses_what_it_cannot_do(tmp_path, capsys):
    """`--data paths` trains the DMVFNs without a scene; with a scene, or with a negative or NaN
    saturation weight, one line and exit 2, nothing written."""
    from poevp_optics.cli import main

    out = ["--out", str(tmp_path / "t"), "--weights-out", str(tmp_path / "w.safetensors")]
    assert main(["train-predictor", "scenes/highbeam_plate", "--data", "paths", *out]) == 2
    assert main(["train-predictor", "--name", "track_net", "--data", "paths", *out]) == 2
    for w in ("-1", "nan"):
        assert main(["train-predictor", "--data", "paths", "--saturation-weight", w, *out]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(line.startswith("poevp: ") for line in err), err
    assert "without a SCENE" in err[0] and "--saturation-weight nan" in err[3]
    assert not any(tmp_path.iterdir())
