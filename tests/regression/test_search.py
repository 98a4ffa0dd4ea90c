"""`poevp search` (apps/search/): a tiny search finds a better objective than its worst trial and
writes its table, plot and best settings; a search killed mid-run resumes from its own state
without running a finished trial again; bad questions are one line before anything runs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

from poevp_optics.apps.search.space import Constraint, metric_value, parse_param
from poevp_optics.cli import main
from poevp_optics.core.exceptions import SceneError
from tests.conftest import ROOT, SCENES

#: smoke at 24x32, 3 frames (the last after the two white initialisation frames)
TINY = ["--set", "render.resolution=[24,32]", "--set", "timing.frames=3", "--set", "outputs.previews=false",
        "--set", "outputs.contact_sheet=false", "--quiet"]
#: the plate's entropy in the encoded capture: the `target` law's aim and the mask's blur move it
#: (0.05 -> 2.6 bits, 0.8 -> 4.3 bits at this size), neither moves the render
QUESTION = ["--param", "mask.target=0.05:1.0", "--param", "mask.smooth_px=0.0:6.0",
            "--maximize", "metrics.entropy_roi.encoded_after_init", "--sampler-seed", "3"]
METRIC = "metrics.entropy_roi.encoded_after_init"


def test_param_syntax_and_metrics():
    assert parse_param("mask.a=0.5:1.0").kind == "float"
    p = parse_param("render.spp=4:16")
    assert (p.kind, p.low, p.high) == ("int", 4, 16)
    assert parse_param("mask.vs=log:50:250").kind == "log"
    c = parse_param("predictor.name=hold,flow,track_net")
    assert c.kind == "choice" and c.choices == ('"hold"', '"flow"', '"track_net"')
    for bad in ("mask.a", "mask.a=1:0.5", "mask.a=log:0:1", "mask.a=0.5", "predictor.name=hold,hold"):
        with pytest.raises(SceneError):
            parse_param(bad)
    report = {"metrics": {"x": 0.25, "flag": True}, "timing_budget": {"late_frames": [3, 7]}}
    assert metric_value(report, "metrics.x") == 0.25 and metric_value(report, "metrics.flag") == 1.0
    assert metric_value(report, "timing_budget.late_frames") == 2.0          # a list counts its entries
    assert Constraint("timing_budget.late_frames", "<=", 0).violation(2.0) == 2.0
    with pytest.raises(Exception, match="no 'nope' under metrics .*it has: flag, x"):
        metric_value(report, "metrics.nope")


def test_a_bad_question_is_one_line_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["search", str(SCENES / "smoke"), *TINY, "--param", "mask.nope=0:1", "--minimize", "metrics.x",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "mask.nope" in err[0]
    assert main(["search", str(SCENES / "smoke"), *TINY, "--param", "mask.target=0.3:1.5", "--minimize",
                 "metrics.x", "--out", str(out)]) == 2
    assert "mask.target" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.slow
def test_a_tiny_search_improves_on_its_worst_trial(tmp_path, capsys):
    out = tmp_path / "s"
    rc = main(["search", str(SCENES / "smoke"), *TINY, *QUESTION, "--trials", "6", "--startup-trials", "3",
               "--workers", "2", "--out", str(out)])
    text = capsys.readouterr()
    assert rc == 0, text.err
    df = pd.read_parquet(out / "trials.parquet")
    assert len(df) == 6 and (df["state"] == "ok").all() and df["trial"].tolist() == list(range(6))
    assert df["objective"].min() < df["objective"].max()        # the best beats the worst
    assert (out / "search_plot.png").stat().st_size > 1000 and (out / "trials.csv").is_file()
    best = json.loads((out / "best.json").read_text())
    row = df.loc[df["objective"].idxmax()]
    assert best["trial"] == row["trial"] and best["objective"] == row["objective"]
    assert f"settings: {best['set_line']}" in text.out
    # the ready --set line reproduces the best trial's point, as `poevp render` runs it
    folder = out / "points" / best["points"][0]
    report = json.loads((folder / "report.json").read_text())
    assert metric_value(report, METRIC) == best["objective"]
    assert best["set_line"].startswith("--set mask.target=") and "--set mask.smooth_px=" in best["set_line"]
    # every trial's values are within its bounds; all points share one render
    assert df["param.mask.target"].astype(float).between(0.05, 1.0).all()
    assert df["param.mask.smooth_px"].astype(float).between(0.0, 6.0).all()
    assert len(list((out / "renders").iterdir())) == 1 and df["reused_points"].sum() == 5


def _cli(out, trials):
    return [sys.executable, "-m", "poevp_optics.cli", "search", str(SCENES / "smoke"), *TINY, *QUESTION,
            "--trials", str(trials), "--startup-trials", "2", "--workers", "1", "--out", str(out)]


@pytest.mark.slow
def test_a_killed_search_resumes_without_repeating_finished_trials(tmp_path):
    out = tmp_path / "s"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(_cli(out, 5), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    t0 = time.time()
    while time.time() - t0 < 300 and proc.poll() is None:        # stop it after 2 finished trials
        p = out / "trials.parquet"
        try:
            if p.is_file() and len(pd.read_parquet(p)) >= 2:
                break
        except Exception:  # noqa: BLE001 - replaced between two reads
            pass
        time.sleep(0.05)
    assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err.decode()[-2000:]
    before = pd.read_parquet(out / "trials.parquet")
    finished = before[before["state"] == "ok"]
    assert 2 <= len(finished) < 5
    stamps = {f: (out / "points" / f / "report.json").stat().st_mtime_ns
              for pts in finished["points"] for f in pts.split(";")}
    done = subprocess.run(_cli(out, 5), env=env, capture_output=True, timeout=600)
    assert done.returncode == 0, done.stderr.decode()[-2000:]
    after = pd.read_parquet(out / "trials.parquet")
    ok = after[after["state"] == "ok"]
    assert len(ok) == 5                                         # the total, not 5 more
    for _, r in finished.iterrows():                            # finished trials kept as they were
        again = after[after["trial"] == r["trial"]].iloc[0]
        assert again["objective"] == r["objective"] and again["points"] == r["points"]
    for f, ns in stamps.items():                                # and their points never ran again
        assert (out / "points" / f / "report.json").stat().st_mtime_ns == ns
    # trials stopped mid-run are marked and asked again with the values drawn before the kill
    # (one stopped before a value was drawn has none for it: that value is drawn anew)
    keys = ["param.mask.target", "param.mask.smooth_px"]
    for _, r in after[(after["state"] == "interrupted") & after["param.mask.target"].notna()].iterrows():
        drawn = [k for k in keys if pd.notna(r[k])]
        assert np.logical_and.reduce([ok[k] == r[k] for k in drawn]).any()
