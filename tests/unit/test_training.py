"""A tiny training run lowers the loss; checkpoints resume (issue 4)."""

from __future__ import annotations

import json

import numpy as np

from poevp_optics.apps.train import train as train_mod


def test_tiny_training_lowers_loss_and_resumes(tmp_path, monkeypatch):
    rng = np.random.default_rng(0)
    # a synthetic dataset of moving bright bars keeps this test independent of rendering
    def fake_dataset(n, frames, seed, resolution, progress=True):
        h, w = resolution
        out = np.zeros((n, frames, h, w), np.uint8)
        for i in range(n):
            x0, v = rng.integers(10, 40), rng.integers(3, 7)
            for t in range(frames):
                img = np.full((h, w), 30, np.uint8)
                img[20:40, x0 + v * t:x0 + v * t + 12] = 255
                out[i, t] = img
        return out

    monkeypatch.setattr(train_mod, "build_dataset", fake_dataset)
    rec = train_mod.train("dmvfn_lite", minutes=5, sequences=4, frames=5, val_sequences=1, batch=4,
                          lr=3e-3, out=tmp_path, max_steps=80, checkpoint_every=40,
                          resolution=(64, 128), progress=False)
    losses = json.loads((tmp_path / "dmvfn_lite" / "checkpoint.json").read_text())["losses"]
    assert len(losses) == 80
    assert np.mean(losses[-10:]) < 0.8 * np.mean(losses[:10])
    # resume: another 20 steps continue from step 80
    rec2 = train_mod.train("dmvfn_lite", minutes=5, sequences=4, frames=5, val_sequences=1, batch=4,
                           lr=3e-3, out=tmp_path, max_steps=100, checkpoint_every=40,
                           resolution=(64, 128), progress=False)
    assert rec2["steps"] == 100 and rec["steps"] == 80
