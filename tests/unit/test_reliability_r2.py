"""Reliability, second round (issue 28): every failure one line, runs sized before they start,
sweep state verified on resume, validate agrees with render, trajectories checked.

Each family runs as a user meets it: real temporary folders, real symbolic-link loops, real
damaged files; the command line in a subprocess where the exit status and the stderr line count
are the point (a traceback would show there), in-process where a writer must be made to fail
(disk full: the writer raises ENOSPC as the kernel would).
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import random
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from poevp_optics.cli import main
from tests.conftest import ROOT, SCENES

SMOKE = SCENES / "smoke"
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def poevp(*args, cwd=None, env=None, timeout=300):
    """Run `poevp ARGS` in a fresh interpreter: (exit status, stdout, non-empty stderr lines)."""
    r = subprocess.run([sys.executable, "-m", "poevp_optics.cli", *map(str, args)], cwd=cwd,
                       env={**ENV, **(env or {})}, capture_output=True, text=True, timeout=timeout)
    return r.returncode, r.stdout, [ln for ln in r.stderr.splitlines() if ln.strip()]


def one_line(rc, lines, want_rc=2, *names):
    assert rc == want_rc, (rc, lines)
    assert len(lines) == 1, lines
    assert "Traceback" not in lines[0]
    for n in names:
        assert str(n) in lines[0], (n, lines[0])
    return lines[0]


def snapshot(root: Path) -> dict:
    return {str(p.relative_to(root)): (hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir")
            for p in sorted(root.rglob("*")) if not p.is_symlink()}


@pytest.fixture
def scene(tmp_path):
    d = tmp_path / "scene"
    shutil.copytree(SMOKE, d)
    return d


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))


# ---------------------------------------------------------------------------- error boundary
def test_oserrors_are_classified_by_errno():
    from poevp_optics.core.failures import describe

    msg, rc = describe(OSError(errno.ENOSPC, "No space left on device", "/x/frame.exr"))
    assert rc == 1 and "/x/frame.exr" in msg and "nothing already written was lost" in msg
    for code in (errno.ENAMETOOLONG, errno.ELOOP, errno.EACCES, errno.EROFS):
        msg, rc = describe(OSError(code, os.strerror(code), "/some/path"))
        assert rc == 2 and "/some/path" in msg and "\n" not in msg
    assert describe(RecursionError())[1] == 2
    assert describe(MemoryError())[1] == 1
    # an OSError in the cause chain decides, whatever wraps it
    try:
        try:
            raise OSError(errno.EMFILE, "Too many open files")
        except OSError as e:
            raise RuntimeError("wrapped") from e
    except RuntimeError as e:
        assert describe(e)[1] == 1


def test_internal_error_is_one_line_and_debug_shows_the_traceback(monkeypatch, capsys):
    import poevp_optics.cli as cli

    def broken(args):
        raise TypeError("a bug\nwith two lines")

    monkeypatch.setattr(cli, "cmd_info", broken)
    assert main(["info"]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "internal error TypeError: a bug with two lines" in err
    assert "--debug" in err
    with pytest.raises(TypeError):
        main(["--debug", "info"])
    monkeypatch.setenv("POEVP_DEBUG", "1")
    with pytest.raises(TypeError):
        main(["info"])


def test_hostile_out_paths_and_threads_are_one_line(scene, tmp_path):
    (tmp_path / "loop1").symlink_to(tmp_path / "loop2")
    (tmp_path / "loop2").symlink_to(tmp_path / "loop1")
    before = snapshot(tmp_path)
    for out in ("loop1", "loop1/x"):
        rc, _, err = poevp("render", scene, "--out", tmp_path / out, "--quiet")
        one_line(rc, err, 2, "--out", "loop")
    rc, _, err = poevp("render", scene, "--out", tmp_path / ("a" * 300), "--quiet")
    one_line(rc, err, 2, "--out", "300 bytes")
    rc, _, err = poevp("render", scene, "--threads", "100000", "--quiet", "--out", tmp_path / "o")
    one_line(rc, err, 2, "--threads", "100000")
    assert snapshot(tmp_path) == before


# ---------------------------------------------------------------------------- disk
def test_disk_full_while_writing_keeps_the_old_output(scene, tmp_path, monkeypatch, capsys):
    """The first PNG write fails as on a full disk: one line naming the file as in --out, exit
    1, the previous output byte-identical, no staging folder left."""
    import poevp_optics.core.io as io

    out = tmp_path / "out"
    assert main(["render", str(scene), "--out", str(out), "--quiet", "--frames", "1"]) == 0
    capsys.readouterr()
    from poevp_optics.apps.run.run_size import estimate
    from poevp_optics.scene.load import load_scene

    written = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    bound = estimate(load_scene(scene, ["timing.frames=1"])).disk_bytes
    assert written <= bound, (written, bound)          # the disk estimate is an upper bound
    before = snapshot(tmp_path)
    monkeypatch.setattr(io.cv2, "imwrite", lambda *a, **k: False)
    monkeypatch.setattr(io, "free_bytes", lambda p: 4096 if "staging" in str(p) else 1 << 40)
    assert main(["render", str(scene), "--out", str(out), "--quiet", "--frames", "2"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "No space left on device" in err[0] and str(out / "capture") in err[0], err
    assert snapshot(tmp_path) == before
    assert not list(tmp_path.glob(".out.staging-*"))


def test_free_space_is_checked_before_any_work(scene, tmp_path, monkeypatch, capsys):
    import poevp_optics.core.io as io

    monkeypatch.setattr(io, "free_bytes", lambda p: 10_000)
    assert main(["render", str(scene), "--out", str(tmp_path / "o"), "--quiet", "--yes"]) == 2
    err = capsys.readouterr().err
    assert "needs about" in err and "free there" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------------------- run size
def test_validate_prints_the_run_size_and_limits_refuse_before_work(scene, tmp_path):
    rc, out, err = poevp("validate", scene)
    assert rc == 0 and "run size: about" in out and "on disk" in out, (out, err)
    t0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    rc, _, err = poevp("render", scene, "--frames", "100000", "--resolution", "1080x1920",
                       "--out", tmp_path / "big", "--quiet")
    t1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    line = one_line(rc, err, 2, "CPU", "on disk", "--yes")
    assert "POEVP_MAX_CPU_HOURS" in line and not (tmp_path / "big").exists()
    assert (t1.ru_utime - t0.ru_utime) + (t1.ru_stime - t0.ru_stime) < 10.0
    # a small stated limit refuses the smoke scene in validate as in render; --yes lets it through
    small = {"POEVP_MAX_CPU_HOURS": "0.0001"}
    one_line(*poevp("validate", scene, env=small)[::2], 2, "--yes")
    rc, out, _ = poevp("validate", scene, "--yes", "--no-load", env=small)
    assert rc == 0
    assert poevp("validate", scene, "--force", "--no-load", env=small)[0] == 0    # the alias


def test_run_size_scales_as_its_formula():
    from poevp_optics.apps.run.run_size import CPU_S_PER_SAMPLE, estimate
    from poevp_optics.scene.load import load_scene

    a = estimate(load_scene(SMOKE, ["timing.frames=2"]))
    b = estimate(load_scene(SMOKE, ["timing.frames=4"]))
    b2 = estimate(load_scene(SMOKE, ["timing.frames=6"]))
    c = estimate(load_scene(SMOKE, ["timing.frames=2", "render.spp=8"]))
    # disk and CPU are affine in the frames; spp adds path samples (CPU) only
    assert b2.disk_bytes - b.disk_bytes == pytest.approx(b.disk_bytes - a.disk_bytes, abs=2)
    assert b2.cpu_seconds - b.cpu_seconds == pytest.approx(b.cpu_seconds - a.cpu_seconds)
    spec = load_scene(SMOKE, ["timing.frames=2"])
    from poevp_optics.apps.run.memory import radiance_samples, rendered_grid

    h, w = rendered_grid(spec)
    assert c.cpu_seconds - a.cpu_seconds == pytest.approx(2 * radiance_samples(spec) * h * w * 4 * CPU_S_PER_SAMPLE)
    assert c.disk_bytes == a.disk_bytes


def _peak_rss_kib(*args) -> tuple[int, int, float, list[str]]:
    """(peak RSS in KiB, CPU s, stderr lines) of `poevp ARGS` alone: measured by a wrapper process
    whose only child is that run (RUSAGE_CHILDREN of the test process would also hold every
    earlier test's children)."""
    code = ("import resource, subprocess, sys; r = subprocess.run(sys.argv[1:], capture_output=True, text=True); "
            "u = resource.getrusage(resource.RUSAGE_CHILDREN); sys.stderr.write(r.stderr); "
            "print(u.ru_maxrss, u.ru_utime + u.ru_stime); sys.exit(r.returncode)")
    r = subprocess.run([sys.executable, "-c", code, sys.executable, "-m", "poevp_optics.cli", *map(str, args)],
                       env=ENV, capture_output=True, text=True, timeout=300)
    rss, cpu = r.stdout.split()
    return r.returncode, int(rss), float(cpu), [ln for ln in r.stderr.splitlines() if ln.strip()]


def test_sweep_bounds_are_refused_before_allocating(scene, tmp_path):
    rc, rss_kib, cpu_s, err = _peak_rss_kib("sweep", scene, "--grid", "mask.a=0:1:1000000000", "--out", tmp_path / "sw")
    one_line(rc, err, 2, "--grid", "1000000000")
    assert rss_kib < 2 << 20                             # KiB: well under 2 GiB (7.45 GiB before)
    assert cpu_s < 10.0
    one_line(*poevp("sweep", scene, "--grid", "mask.a=0:1:200", "--seeds", "100", "--out",
                    tmp_path / "sw")[::2], 2, "20000 runs")
    one_line(*poevp("sweep", scene, "--grid", "mask.a=0.5", "--seeds", "1000000", "--out",
                    tmp_path / "sw")[::2], 2, "--seeds")
    assert not (tmp_path / "sw").exists()


def test_sweep_free_space_is_checked_before_writing(scene, tmp_path, monkeypatch, capsys):
    import poevp_optics.core.io as io

    monkeypatch.setattr(io, "free_bytes", lambda p: 10_000)
    assert main(["sweep", str(scene), "--grid", "timing.frames=1,2", "--out", str(tmp_path / "sw")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "this sweep (2 points x 1 seeds) needs about" in err[0]
    assert not (tmp_path / "sw").exists()


# ---------------------------------------------------------------------------- sweep state
def test_sweep_state_is_verified_on_resume(scene, tmp_path, monkeypatch, capsys):
    import pandas as pd

    import poevp_optics.apps.sweep.sweep as sw

    out = tmp_path / "sw"
    argv = ["sweep", str(scene), "--grid", "timing.frames=1,2", "--workers", "1", "--out", str(out),
            "--quiet"]
    assert main(argv) == 0
    capsys.readouterr()
    good = pd.read_parquet(out / "results.parquet")
    table = (out / "results.parquet").read_bytes()
    # a truncated table: one line naming it, nothing changed; --rebuild restores it from the reports
    (out / "results.parquet").write_bytes(table[:100])
    before = snapshot(out)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "results.parquet" in err[0] and "--rebuild" in err[0]
    assert snapshot(out) == before
    assert main(argv + ["--rebuild"]) == 0
    capsys.readouterr()
    rebuilt = pd.read_parquet(out / "results.parquet")
    cols = [c for c in good.columns if "seconds" not in c]
    pd.testing.assert_frame_equal(rebuilt[cols], good[cols])
    # a manifest that is not JSON, then one of the wrong shape
    for bad in ("{not json", json.dumps({"scene": 3})):
        (out / "sweep.json").write_text(bad)
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "sweep.json" in err[0] and "--rebuild" in err[0]
        assert main(argv + ["--rebuild"]) == 0
        capsys.readouterr()
    # a finished point whose folder was deleted runs again
    gone = sorted((out / "points").iterdir())[0]
    shutil.rmtree(gone)
    assert main(argv) == 0
    capsys.readouterr()
    assert (gone / "report.json").is_file()
    # disk full while the table is written: one line, exit 1, every point kept
    shutil.rmtree(gone)

    def full(rows, folder):
        raise OSError(errno.ENOSPC, "No space left on device", str(folder / "results.parquet"))

    monkeypatch.setattr(sw, "write_table", full)
    kept = snapshot(out)
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "No space left on device" in err[0] and "results.parquet" in err[0]
    assert all(snapshot(out).get(k) == v for k, v in kept.items() if k.startswith("points"))


# ---------------------------------------------------------------------------- validate = render
@pytest.mark.parametrize("case", ["include", "unused_default", "texture"])
def test_validate_refuses_what_render_refuses(case, scene, tmp_path):
    xml = scene / "scene.xml"
    if case == "include":
        _edit(xml, "<integrator", '<include filename="missing.xml"/>\n    <integrator')
        names = ("scene.xml", "missing.xml")
    elif case == "unused_default":
        _edit(xml, 'value="$ink"', 'value="0.03"')
        names = ("scene.xml", "$ink", "spectra.ink")
    else:
        (scene / "fake.png").write_text("not an image\n")
        _edit(xml, "plates/plate_B4713.png", "fake.png")
        names = ("fake.png", "texture")
    for args in (["validate", scene, "--no-load"], ["validate", scene],
                 ["render", scene, "--out", tmp_path / "o", "--quiet"]):
        one_line(*poevp(*args)[::2], 2, *names)
    assert not (tmp_path / "o").exists()


def test_mitsuba_loader_errors_name_file_line_and_key(scene):
    """Mitsuba's own messages for the three cases, translated (the static checks above come
    first in a run; this is what a case they miss would print)."""
    import mitsuba as mi

    from poevp_optics.core import runtime
    from poevp_optics.render.renderer import mitsuba_load_error
    from poevp_optics.scene.load import load_scene

    spec = load_scene(scene)
    runtime.set_variant(runtime.choose_variant("mono")[0])
    _edit(scene / "scene.xml", 'value="$ink"', 'value="0.03"')
    with pytest.raises(Exception) as e:
        mi.load_file(str(scene / "scene.xml"), ink="0.0336")
    line = mitsuba_load_error(str(e.value), spec.resolved.render)
    assert "$ink" in line and "spectra.ink" in line and str(spec.toml_path) in line
    _edit(scene / "scene.xml", "<integrator", '<include filename="nothere.xml"/>\n    <integrator')
    with pytest.raises(Exception) as e:
        mi.load_file(str(scene / "scene.xml"))
    line = mitsuba_load_error(str(e.value), spec.resolved.render)
    assert "scene.xml: line 8" in line and "nothere.xml" in line and "\n" not in line


def test_damaged_frames_are_named_by_their_path(tmp_path):
    for case in ("truncated", "broken_link"):
        d = tmp_path / case
        shutil.copytree(SCENES / "exr_highbeam", d)
        frame = sorted((d / "frames").glob("*.exr"))[1]
        if case == "truncated":
            frame.write_bytes(frame.read_bytes()[: frame.stat().st_size // 2])
        else:
            frame.unlink()
            frame.symlink_to(tmp_path / "nowhere.exr")
        rc, out, err = poevp("validate", d)
        one_line(rc, err, 2, frame.name, "source.frames")
        assert "boxes" not in err[0] and out == ""      # nothing of OpenEXR's on stdout either


# ---------------------------------------------------------------------------- values
def test_overflowing_values_give_only_the_refusal_line(scene):
    _edit(scene / "scene.toml", "intensity_cd = 20000.0", "intensity_cd = 1e308")
    one_line(*poevp("validate", scene, "--no-load")[::2], 2, "spectra.lamp.intensity_cd")


@pytest.mark.parametrize("key,value,names", [
    ("velocity_m_per_s", "[1e308, 0.0, 0.0]", ("motion.plate.velocity_m_per_s", "light")),
    ("velocity_m_per_s", "[299792458.0, 0.0, 0.0]", ("motion.plate.velocity_m_per_s", "light")),
    ("start_offset_m", "[2e5, 0.0, 0.0]", ("motion.plate.start_offset_m", "leaves the scene")),
])
def test_impossible_trajectories_are_refused(scene, capsys, key, value, names):
    assert main(["validate", str(scene), "--no-load", "--set", f"motion.plate.{key}={value}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and all(n in err[0] for n in names), err
    # just under light: the check is the physical bound, not a guess at plausible speeds
    assert main(["validate", str(scene), "--no-load", "--set", "motion.plate.velocity_m_per_s=[2.0, 0.0, 0.0]"]) == 0


def test_keyframes_faster_than_light_are_refused(scene, capsys):
    args = ["--set", "motion.plate.kind='keyframes'", "--set", "motion.plate.velocity_m_per_s=[0.0,0.0,0.0]",
            "--set", "motion.plate.start_offset_m=[0.0,0.0,0.0]",
            "--set", "motion.plate.times_s=[0.0, 1e-9]", "--set", "motion.plate.offsets_m=[[0,0,0],[1,0,0]]"]
    assert main(["validate", str(scene), "--no-load", *args]) == 2      # 1 m in 1 ns: 1e9 m/s
    assert "motion.plate.offsets_m" in capsys.readouterr().err


def test_deeply_nested_toml_is_one_line(scene, tmp_path):
    deep = "x = " + "[" * 20000 + "]" * 20000 + "\n"
    (scene / "scene.toml").write_text(deep + (SMOKE / "scene.toml").read_text())
    one_line(*poevp("validate", scene)[::2], 2, "scene.toml", "nest")
    one_line(*poevp("validate", SMOKE, "--set", "render.spp=" + "[" * 20000 + "]" * 20000)[::2], 2,
             "--set render.spp")


# ---------------------------------------------------------------------------- signals
def test_sigterm_outside_the_command_exits_143_with_a_line():
    code = ("import os, signal, time\nfrom poevp_optics.core import runtime\n"
            "runtime.sigterm_exits('poevp: terminated (test)')\nos.kill(os.getpid(), signal.SIGTERM)\n"
            "time.sleep(10)\n")
    r = subprocess.run([sys.executable, "-c", code], env=ENV, capture_output=True, text=True, timeout=60)
    assert r.returncode == 143 and r.stderr.strip() == "poevp: terminated (test)"


# ---------------------------------------------------------------------------- fuzz
HOSTILE = ["1e308", "-1e308", "nan", "inf", "-inf", "0", "-1", "9999999999999999999", "''", "'x' ",
           "[]", "[[[[1]]]]", "{a = 1}", "true", "'" + "z" * 5000 + "'", "[1e308, 1e308, 1e308]",
           "[0, 0]", "'../../../../etc/passwd'", "'/dev/zero'", "1979-05-27T07:32:00Z",
           # legal-looking edge values, so that runs get past the key checks to the later ones
           "0.5", "1", "2", "1e-300", "1e6", "65535", "100", "0.001", "[1.0, 0.0, 0.0]"]


FLAG_VALUES = ["-1", "0", "1e9", "abc", "99999999999999999999", "10x", "0x0", "100000x100000", "", "fast"]


def _keys(raw: dict, prefix="") -> dict:
    out = {}
    for k, v in raw.items():
        out.update(_keys(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v})
    return out


def _perturb(v, rng: random.Random) -> str:
    """The value with its type kept and its size pushed to an edge (TOML text)."""
    if isinstance(v, bool) or isinstance(v, str):
        return rng.choice(HOSTILE)
    if isinstance(v, (int, float)):
        f = rng.choice([0, -1, 1e-9, 0.5, 2, 10, 1e3, 1e9])
        return str(int(v * f)) if isinstance(v, int) else repr(float(v) * f)
    if isinstance(v, list):
        return "[" + ", ".join(_perturb(x, rng) for x in v) + "]"
    return rng.choice(HOSTILE)


def test_fuzzed_scene_values_never_crash(capsys):
    """Seeded random hostile values on every key of the smoke scene and of night_road, and on
    the run flags: each run ends 0 or 2 with at most one stderr line, never an internal error
    (exit 1) or an escaped exception. (Hypothesis is not installed here: a seeded generator.)"""
    import tomllib

    rng = random.Random(28)
    values = {k: v for s in ("smoke", "night_road")
              for k, v in _keys(tomllib.loads((SCENES / s / "scene.toml").read_text())).items()}
    keys = sorted(values)
    bad = []
    flags = ["--frames", "--spp", "--seed", "--resolution", "--accuracy"]
    passed = 0
    for i in range(100):
        scene = str(SCENES / rng.choice(["smoke", "night_road"]))
        picked = [rng.choice(keys) for _ in range(rng.randint(1, 2))]
        sets = [f"{k}={_perturb(values[k], rng) if i % 2 else rng.choice(HOSTILE)}" for k in picked]
        argv = ["validate", scene, "--no-load"] + [a for s in sets for a in ("--set", s)]
        if i % 5 == 0:
            argv += [rng.choice(flags), rng.choice(FLAG_VALUES)]
        rc = main(argv)
        err = capsys.readouterr().err
        if rc not in (0, 2) or "internal error" in err or len(err.strip().splitlines()) > 1:
            bad.append((sets, rc, err[:300]))
        passed += rc == 0
    assert not bad, bad
    assert passed >= 3                 # some runs get past every check (seeded: 5 of 100)
