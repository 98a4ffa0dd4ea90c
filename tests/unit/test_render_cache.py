"""Stored renders (render/render_cache.py): the key names exactly the render's inputs, a stored
exposure reads back with the same arrays and scalar types, a replayed run writes the recorded
run's bytes, a damaged store is noted and rendered again, and a sweep point on a worker without
the client's files replays a render it was sent (apps/sweep/reuse.py)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pytest

from poevp_optics.apps.run.render_run import run_render
from poevp_optics.apps.sweep.bundle import scene_inputs, with_hashes
from poevp_optics.core.frame import RenderedExposure
from poevp_optics.render.render_cache import (CAMERA_ONLY_ACCURACY, RenderCache, load_exposure, render_group,
                                              save_exposure, verify)
from poevp_optics.scene.load import load_scene
from tests.conftest import ROOT, SCENES

#: smoke at 24x32, 2 frames, 2 radiance nodes: a run of about a second.
TINY = ["render.resolution=[24,32]", "timing.frames=2", "render.spp=4", "outputs.previews=false",
        "outputs.contact_sheet=false", "mask.law='threshold_exp'", "mask.vs=200.0"]


def _group(overrides):
    spec = load_scene(SCENES / "smoke", TINY + overrides, cross_checks=False)
    return render_group(spec.resolved.render, {r.key: r.sha256 for r in with_hashes(scene_inputs(spec))})


def test_the_key_follows_the_render_inputs_and_nothing_else():
    base = _group([])
    # after the render: the mask law's coefficients, the sensor's gain, the relay, the predictor
    # and the camera's numerics (accuracy settings only the camera reads); the relay's PSF
    # width sets the guard band, which the run adds to the key (render_key)
    for same in (["mask.a=0.5"], ["mask.b=0.3"], ["sensor.seed=9"], ["relay.sigma_px=2.0"],
                 ["mask.smooth_px=3.0"], ["sensor.poisson_sampler='gaussian'"]):
        assert _group(same) == base, same
    # what the render reads: seed, spp, exposure window (the radiance nodes move), resolution
    for other in (["render.seed=8"], ["render.spp=8"], ["timing.exposure_s=0.01"], ["render.subframes=3"],
                  ["render.resolution=[24,40]"]):
        assert _group(other) != base, other


def test_camera_only_accuracy_fields_are_never_read_by_the_render():
    """The key leaves out CAMERA_ONLY_ACCURACY: no module of render/ or sources/ may read them."""
    from poevp_optics.core.accuracy import Accuracy

    names = {f.name for f in dataclasses.fields(Accuracy)}
    assert set(CAMERA_ONLY_ACCURACY) <= names
    for folder in ("render", "sources"):
        for p in (ROOT / "poevp_optics" / folder).rglob("*.py"):
            if p.name == "render_cache.py":
                continue
            text = p.read_text()
            for name in CAMERA_ONLY_ACCURACY:
                assert not re.search(rf"\.{name}\b", text), f"{p.name} reads accuracy.{name}"


def test_an_exposure_reads_back_with_its_arrays_and_scalar_types(tmp_path):
    rng = np.random.default_rng(1)
    mean = rng.random((5, 7), dtype=np.float32)
    ex = RenderedExposure.build(3, 0.1, 0.12, np.array([0.1, 0.11, 0.12]),
                                [rng.random((5, 7), dtype=np.float32) for _ in range(3)], mean,
                                rng.random((5, 7)), (1, 2, 4, 6), 0.125, np.float64(0.25),
                                subframe_variances=tuple(rng.random((5, 7)) for _ in range(3)),
                                spp=(4, 4, 8), target_met=None, ground_truth={"plate": "KA 7391", "n": 2})
    save_exposure(tmp_path / "f.npz", ex)
    back = load_exposure(tmp_path / "f.npz")
    for f in dataclasses.fields(RenderedExposure):
        a, b = getattr(ex, f.name), getattr(back, f.name)
        if f.name == "radiance":
            for g in dataclasses.fields(a):
                x, y = getattr(a, g.name), getattr(b, g.name)
                assert type(x) is type(y) and (np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y)
                if isinstance(x, np.ndarray):
                    assert x.dtype == y.dtype
        elif isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and np.array_equal(a, b), f.name
        elif isinstance(a, tuple) and a and isinstance(a[0], np.ndarray):
            assert all(x.dtype == y.dtype and np.array_equal(x, y) for x, y in zip(a, b)), f.name
        else:
            assert type(a) is type(b) and a == b, f.name
            assert repr(a) == repr(b), f.name           # EXR metadata writes repr(t_start_s)


def _files(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name != "report.html"}


def _untimed(obj):
    if isinstance(obj, dict):
        return {k: _untimed(v) for k, v in obj.items() if "seconds" not in k and k != "render_reuse"}
    if isinstance(obj, list):
        return [_untimed(v) for v in obj]
    return obj


def _run(tmp_path, name, cache, overrides=("mask.a=0.7",)):
    spec = load_scene(SCENES / "smoke", TINY + list(overrides))
    out = tmp_path / name
    out.mkdir()
    report = run_render(spec, out, progress=False, render_cache=cache)
    return out, report


def test_replay_writes_the_recorded_runs_bytes_and_a_damaged_store_renders_again(tmp_path, capsys):
    group, store = _group(["mask.a=0.7"]), tmp_path / "store"
    plain, _ = _run(tmp_path, "plain", None)
    first = RenderCache(group, (store,), store, "first")
    rec, rec_report = _run(tmp_path, "rec", first)
    assert first.outcome["reused"] is False and first.outcome["stored"]
    key = first.outcome["key"]
    assert verify(store / key)[0]["rendered_by"] == "first"
    again = RenderCache(group, (store,), store, "again")
    rep, rep_report = _run(tmp_path, "rep", again, ["mask.a=0.9"])    # another mask law coefficient
    assert again.outcome == {"key": key, "reused": True, "rendered_by": "first", "stored": None, "why": ""}
    same = RenderCache(group, (store,), store, "same")
    rep2, _ = _run(tmp_path, "rep2", same)
    files, plain_files = _files(rep2), _files(plain)
    assert files.pop("report.json") != plain_files.pop("report.json")     # timings differ
    assert files == plain_files == {k: v for k, v in _files(rec).items() if k != "report.json"}
    a, b = (json.loads((d / "report.json").read_text()) for d in (rec, rep2))
    assert _untimed(a) == _untimed(b) == _untimed(json.loads((plain / "report.json").read_text()))
    assert a["render_reuse"] == b["render_reuse"] and a["render_reuse"]["key"] == key
    assert b["stages"]["render"]["calls"] == a["stages"]["render"]["calls"]   # the render's counters
    # a frame file cut short: noted once, rendered and stored again, the same bytes
    frame = store / key / "frame_0001.npz"
    frame.write_bytes(frame.read_bytes()[:100])
    capsys.readouterr()
    healed = RenderCache(group, (store,), store, "healed")
    out, _ = _run(tmp_path, "healed", healed)
    err = capsys.readouterr().err
    assert f"cache folder {store / key} failed its check (frame_0001.npz:" in err and err.count("\n") == 1
    assert healed.outcome["reused"] is False and verify(store / key)[0]["rendered_by"] == "healed"
    assert {k: v for k, v in _files(out).items() if k != "report.json"} == \
           {k: v for k, v in plain_files.items() if k != "report.json"}


def test_a_point_without_the_clients_files_replays_the_render_it_was_sent(tmp_path, monkeypatch):
    """The scene bundle path of a sweep (no shared file system), on an in-process Dask worker:
    the recording is pulled from the worker in chunks and pushed back to it in chunks, into the
    inbox the next point reads."""
    from distributed import Client

    from poevp_optics.apps.sweep import reuse
    from poevp_optics.apps.sweep.bundle import make_bundle, make_plan
    from poevp_optics.apps.sweep.sweep import PointTask, run_point
    from poevp_optics.apps.sweep.sweep_grid import point_overrides

    monkeypatch.setattr(reuse, "CHUNK_BYTES", 4096)           # many chunks per file
    ov = tuple(TINY + point_overrides(["mask.a"], [0.7], 0))
    spec = load_scene(SCENES / "smoke", list(ov))
    refs = tuple(with_hashes(scene_inputs(spec)))
    plan = make_plan("bundle", SCENES / "smoke", list(refs))
    bundle = make_bundle(plan, list(refs))
    plan = dataclasses.replace(plan, bundle_sha256=bundle.sha256)
    group = render_group(spec.resolved.render, {r.key: r.sha256 for r in refs})
    task = PointTask(ov, "render", 1, plan, refs, {}, group, (), "leader-s0")
    with Client(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=None) as client:
        led = client.submit(run_point, task, bundle.data, pure=False).result()
        assert led["row"]["status"] == "ok", led["row"]
        assert led["render"]["reused"] is False and "archive" not in led["render"]
        remote = dict(led["render_remote"])
        key = led["render"]["key"]
        sweep = reuse.RenderReuse(tmp_path / "sweep", {"p0": group}, False, log=lambda *a: None)
        sweep.finished(({}, ov, refs, "p0"), led, client)
        assert sweep.stored[group] == [key] and verify(tmp_path / "sweep" / "renders" / key)[0] is not None
        assert not Path(remote["folder"]).exists()          # the worker removed its copy
        ov2 = tuple(TINY + point_overrides(["mask.a"], [0.9], 0))
        task2 = dataclasses.replace(task, overrides=ov2, label="other-s0")
        assert sweep.payload(client, ({}, ov2, refs, "p0")) == []   # pushed to the worker's inbox
        assert len(sweep._scattered[key]) == 1
        got = client.submit(run_point, task2, bundle.data, pure=False).result()
    assert got["row"]["status"] == "ok" and "render_remote" not in got
    assert got["render"] == {"key": key, "reused": True, "rendered_by": "leader-s0"}
    fresh = run_point(dataclasses.replace(task2, render_group=""), bundle.data)
    assert "render" not in fresh
    metrics = [k for k in fresh["row"] if k.startswith("metrics.")]
    assert metrics and all(got["row"][k] == fresh["row"][k] or (np.isnan(got["row"][k]) and np.isnan(fresh["row"][k]))
                           for k in metrics)


def test_a_render_on_a_worker_that_left_is_given_up_not_waited_for(tmp_path, monkeypatch):
    """Moving a render to or from a worker that left the cluster: the tasks pinned to it would
    wait for it for ever; pull reports why (the group renders again) and push reports that it did
    not arrive, each within a few checks, and no staging folder is left behind."""
    import time

    from distributed import Client

    from poevp_optics.apps.sweep import reuse

    monkeypatch.setattr(reuse, "WORKER_CHECK_S", 0.2)
    gone = "tcp://127.0.0.1:1"                 # no worker listens there
    src = tmp_path / "render"
    src.mkdir()
    (src / "frame_0000.npz").write_bytes(b"x" * 100)
    with Client(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=None) as client:
        assert gone not in client.scheduler_info(n_workers=-1)["workers"]
        t0 = time.monotonic()
        folder, why = reuse.pull(client, {"worker": gone, "folder": "/nowhere/poevp-renders-x-1/k",
                                          "files": [("frame_0000.npz", 100)]}, tmp_path / "store", "k")
        assert folder is None and why == f"WorkerGone: worker {gone} left the cluster"
        assert reuse.push(client, gone, src, "k") is False
        assert time.monotonic() - t0 < 30
        assert not list((tmp_path / "store").iterdir())
        # the same calls on the worker that is there run its tasks
        here = next(iter(client.scheduler_info(n_workers=-1)["workers"]))
        assert reuse.on_worker(client, here, pow, 2, 10) == 1024
