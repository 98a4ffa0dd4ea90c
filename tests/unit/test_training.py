"""A tiny training run lowers the loss; checkpoints resume, but only into the same run."""

from __future__ import annotations

import json

import numpy as np

from poevp_optics.apps.train import train as train_mod


def _bars(n, frames, seed, resolution, progress=True):
    """A synthetic dataset of moving bright bars (independent of rendering), seeded."""
    rng = np.random.default_rng(seed)
    h, w = resolution
    out = np.zeros((n, frames, h, w), np.uint8)
    for i in range(n):
        x0, v = rng.integers(10, 40), rng.integers(3, 7)
        for t in range(frames):
            img = np.full((h, w), 30, np.uint8)
            img[20:40, x0 + v * t:x0 + v * t + 12] = 255
            out[i, t] = img
    return out


KW = dict(minutes=5, sequences=4, frames=5, val_sequences=1, batch=4, checkpoint_every=40,
          resolution=(64, 128), progress=False)


def _losses(tmp_path):
    return json.loads((tmp_path / "dmvfn_lite" / "checkpoint.json").read_text())["losses"]


def test_tiny_training_lowers_loss_and_resumes(tmp_path, monkeypatch):
    monkeypatch.setattr(train_mod, "build_dataset", _bars)
    notes = []
    rec = train_mod.train("dmvfn_lite", lr=3e-3, out=tmp_path, max_steps=80, log=notes.append, **KW)
    losses = _losses(tmp_path)
    assert len(losses) == 80
    assert np.mean(losses[-10:]) < 0.8 * np.mean(losses[:10])
    # resume: the same run given a larger budget continues from step 80
    rec2 = train_mod.train("dmvfn_lite", lr=3e-3, out=tmp_path, max_steps=100, log=notes.append, **KW)
    assert rec2["steps"] == 100 and rec["steps"] == 80 and not notes
    assert _losses(tmp_path)[:80] == losses
    assert rec2["dataset"]["sha256"] == train_mod.frames_sha256(*train_mod._procedural(4, 1, 5, 0, (64, 128), False))


def test_another_run_does_not_resume_a_checkpoint(tmp_path, monkeypatch):
    """A run with another learning rate, seed or data in the same folder starts at step 0 (one
    note naming what differs) and records its own settings; it used to resume the first run's
    checkpoint, run 0 more steps and return the first run's model under the new settings."""
    monkeypatch.setattr(train_mod, "build_dataset", _bars)
    notes = []
    kw = {**KW, "checkpoint_every": 5, "max_steps": 10}
    train_mod.train("dmvfn_lite", lr=3e-3, out=tmp_path, log=notes.append, **kw)
    first = _losses(tmp_path)
    rec = train_mod.train("dmvfn_lite", lr=1e-3, out=tmp_path, log=notes.append, **kw)
    assert rec["steps"] == 10 and rec["lr"] == 1e-3 and len(_losses(tmp_path)) == 10
    assert _losses(tmp_path)[1:] != first[1:]
    assert len(notes) == 1 and "another run's checkpoint" in notes[0] and "lr" in notes[0] and "\n" not in notes[0]
    # other data (another seed draws other bars): again afresh
    rec = train_mod.train("dmvfn_lite", lr=1e-3, seed=1, out=tmp_path, log=notes.append, **kw)
    assert rec["steps"] == 10 and "data_sha256" in notes[-1] and "seed" in notes[-1]
    # a damaged checkpoint: afresh, with a note
    (tmp_path / "dmvfn_lite" / "checkpoint.safetensors").write_bytes(b"\0" * 16)
    rec = train_mod.train("dmvfn_lite", lr=1e-3, seed=1, out=tmp_path, log=notes.append, **kw)
    assert rec["steps"] == 10 and "unreadable checkpoint" in notes[-1]


def test_procedural_data_cache_key_covers_what_the_frames_depend_on(tmp_path, monkeypatch):
    """The procedural set's cache key changes with every input of its frames: a scene file's
    bytes, the camera (a scene.toml edit), the renderer's version, and the draw parameters; the
    same inputs give the same key (no stale data set served for another scene or renderer)."""
    import shutil

    import mitsuba as mi

    from poevp_optics.apps.train import training_data as tdata

    base, parts = tdata.dataset_key(2, 4, 0, (64, 112))
    assert tdata.dataset_key(2, 4, 0, (64, 112))[0] == base
    assert {"scene.toml", "scene.xml"} <= set(parts["scene_files_sha256"])
    assert tdata.dataset_key(2, 4, 0, (64, 128))[0] != base
    assert tdata.dataset_key(2, 4, 1, (64, 112))[0] != base
    copy = tmp_path / "highbeam_plate"
    shutil.copytree(tdata.SCENE, copy)
    monkeypatch.setattr(tdata, "SCENE", copy)
    assert tdata.dataset_key(2, 4, 0, (64, 112))[0] == base          # same bytes elsewhere: same key
    xml = copy / "scene.xml"
    xml.write_text(xml.read_text() + "\n<!-- edited -->\n")
    edited = tdata.dataset_key(2, 4, 0, (64, 112))[0]
    assert edited != base
    toml = copy / "scene.toml"
    text = toml.read_text()
    assert "\n[sensor]\npreset = \"IMX253\"\nf_number = 2.0\n" in text
    toml.write_text(text.replace("f_number = 2.0\n", "f_number = 2.8\n", 1))     # the camera's working f-number
    camera = tdata.dataset_key(2, 4, 0, (64, 112))
    assert camera[0] != edited and "f_number=2.8" in camera[1]["camera"]
    monkeypatch.setattr(mi, "__version__", "0.0.0-other")
    assert tdata.dataset_key(2, 4, 0, (64, 112))[0] != camera[0]
