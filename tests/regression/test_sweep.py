"""Batch sweeps on Dask (issue 6): table = single runs, kill-and-resume, failed points, bad keys."""

from __future__ import annotations

import math
import io
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

from poevp_optics.core.exceptions import SceneError
from poevp_optics.scene.load import load_scene
from poevp_optics.apps.sweep.sweep import SEED_KEYS, flatten_report, parse_grid, point_overrides, sweep

from ..conftest import ROOT, SCENES

# the default scene made small through the same overrides a user would give
SMALL = ["render.resolution=[46,80]", "timing.frames=3", "render.spp=4", "render.subframes=2",
         "mask.law='threshold_exp'", "predictor.name='oracle'", "outputs.previews=false",
         "outputs.contact_sheet=false"]
GRID = ["timing.exposure_s=0.01,0.02", "mask.a=0.5,0.7,0.9", "mask.b=0.0,0.2"]


def test_grid_syntax():
    assert parse_grid("mask.a=0.5,0.7") == ("mask.a", [0.5, 0.7])
    assert parse_grid("render.spp=4:16:4") == ("render.spp", [4, 8, 12, 16])
    k, v = parse_grid("timing.exposure_s=log:0.001:0.1:3")
    assert np.allclose(v, [0.001, 0.01, 0.1])
    assert parse_grid("render.resolution=[8,8],[16,16]")[1] == [[8, 8], [16, 16]]
    assert parse_grid("predictor.name=hold,'flow'")[1] == ["hold", "flow"]
    for bad in ("mask.a", "mask.a=", "mask.a=1:2:0", "mask.a=log:0:1:3", "mask.a=1,1"):
        with pytest.raises(SceneError):
            parse_grid(bad)


def test_a_results_tables_numpy_values_rerun_as_overrides():
    """A point re-run from its row of results.parquet: NumPy scalars become the TOML literals of
    the values they hold, and the scene loads with them."""
    values = [np.float64(0.02), np.float64(0.7), np.int64(3)]
    ov = point_overrides(["timing.exposure_s", "mask.a", "timing.frames"], values, 0)
    assert ov[:3] == ["timing.exposure_s=0.02", "mask.a=0.7", "timing.frames=3"]
    spec = load_scene(SCENES / "highbeam_plate", SMALL + ov)
    assert (spec.timing.exposure_s, spec.mask.a, spec.timing.frames) == (0.02, 0.7, 3)
    assert point_overrides(["outputs.previews"], [np.bool_(False)], 0)[0] == "outputs.previews=false"


def test_unknown_key_or_bad_value_stops_before_anything_is_written(tmp_path):
    out = tmp_path / "sw"
    with pytest.raises(SceneError, match="mask.nope"):
        sweep(str(SCENES / "highbeam_plate"), ["mask.nope=1,2"], out=out, base_overrides=SMALL,
              progress=False, log=lambda *a: None)
    with pytest.raises(SceneError, match="mask.a"):
        sweep(str(SCENES / "highbeam_plate"), ["mask.a=0.5,1.5"], out=out, base_overrides=SMALL,
              progress=False, log=lambda *a: None)
    assert not out.exists()


#: The sweep the command-line runs below use: points of ~0.5 s each, so that a poll catches a
#: running sweep between its 2nd and 12th point.
SWEEP_SMALL = [s for s in SMALL if not s.startswith(("timing.frames", "render.spp"))] + ["timing.frames=5",
                                                                                         "render.spp=8"]


@pytest.fixture(scope="module")
def grid_sweep(tmp_path_factory):
    """GRID with a third exposure, 0.05 s, that does not fit in a 1/30 s frame: (folder, table)."""
    out = tmp_path_factory.mktemp("grid") / "sw"
    grid = ["timing.exposure_s=0.01,0.02,0.05", *GRID[1:]]
    df = sweep(str(SCENES / "highbeam_plate"), grid, out=out, base_overrides=SWEEP_SMALL, workers=2,
               metric="metrics.saturated_fraction_roi.encoded", progress=False, log=lambda *a: None)
    return out, df


def test_2x3x2_sweep_equals_single_renders_and_records_failures(grid_sweep, tmp_path):
    out, df = grid_sweep
    # the 0.05 s points must fail alone, the others complete
    assert len(df) == 18
    failed = df[df["status"] == "failed"]
    assert set(failed["grid.timing.exposure_s"]) == {0.05} and len(failed) == 6
    assert failed["error"].str.contains("impossible timing").all()
    ok = df[df["status"] == "ok"]
    assert len(ok) == 12 and ok["metrics.saturated_fraction_roi.encoded"].notna().all()
    assert (out / "results.parquet").is_file() and (out / "results.csv").is_file()
    assert (out / "plot_metrics_saturated_fraction_roi_encoded.png").is_file()
    pd.testing.assert_frame_equal(pd.read_parquet(out / "results.parquet"), df)
    # one point run on its own, as `poevp render` runs it, gives the same numbers
    from poevp_optics.apps.run.render_run import run_render

    row = ok.iloc[3]
    values = [row["grid.timing.exposure_s"], row["grid.mask.a"], row["grid.mask.b"]]
    spec = load_scene(SCENES / "highbeam_plate",
                      SWEEP_SMALL + point_overrides(["timing.exposure_s", "mask.a", "mask.b"], values, 0))
    single = tmp_path / "single"
    single.mkdir()
    ref = flatten_report(run_render(spec, single, progress=False))
    compared = 0
    for k, v in ref.items():
        if "seconds" in k or k not in row.index:
            continue
        assert (math.isnan(v) and math.isnan(row[k])) or row[k] == pytest.approx(v, rel=1e-9, abs=1e-12), k
        compared += 1
    assert compared > 10


def _run_cli(out, *extra):
    small = SWEEP_SMALL
    cmd = [sys.executable, "-m", "poevp_optics.cli", "sweep", str(SCENES / "highbeam_plate"),
           "--out", str(out), "--workers", "2", "--quiet", *[a for g in GRID for a in ("--grid", g)],
           *[a for s in small for a in ("--set", s)], *extra]
    return cmd


def _stop_midway(proc, cut, at_least: int, sig) -> None:
    """Send `sig` once the table holds at least `at_least` points and the sweep still runs."""
    t0 = time.time()
    while time.time() - t0 < 300:
        p = cut / "results.parquet"
        # read the bytes once: pyarrow opens a path more than once, and the sweep replaces the
        # file atomically between points, so two opens may see two versions
        if p.is_file() and at_least <= len(pd.read_parquet(io.BytesIO(p.read_bytes()))) < 12:
            break
        if proc.poll() is not None:
            break
        time.sleep(0.05)
    assert proc.poll() is None, ("the sweep finished before it could be killed",
                                 proc.stderr.read().decode()[-2000:] if proc.stderr else "")
    proc.send_signal(sig)


def _by_point(df: pd.DataFrame) -> pd.DataFrame:
    """The reproducible columns, row per point key: a point's results whatever grid it sat in
    (its index in the grid and which render it shared aside)."""
    drop = {"point", "render_by", "render_reused"}
    keep = [c for c in df.columns if "seconds" not in c and c not in drop]
    return df[keep].sort_values(["point_key", "seed"]).reset_index(drop=True)


def test_kill_and_resume_gives_the_uninterrupted_table(grid_sweep, tmp_path):
    """SIGTERM (handled: exit 143), then SIGKILL of the resumed run (no handler runs: its
    in-flight points leave staging folders), then a resume to the end: the table equals the
    uninterrupted one (the same points in `grid_sweep`, run in one go) and no finished point is
    computed twice."""
    cut = tmp_path / "cut"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(_run_cli(cut), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _stop_midway(proc, cut, 2, signal.SIGTERM)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 143, err.decode()[-2000:]
    assert "poevp: terminated (SIGTERM)" in err.decode()
    before = pd.read_parquet(cut / "results.parquet")
    assert 2 <= len(before) < 12
    proc = subprocess.Popen(_run_cli(cut), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _stop_midway(proc, cut, len(before) + 1, signal.SIGKILL)
    proc.communicate(timeout=300)
    killed = pd.read_parquet(cut / "results.parquet")
    assert len(before) < len(killed) < 12
    stamps = {k: (cut / "points" / f"{k}-s0" / "report.json").stat().st_mtime_ns for k in killed["point_key"]}
    subprocess.run(_run_cli(cut), check=True, env=env, capture_output=True, timeout=600)
    after = pd.read_parquet(cut / "results.parquet")
    assert len(after) == 12
    # no finished point was computed again
    for k, ns in stamps.items():
        assert (cut / "points" / f"{k}-s0" / "report.json").stat().st_mtime_ns == ns
    full = grid_sweep[1]
    full = full[full["grid.timing.exposure_s"] != 0.05]
    assert len(full) == 12
    pd.testing.assert_frame_equal(_by_point(after), _by_point(full), check_dtype=False)
    assert not list((cut / "points").glob(".*staging*"))
    assert not list(tmp_path.glob(".cut.*"))
    assert set(SEED_KEYS) and after["status"].eq("ok").all()
