"""Runs killed or failing half-way lose nothing (issue 14): render, chart and sweep under SIGTERM,
SIGKILL and an exception (the sweep's SIGTERM and SIGKILL: test_sweep.py; its exception:
test_sweep_record.py). Earlier outputs stay byte-identical; SIGTERM exits 143 with one line
and removes its staging folder at once; after SIGKILL the next run into the same folder removes
the staging folder the killed one left; two runs into one folder: the second refuses.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from poevp_optics.cli import main
from tests.conftest import ROOT, SCENES

ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
# a render of a few seconds, so a signal lands while it works
SLOW_RENDER = ["--quiet", "--frames", "8", "--resolution", "64x96", "--spp", "16"]
QUICK_RENDER = ["--quiet", "--frames", "1", "--resolution", "8x8"]
# the DR chart made small (36 patches of ~20 px) but still seconds long
CHART = ["--quiet", "--resolution", "160x160", "--set", "predictor.resolution=[160,160]",
         "--set", "chart.repeats=8", "--set", "chart.max_iterations=4"]
# ... and long enough that a signal 1 s in lands mid-run on any machine: 800 repeats are ~4 s of
# captures after the chart's render (48 repeats were 0.2 s, so a 1.5 s wait raced the run's end in CI)
SLOW_CHART = [*CHART[:-4], "--set", "chart.repeats=800", "--set", "chart.max_iterations=4"]


def tree(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def earlier_output(out: Path, kind: str) -> dict[str, str]:
    """A previous poevp output of `kind` in `out` (what a killed run must not touch)."""
    out.mkdir(parents=True)
    (out / ".poevp-output.json").write_text(json.dumps({"kind": kind}) + "\n")
    (out / "report.json").write_text('{"scene": "the earlier run"}\n')
    (out / "capture").mkdir()
    (out / "capture" / "frame_0000.png").write_bytes(b"earlier capture bytes")
    return tree(out)


def debris(out: Path) -> list[str]:
    return sorted(p.name for p in out.parent.glob(f".{out.name}.*"))


def start(args: list[str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "poevp_optics.cli", *args], env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for(cond, proc: subprocess.Popen, timeout: float = 120.0) -> None:
    t0 = time.time()
    while not cond():
        assert proc.poll() is None, ("finished before it could be killed", proc.stderr.read()[-2000:])
        assert time.time() - t0 < timeout, "timed out waiting"
        time.sleep(0.05)


def staging_has(out: Path, pattern: str):
    return lambda: any(any(s.glob(pattern)) for s in out.parent.glob(f".{out.name}.staging-*"))


@pytest.mark.parametrize("command,scene,args,kind,pattern", [
    ("render", "smoke", SLOW_RENDER, "render", "radiance/frame_0001.exr"),
    ("chart", "dr_chart36", SLOW_CHART, "chart", ".poevp-output.json"),
], ids=["render", "chart"])
def test_sigterm_then_sigkill_then_next_run(tmp_path, command, scene, args, kind, pattern):
    out = tmp_path / "out"
    kept = earlier_output(out, kind)
    # SIGTERM: message, exit 143, staging removed at once, earlier output untouched
    p = start([command, str(SCENES / scene), "--out", str(out), *args])
    wait_for(staging_has(out, pattern), p)
    if command == "chart":
        time.sleep(1.0)                       # into the render / captures
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 143, err
    assert len(err.strip().splitlines()) == 1 and "terminated" in err and "Traceback" not in err, err
    assert tree(out) == kept and debris(out) == []
    # SIGKILL: no cleanup possible; the earlier output is still untouched
    p = start([command, str(SCENES / scene), "--out", str(out), *args])
    wait_for(staging_has(out, pattern), p)
    p.kill()
    p.communicate(timeout=60)
    assert tree(out) == kept
    assert [n for n in debris(out) if ".staging-" in n], "SIGKILL leaves its staging folder"
    # the next run into the same folder cleans up and replaces the output whole
    quick = QUICK_RENDER if command == "render" else CHART
    assert main([command, str(SCENES / scene), "--out", str(out), *quick]) == 0
    assert debris(out) == []
    assert tree(out) != kept and (out / "report.json").is_file()
    assert json.loads((out / ".poevp-output.json").read_text())["kind"] == kind


@pytest.mark.parametrize("command,scene,args,kind,target", [
    ("render", "smoke", QUICK_RENDER, "render", "poevp_optics.apps.run.outputs.write_exr"),
    ("chart", "dr_chart36", CHART, "chart", "poevp_optics.apps.run.chart.write_exr"),
], ids=["render", "chart"])
def test_exception_midway_leaves_earlier_output(tmp_path, monkeypatch, capsys, command, scene, args, kind,
                                                target):
    out = tmp_path / "out"
    kept = earlier_output(out, kind)

    def broken(*a, **k):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(target, broken)
    capsys.readouterr()
    assert main([command, str(SCENES / scene), "--out", str(out), *args]) == 1   # one line (issue 28)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "RuntimeError: disk on fire" in err[0], err
    assert tree(out) == kept and debris(out) == []


def test_second_run_into_a_busy_folder_refuses(tmp_path):
    out = tmp_path / "out"
    p = start(["render", str(SCENES / "smoke"), "--out", str(out), *SLOW_RENDER])
    wait_for(staging_has(out, "*"), p)
    p.send_signal(signal.SIGSTOP)      # held mid-run (its lock too) on any machine, however fast
    try:
        r = subprocess.run([sys.executable, "-m", "poevp_optics.cli", "render", str(SCENES / "smoke"),
                            "--out", str(out), *QUICK_RENDER], env=ENV, capture_output=True, text=True,
                           timeout=120)
    finally:
        p.send_signal(signal.SIGCONT)
    assert r.returncode == 2 and "another poevp process" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    _, err = p.communicate(timeout=300)
    assert p.returncode == 0, err                  # the first run was not disturbed
    assert json.loads((out / "report.json").read_text())["frames"] == 8
    assert debris(out) == []
