"""`poevp train-data` / `train-predictor SCENE --name track_net` (issue 26): the data's split is
disjoint, the cache is hit by content, a killed-and-resumed training ends with the weights of an
uninterrupted one, the weights' metadata holds the budget and loads without pickle, and
`--device auto` picks the CPU when torch sees no CUDA device. Tiny budgets (one small render)."""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest
import torch

from poevp_optics.apps.train import train_data as td
from poevp_optics.apps.train import train_track as tt
from poevp_optics.cli import main
from poevp_optics.core.paths import SCENES_DIR

TINY = ["--sequences", "3,2,2", "--frames", "6", "--resolution", "64x112", "--spp", "2", "--quiet"]
TINY_CFG = td.DataConfig(sequences=(3, 2, 2), frames=6, resolution=(64, 112), spp=2)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A cache folder holding the tiny highbeam_plate data set, built once by the CLI."""
    root = tmp_path_factory.mktemp("cache")
    mp = pytest.MonkeyPatch()
    mp.setenv("POEVP_CACHE_DIR", str(root))
    assert main(["train-data", str(SCENES_DIR / "highbeam_plate"), *TINY]) == 0
    yield root
    mp.undo()


@pytest.fixture
def data(cache, monkeypatch):
    monkeypatch.setenv("POEVP_CACHE_DIR", str(cache))
    monkeypatch.setattr(td, "render_frames", _no_render)
    return td.build_data(str(SCENES_DIR / "highbeam_plate"), TINY_CFG, progress=False, log=lambda *_: None)


def _no_render(spec):
    raise AssertionError("rendered although the data set is in the cache")


def test_manifest_split_is_disjoint(data):
    m = data.manifest
    seqs = m["sequences"]
    assert [len(seqs[s]) for s in td.SPLITS] == [3, 2, 2]
    for a in td.SPLITS:
        for b in td.SPLITS:
            if a >= b:
                continue
            assert not {d["text"] for d in seqs[a]} & {d["text"] for d in seqs[b]}
            assert not {d["seed"] for d in seqs[a]} & {d["seed"] for d in seqs[b]}
            assert not [(x, y) for x in seqs[a] for y in seqs[b] if _near(x, y)]
            # texts cannot collide by construction: their first letters come from disjoint sets
            assert not set(m["split"]["text_first_letters"][a]) & set(m["split"]["text_first_letters"][b])
    for s in td.SPLITS:
        fr, boxes = data.splits[s]["frames"], data.splits[s]["boxes"]
        assert fr.shape == (len(seqs[s]), 6, 64, 112) and fr.dtype == np.uint8
        assert boxes.shape == (len(seqs[s]), 6, 4)
        assert all(d["text"][0] in m["split"]["text_first_letters"][s] for d in seqs[s])
        # the plate is in view and clipped in the LDR frames (what the tracker follows)
        assert (boxes[..., 2] > boxes[..., 0]).all()
        assert all((f >= 255).sum() >= 16 for seq in fr for f in seq)
        # ... where the renderer says the plate is (its boxes in the frame's pixels)
        for seq, bs in zip(fr, boxes):
            for f, b in zip(seq, bs):
                assert (f[b[0]:b[2], b[1]:b[3]] >= 255).sum() >= 16
    assert m["timing"]["render_seconds"] > 0 and m["timing"]["where"] == "local"
    # the check finds a near-duplicate trajectory where there is one: the train split drawn again
    # from its seeds, and one draw nudged within the tolerances
    again = [asdict(d) for d in td.draws(TINY_CFG)["train"]]
    assert all(_near(x, y) for x, y in zip(seqs["train"], again))
    first = seqs["train"][0]
    nudged = {**first, "speed_px": first["speed_px"] * 1.01, "heading_deg": first["heading_deg"] + 1.0}
    assert _near(first, nudged) and not _near(first, {**nudged, "speed_px": first["speed_px"] * 1.03})


def _near(a: dict, b: dict) -> bool:
    """Two sequences' trajectories are near-duplicates: same kind, image speeds within 2 %,
    headings within 2 deg, start ranges within 1 % and range speeds within 0.2 m/s. A leak of one
    split's draws into another (exact or rounded) is near; two independent draws are near with
    probability below 1 kind in 10 x 1/2 (a lateral pair on the same side) x 0.04 / ln 12.5
    (log-uniform speeds over 12.5x) x 0.02 x 0.85 / 0.7 (start range uniform in 0.5-1.2,
    DataConfig.distance), about 2e-5 per pair (16 pairs here: the seeded draws give the same answer on every run)."""
    dh = abs((a["heading_deg"] - b["heading_deg"] + 180.0) % 360.0 - 180.0)
    return (a["kind"] == b["kind"] and abs(np.log(a["speed_px"] / b["speed_px"])) < 0.02 and dh < 2.0
            and abs(a["range_scale"] / b["range_scale"] - 1.0) < 0.01
            and abs(a["range_speed_m_per_s"] - b["range_speed_m_per_s"]) < 0.2)


def test_cache_hit_by_content(cache, data, tmp_path, monkeypatch):
    # second call: served from the cache (render_frames raises if called: the `data` fixture)
    assert not data.rendered
    assert data.folder.parent == cache / "train_data"
    key, _ = td.content_key(str(SCENES_DIR / "highbeam_plate"), TINY_CFG)
    assert data.sha256 == key
    # other generation parameters or other scene files: another key
    other, _ = td.content_key(str(SCENES_DIR / "highbeam_plate"), td.DataConfig(**{**TINY_CFG.__dict__, "seed": 1}))
    assert other != key
    copy = tmp_path / "hb"
    shutil.copytree(SCENES_DIR / "highbeam_plate", copy)
    xml = copy / "scene.xml"
    xml.write_text(xml.read_text() + "\n<!-- edited -->\n")
    toml = copy / "scene.toml"
    toml.write_text(toml.read_text())
    edited, _ = td.content_key(str(copy), TINY_CFG)
    assert edited != key


def _chains(n: int, seed: int) -> dict[str, torch.Tensor]:
    """Constant-acceleration chains (d_{t+1} = 2 d_t - d_{t-1}) with noise: a learnable law."""
    rng = np.random.default_rng(seed)
    v = rng.normal(0, 10, (n, 2))
    a = rng.normal(0, 2, (n, 2))
    disp = np.stack([v, v - a, v - 2 * a], 1) + rng.normal(0, 0.3, (n, 3, 2))
    return {"disp": torch.tensor(disp, dtype=torch.float32), "valid": torch.ones(n, 3),
            "resp": torch.full((n, 3), 0.5), "target": torch.tensor(v + a, dtype=torch.float32)}


def test_killed_and_resumed_equals_uninterrupted(tmp_path):
    tr, va = _chains(400, 0), _chains(100, 1)
    kw = dict(steps=60, batch=32, lr=3e-3, seed=3, checkpoint_every=20, run_id={"data": "x"}, progress=False)
    whole, st_whole = tt.fit(tr, va, checkpoint_dir=tmp_path / "a", **kw)
    # killed at step 50: the last checkpoint (step 40) stands; the rerun resumes from it
    tt.fit(tr, va, checkpoint_dir=tmp_path / "b", stop_after=50, **kw)
    ck = json.loads(_metadata(tmp_path / "b" / "checkpoint.safetensors")["state"])
    assert ck["step"] == 40
    resumed, st = tt.fit(tr, va, checkpoint_dir=tmp_path / "b", resume=True, **kw)
    assert st["resumed_at"] == [40] and st["step"] == 60
    for (k, a), (_, b) in zip(whole.state_dict().items(), resumed.state_dict().items()):
        assert torch.equal(a, b), k
    assert st["losses"] == st_whole["losses"]
    # training learned the law: constant acceleration beats constant velocity on held-out chains
    assert st["val"]["median_centroid_error_px"] < float((va["disp"][:, 0] - va["target"]).norm(dim=-1).median())
    # another run's checkpoint is refused
    with pytest.raises(ValueError, match="another run"):
        tt.fit(tr, va, checkpoint_dir=tmp_path / "b", resume=True, **{**kw, "run_id": {"data": "y"}})


def _metadata(path: Path) -> dict:
    from safetensors import safe_open

    with safe_open(str(path), framework="pt") as f:
        return f.metadata()


def test_scene_weights_metadata(cache, monkeypatch, tmp_path, capsys):
    from poevp_optics.control.predictors import make_predictor
    from poevp_optics.control.predictors.track_net_model import load_track_net

    monkeypatch.setenv("POEVP_CACHE_DIR", str(cache))
    monkeypatch.setattr(td, "render_frames", _no_render)
    out = tmp_path / "w.safetensors"
    assert main(["train-predictor", str(SCENES_DIR / "highbeam_plate"), "--name", "track_net", *TINY,
                 "--max-steps", "30", "--batch", "8", "--device", "auto", "--out", str(tmp_path / "ck"),
                 "--weights-out", str(out)]) == 0
    assert "held-out median centroid error" in capsys.readouterr().out
    raw = out.read_bytes()
    header = int.from_bytes(raw[:8], "little")
    assert raw[8:9] == b"{" and json.loads(raw[8:8 + header])          # safetensors, not a pickle
    model, meta = load_track_net(out)
    b = meta["budget"]
    assert b["steps"] == 30 and b["batch"] == 8 and b["device"] == "cpu" and b["epochs"] > 0
    assert b["train_cpu_seconds"] > 0 and b["data_seconds"] > 0 and b["data_from_cache"]
    manifest = json.loads(next((cache / "train_data").glob("highbeam_plate-*/manifest.json")).read_text())
    assert meta["data"]["content_sha256"] == manifest["content_sha256"]
    assert meta["split"]["texts"] == manifest["split"]["texts"]
    assert "train-predictor" in meta["command"]
    assert {"median_centroid_error_px", "mean_region_iou"} <= set(meta["val_metric"])
    assert make_predictor("track_net", str(out)).describe()["name"] == "track_net"


def test_device_auto(monkeypatch):
    assert tt.resolve_device("cpu") == "cpu"
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert tt.resolve_device("auto") == "cpu"
    with pytest.raises(ValueError, match="no CUDA"):
        tt.resolve_device("cuda")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert tt.resolve_device("auto") == "cuda"


def test_sequence_renders_as_a_sweep_point(cache, monkeypatch, tmp_path):
    """The Dask path's unit: one sequence as a sweep point (apps/sweep/sweep.py run_point, job
    train_sequence) gives the frames the local build stored, bit for bit."""
    import io
    import zipfile

    from poevp_optics.apps.sweep.bundle import make_plan, scene_inputs, with_hashes
    from poevp_optics.apps.sweep.sweep import PointTask, run_point
    from poevp_optics.scene.load import load_scene, resolve_scene_path

    monkeypatch.setenv("POEVP_CACHE_DIR", str(cache))
    scene = str(SCENES_DIR / "highbeam_plate")
    folder = next((cache / "train_data").glob("highbeam_plate-*"))
    m = json.loads((folder / "manifest.json").read_text())
    geo = td.Geometry(**m["geometry"])
    d = td.SequenceDraw(**m["sequences"]["test"][0])
    base = load_scene(scene, ["render.resolution=[64, 112]"])
    ov = td.sequence_overrides(base, d, TINY_CFG, geo)
    refs = tuple(with_hashes(scene_inputs(load_scene(scene, ov, cross_checks=False))))
    plan = make_plan("shared", resolve_scene_path(scene), list(refs))
    res = run_point(PointTask(tuple(ov), td.JOB, 1, plan, refs), None)
    assert res["row"]["status"] == "ok", res["row"]
    with zipfile.ZipFile(io.BytesIO(res["archive"])) as z:
        got = np.load(io.BytesIO(z.read("frames.npz")))
    stored = np.load(folder / "test.npz")
    assert np.array_equal(got["frames"], stored["frames"][0])
    assert np.array_equal(got["boxes"], stored["boxes"][0])
