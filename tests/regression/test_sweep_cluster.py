"""Sweeps on a real Dask cluster (issue 21).

A `dask scheduler` (scheduler file, no dashboard) and `dask worker` processes started as a user
would, in another working folder with another HOME and TMPDIR; the client runs from the
repository with a relative scene path. Every point's outputs must equal a LocalCluster run's;
killed workers must not cost points (retries) until the retries are spent; a worker running
another poevp_optics version is refused with one line.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pandas as pd
import pytest

from poevp_optics import __version__
from poevp_optics.cli import main

from tests.conftest import ROOT
from tests.regression.bit_identical import hash_outputs

DASK = Path(sys.executable).with_name("dask")
GRID = ["--grid", "mask.target=0.3,0.6", "--grid", "timing.exposure_s=0.01,0.02"]   # 2 x 2 smoke points
SCENE = "scenes/smoke"                  # relative to the client's folder, not the workers'


class DaskProcesses:
    """A scheduler and workers as subprocesses in their own folder, HOME and TMPDIR."""

    def __init__(self, root: Path):
        self.root = root
        self.work, self.home, self.tmp, self.logs = (root / n for n in ("work", "home", "tmp", "logs"))
        for d in (self.work, self.home, self.tmp, self.logs):
            d.mkdir(parents=True)
        self.scheduler_file = root / "scheduler.json"
        self.procs: list[subprocess.Popen] = []
        self.workers: dict[str, subprocess.Popen] = {}

    def _env(self, pythonpath: Path) -> dict:
        env = {k: v for k, v in os.environ.items() if k not in ("POEVP_CACHE_DIR", "PYTHONPATH")}
        return {**env, "HOME": str(self.home), "TMPDIR": str(self.tmp), "PYTHONPATH": str(pythonpath),
                # the scheduler reports a killed worker's points at once, so poevp's --retries
                # alone decides whether they run again (Dask's default reschedules 3 times itself)
                "DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES": "0"}

    def _start(self, args: list[str], name: str, pythonpath: Path) -> subprocess.Popen:
        log = open(self.logs / f"{name}.log", "wb")
        p = subprocess.Popen([str(DASK), *args], cwd=self.work, env=self._env(pythonpath), stdout=log,
                             stderr=subprocess.STDOUT, start_new_session=True)
        log.close()
        self.procs.append(p)
        return p

    def start_scheduler(self) -> Path:
        self._start(["scheduler", "--no-dashboard", "--host", "127.0.0.1", "--port", "0",
                     "--scheduler-file", str(self.scheduler_file)], "scheduler", ROOT)
        t0 = time.time()
        while not self.scheduler_file.is_file():
            assert time.time() - t0 < 60, (self.logs / "scheduler.log").read_text()[-2000:]
            time.sleep(0.1)
        return self.scheduler_file

    def start_worker(self, name: str, pythonpath: Path = ROOT) -> subprocess.Popen:
        # no nanny: the worker process is the one a test kills, as a lost machine would vanish
        p = self._start(["worker", "--scheduler-file", str(self.scheduler_file), "--nthreads", "1",
                         "--no-nanny", "--name", name], name, pythonpath)
        self.workers[name] = p
        return p

    def wait_workers(self, n: int, timeout_s: float = 120) -> None:
        from distributed import Client

        # running, not only registered: a worker registers first, then reports that it runs, and
        # the scheduler sends scattered data (the scene bundle) only to running workers
        with Client(scheduler_file=str(self.scheduler_file), timeout=30) as c:
            t0 = time.time()
            while sum(w["status"] == "running" for w in c.scheduler_info(n_workers=-1)["workers"].values()) != n:
                assert time.time() - t0 < timeout_s, f"{n} workers did not connect"
                time.sleep(0.2)

    def stop(self) -> None:
        """SIGTERM, then SIGKILL to what still runs after 3 s (a worker's graceful close can
        wait on its running task); every process is reaped."""
        for p in self.procs:
            if p.poll() is None:
                p.terminate()
        deadline = time.time() + 3
        for p in self.procs:
            try:
                p.wait(timeout=max(0.1, deadline - time.time()))
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(timeout=10)


@pytest.fixture
def dask_processes(tmp_path):
    procs = DaskProcesses(tmp_path / "dask")
    try:
        yield procs
    finally:
        procs.stop()                    # every process, however the test ended


class KillFirstBusyWorker(threading.Thread):
    """SIGKILL the worker process whose point folder (poevp-point-<host>-<pid>-*) appears first
    in the workers' TMPDIR: a worker lost in the middle of a point."""

    def __init__(self, procs: DaskProcesses):
        super().__init__(daemon=True)
        self.procs, self.killed, self.stop = procs, None, threading.Event()

    def run(self):
        pids = {p.pid: name for name, p in self.procs.workers.items() if p.poll() is None}

        while not self.stop.is_set():
            for d in self.procs.tmp.glob("poevp-point-*"):
                pid = int(re.match(r"poevp-point-[^-]+-(\d+)-", d.name).group(1))
                if pid in pids:
                    os.kill(pid, signal.SIGKILL)
                    self.procs.workers[pids[pid]].wait()      # reaped, as its parent would
                    self.killed = pids[pid]
                    return
            time.sleep(0.005)


def _points(out: Path) -> dict[str, tuple[dict, dict]]:
    """Point folder -> (hashes of its arrays and report, report without timing fields)."""

    def untimed(obj):
        if isinstance(obj, dict):
            return {k: untimed(v) for k, v in obj.items() if "seconds" not in k}
        if isinstance(obj, list):
            return [untimed(v) for v in obj]
        return obj

    return {p.name: (hash_outputs(p), untimed(json.loads((p / "report.json").read_text())))
            for p in sorted((out / "points").iterdir()) if p.is_dir()}


def _sweep(capsys, *args) -> tuple[int, str]:
    rc = main(["sweep", SCENE, *GRID, "--quiet", *args])
    io = capsys.readouterr()
    return rc, io.out + io.err


@pytest.mark.slow
def test_cluster_sweep_in_other_folders_equals_local_cluster_and_survives_killed_workers(
        tmp_path, monkeypatch, capsys, dask_processes):
    procs = dask_processes
    sf = procs.start_scheduler()
    procs.start_worker("w0")
    procs.start_worker("w1")
    monkeypatch.chdir(ROOT)
    assert not (procs.work / SCENE).exists()          # a worker resolving the path itself fails
    # the reference: an embedded LocalCluster on this machine, which serves a dashboard
    rc, text = _sweep(capsys, "--out", str(tmp_path / "local"), "--workers", "1")
    assert rc == 0, text
    assert re.search(r"Dask dashboard http://\S+/status", text)
    local = _points(tmp_path / "local")
    assert len(local) == 4
    # the same sweep on the external cluster: a scene bundle, outputs written by the client
    procs.wait_workers(2)
    rc, text = _sweep(capsys, "--out", str(tmp_path / "external"), "--scheduler-file", str(sf))
    assert rc == 0, text
    assert "scene bundle of 4 files" in text        # TOML, XML, plate texture, QE table
    assert "dashboard" not in text                  # the scheduler serves none: no link
    assert _points(tmp_path / "external") == local
    for name in local:
        report = json.loads((tmp_path / "external" / "points" / name / "report.json").read_text())
        assert report["scene_file"] == str(ROOT / SCENE / "scene.toml")   # the client's file, not a copy
    # --shared-fs: nothing sent, the workers read (and hash) this machine's paths
    rc, text = _sweep(capsys, "--out", str(tmp_path / "shared"), "--scheduler-file", str(sf), "--shared-fs")
    assert rc == 0, text
    assert "scene bundle" not in text and "(--shared-fs), verified on each worker" in text
    assert _points(tmp_path / "shared") == local
    assert not list(procs.work.iterdir())           # workers wrote nothing in their folder ...
    assert not list(procs.tmp.glob("poevp-point-*"))  # ... and removed their point folders
    # a worker killed in the middle of a point: the point runs again on the other one
    killer = KillFirstBusyWorker(procs)
    killer.start()
    rc, text = _sweep(capsys, "--out", str(tmp_path / "killed"), "--scheduler-file", str(sf))
    killer.stop.set()
    assert rc == 0, text
    assert killer.killed, "no worker was caught in a point"
    assert re.search(r"its worker was lost \(KilledWorker\); running it again \(retry 1 of 2\)", text), text
    df = pd.read_parquet(tmp_path / "killed" / "results.parquet")
    assert len(df) == 4 and (df["status"] == "ok").all()
    assert _points(tmp_path / "killed") == local
    first_killed = killer.killed
    # with --retries 0 the points of a killed worker become failed rows; --retry-failed reruns them
    procs.start_worker("w2")
    procs.wait_workers(2)
    killer = KillFirstBusyWorker(procs)
    killer.start()
    rc, text = _sweep(capsys, "--out", str(tmp_path / "noretry"), "--scheduler-file", str(sf), "--retries", "0")
    killer.stop.set()
    assert killer.killed and killer.killed != first_killed
    assert rc == 1, text
    df = pd.read_parquet(tmp_path / "noretry" / "results.parquet")
    failed = df[df["status"] == "failed"]
    # the point it ran and those it held: how many it held is the scheduler's choice (one
    # worker was seen holding all 4 on a loaded machine); every other point ran to "ok"
    assert len(df) == 4 and len(failed) >= 1 and (df["status"] != "failed").sum() == (df["status"] == "ok").sum()
    assert failed["error"].str.startswith("worker lost 1 times (KilledWorker").all()
    assert not any((tmp_path / "noretry" / "points" / f"{k}-s0").exists() for k in failed["point_key"])
    rc, text = _sweep(capsys, "--out", str(tmp_path / "noretry"), "--scheduler-file", str(sf), "--retry-failed")
    assert rc == 0, text
    assert _points(tmp_path / "noretry") == local
    assert not list(procs.tmp.glob("poevp-point-*"))   # the killed workers' folders were removed too


def test_a_worker_with_another_poevp_version_is_refused(tmp_path, monkeypatch, capsys, dask_processes):
    """A worker importing a copy of the package whose version string differs (as an older
    install would): the sweep stops before writing anything, with one line naming the worker,
    the package and both versions."""
    procs = dask_processes
    pkg = tmp_path / "other_install"
    shutil.copytree(ROOT / "poevp_optics", pkg / "poevp_optics", ignore=shutil.ignore_patterns("__pycache__"))
    init = pkg / "poevp_optics" / "core" / "version.py"          # the one definition of __version__
    text, n = re.subn(r'__version__ = "[^"]+"', f'__version__ = "{__version__}+other"', init.read_text())
    assert n == 1
    init.write_text(text)
    sf = procs.start_scheduler()
    procs.start_worker("old", pythonpath=pkg)
    procs.wait_workers(1)
    monkeypatch.chdir(ROOT)
    out = tmp_path / "sw"
    rc = main(["sweep", SCENE, *GRID, "--quiet", "--out", str(out), "--scheduler-file", str(sf)])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert re.fullmatch(rf"poevp: error: worker tcp://127\.0\.0\.1:\d+: poevp_optics {re.escape(__version__)}"
                        rf"\+other there, {re.escape(__version__)} here; install the same software on every "
                        r"worker", err), err
    assert not out.exists()


@pytest.mark.slow
def test_a_sweep_sends_its_scene_bundle_again_when_every_worker_holding_it_is_lost(
        tmp_path, monkeypatch, capsys, dask_processes):
    """The only worker that holds the scene bundle dies in the middle of a point, and another
    joins afterwards: the scheduler forgets the bundle (scattered data has no recipe) and with
    it every point that needs it. The sweep sends the bundle again and runs those points; the
    points the dead worker held count one worker loss each, the others none."""
    procs = dask_processes
    sf = procs.start_scheduler()
    procs.start_worker("w0")
    procs.wait_workers(1)
    monkeypatch.chdir(ROOT)

    class KillThenJoin(KillFirstBusyWorker):
        def run(self):
            super().run()
            if self.killed:
                procs.start_worker("w1")

    killer = KillThenJoin(procs)
    killer.start()
    rc, text = _sweep(capsys, "--out", str(tmp_path / "lost"), "--scheduler-file", str(sf))
    killer.stop.set()
    killer.join(timeout=10)
    assert killer.killed == "w0"
    assert rc == 0, text
    assert "poevp sweep: the scene bundle was lost with every worker that held it; sending it again" in text, text
    df = pd.read_parquet(tmp_path / "lost" / "results.parquet")
    assert len(df) == 4 and (df["status"] == "ok").all(), df
    assert len(_points(tmp_path / "lost")) == 4
