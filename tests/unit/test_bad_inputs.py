"""Bad and unusual inputs (issue 14), table-driven: every case of the issue plus our own.

Each case runs `poevp` on a copy of scenes/smoke in a fresh folder that also holds earlier
outputs (a poevp render output and a file of the user's). A refused case must exit 2 with ONE
stderr line naming the file (or flag) and the key, no traceback, and leave every file of the
folder byte-identical (nothing written, nothing lost). A legal case (rc 0) must leave the
earlier outputs byte-identical too. Most cases stop in validation, so the table runs in-process
in a few seconds; `prepare` and `problems` are shared with a script that replays the table
against older code in subprocesses (for the before/after counts in the report).
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import resource
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from tests.conftest import ROOT, SCENES

SMOKE = SCENES / "smoke"
LITE_WEIGHTS = ROOT / "assets" / "predictor" / "dmvfn_lite.safetensors"


@dataclass(frozen=True)
class Case:
    """args: after `poevp`, with {scene} (the scene copy), {toml}, {out} (the run's output
    folder), {tmp} (the case's root) filled in. names: text the one error line must hold (the
    file and the key). rc 0: a legal input; `stdout` must then appear on stdout."""

    id: str
    args: tuple[str, ...]
    names: tuple[str, ...] = ()
    rc: int = 2
    toml: Callable[[str], str] | None = None              # edit of the scene's TOML
    setup: Callable[[Path, Path], object] | None = None    # (tmp, scene folder) -> extra files
    cwd: str = "{tmp}"
    env: tuple[tuple[str, str], ...] = ()
    stdout: str = ""
    issue: bool = True                                     # listed in issue 14 (else ours)
    creates: tuple[str, ...] = ()                          # paths a legal case adds (rc 0)


# ---------------------------------------------------------------------------- setups
def _csv(name: str, rows: str):
    def make(tmp: Path, scene: Path):
        (scene / name).write_text("wavelength_nm,value\n" + rows)
    return make


def _lamp_from(name: str):
    return lambda t: t.replace('source = "cie:LED-B4"', f'source = "file:{{scene}}/{name}"')


def _nan_weights(tmp: Path, scene: Path):
    from safetensors import safe_open
    from safetensors.torch import load_file, save_file

    with safe_open(str(LITE_WEIGHTS), framework="pt") as f:
        meta = f.metadata()
    tensors = load_file(str(LITE_WEIGHTS))
    first = sorted(tensors)[0]
    tensors[first].view(-1)[0] = float("nan")
    save_file(tensors, str(scene / "nan.safetensors"), metadata=meta)


def _copy_weights(where: str):
    def make(tmp: Path, scene: Path):
        shutil.copy(LITE_WEIGHTS, (scene if where == "scene" else tmp) / "w.safetensors")
    return make


def _write(rel: str, data: bytes | str):
    def make(tmp: Path, scene: Path):
        p = tmp / rel.format(scene=scene.name)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data if isinstance(data, bytes) else data.encode())
    return make


def _png(name: str, shape):
    def make(tmp: Path, scene: Path):
        import cv2

        img = np.zeros(shape, np.uint8)
        img[shape[0] // 2, shape[1] // 2] = 255
        cv2.imwrite(str(scene / name), img)
    return make


def _xml(old: str, new: str):
    def make(tmp: Path, scene: Path):
        x = scene / "scene.xml"
        text = x.read_text()
        assert old in text, old
        x.write_text(text.replace(old, new))
    return make


def _output_of_kind(rel: str, kind: str):
    def make(tmp: Path, scene: Path):
        d = tmp / rel
        d.mkdir(parents=True)
        (d / ".poevp-output.json").write_text(f'{{"kind": "{kind}"}}\n')
        (d / "report.json").write_text("{}\n")
    return make


def _hold_lock(rel: str):
    """Another process is writing `rel`: its lock file is held (flock, as poevp takes it)."""
    def make(tmp: Path, scene: Path):
        out = tmp / rel
        fd = os.open(out.parent / f".{out.name}.lock", os.O_RDWR | os.O_CREAT)
        os.write(fd, b"4242\n")
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return fd
    return make


def _nested_cwd(tmp: Path, scene: Path):
    (tmp / "a" / "b").mkdir(parents=True)


def _scene_render_of_other_run(tmp: Path, scene: Path):
    _output_of_kind(f"{scene.name}/out/other_run", "render")(tmp, scene)
    (scene / "out" / "other_run" / "capture.png").write_bytes(b"an earlier run's capture")


SET = "--set"
Q = "--quiet"
SMALL = ("--frames", "1", "--resolution", "8x8")

CASES = [
    # -------------------------------------------------------------- issue 14: critical
    Case("render_dot_inside_scene_folder", ("render", ".", Q, *SMALL), rc=0, cwd="{scene}",
         setup=_scene_render_of_other_run, creates=("{scene}/out/scene/report.json",)),
    Case("render_toml_inside_scene_folder", ("render", "scene.toml", Q, *SMALL), rc=0, cwd="{scene}",
         setup=_scene_render_of_other_run, creates=("{scene}/out/scene/report.json",)),
    Case("out_is_a_folder_poevp_did_not_write", ("render", "{scene}", "--out", "{tmp}/mine", Q),
         ("--out", "mine", ".poevp-output.json"), setup=_write("mine/thesis.tex", "my thesis")),
    Case("out_of_memory_resolution_16384", ("render", "{scene}", "--out", "{out}", "--resolution", "16384x16384"),
         ("{toml}", "render.resolution", "GiB", "available")),
    Case("out_of_memory_psf_sigma_1000", ("render", "{scene}", "--out", "{out}", "--resolution", "256x256",
                                          SET, "relay.psf='gaussian'", SET, "relay.sigma_px=1000"),
         ("{toml}", "relay.sigma_px", "MiB", "POEVP_MEMORY_LIMIT"), env=(("POEVP_MEMORY_LIMIT", "1000M"),)),
    Case("nan_weights", ("render", "{scene}", "--out", "{out}", SET, "predictor.name='dmvfn_lite'",
                         SET, "predictor.weights='nan.safetensors'"),
         ("{toml}", "predictor.weights", "nan.safetensors", "NaN"), setup=_nan_weights),
    # -------------------------------------------------------------- issue 14: tracebacks
    Case("spp_1", ("render", "{scene}", "--out", "{out}", "--spp", "1"), ("{toml}", "render.spp", "mc_splits")),
    Case("mc_splits_8_spp_4", ("render", "{scene}", "--out", "{out}", SET, "render.mc_splits=8", "--spp", "4"),
         ("{toml}", "render.spp", "mc_splits = 8")),
    Case("sensor_bits_0", ("render", "{scene}", "--out", "{out}", SET, "sensor.bits=0"), ("{toml}", "sensor.bits")),
    Case("sensor_offset_5000", ("render", "{scene}", "--out", "{out}", SET, "sensor.offset_dn=5000"),
         ("{toml}", "sensor.offset_dn")),
    Case("variant_foo", ("render", "{scene}", "--out", "{out}", SET, "render.variant='foo'"),
         ("{toml}", "render.variant", "foo")),
    Case("tonemap_foo", ("render", "{scene}", "--out", "{out}", SET, "outputs.tonemap='foo'"),
         ("{toml}", "outputs.tonemap")),
    Case("plate_text_blank", ("render", "{scene}", "--out", "{out}"), ("{toml}", "plate.text"),
         toml=lambda t: t + '\n[plate]\ntext = " "\n'),
    Case("measured_psf_even_png", ("render", "{scene}", "--out", "{out}", SET, "relay.psf='measured'",
                                   SET, "relay.measured_file='even.png'"),
         ("{toml}", "relay.measured_file", "even.png", "odd-sized"), setup=_png("even.png", (4, 4))),
    Case("measured_psf_not_an_image", ("render", "{scene}", "--out", "{out}", SET, "relay.psf='measured'",
                                       SET, "relay.measured_file='psf.png'"),
         ("{toml}", "relay.measured_file", "psf.png", "not a readable"), setup=_write("{scene}/psf.png", "not a png")),
    Case("dmvfn_lite_resolution_8", ("render", "{scene}", "--out", "{out}", SET, "predictor.name='dmvfn_lite'",
                                     SET, "predictor.resolution=[8, 8]"), ("{toml}", "predictor.resolution")),
    Case("lamp_off_is_legal_validate", ("validate", "{scene}", SET, "spectra.lamp.intensity_cd=0"), rc=0,
         stdout="is valid"),
    Case("lamp_off_is_legal_render", ("render", "{scene}", "--out", "{out}", Q, *SMALL,
                                      SET, "spectra.lamp.intensity_cd=0"), rc=0, creates=("{out}/report.json",)),
    Case("intensity_1e30", ("render", "{scene}", "--out", "{out}", SET, "spectra.lamp.intensity_cd=1e30"),
         ("{toml}", "spectra.lamp.intensity_cd")),
    Case("threads_0", ("render", "{scene}", "--out", "{out}", "--threads", "0"), ("--threads",)),
    Case("threads_minus_1", ("render", "{scene}", "--out", "{out}", "--threads", "-1"), ("--threads",)),
    Case("out_on_read_only_file_system", ("render", "{scene}", "--out", "/proc/poevp-out/run"), ("--out", "/proc")),
    # -------------------------------------------------------------- issue 14: output safety
    Case("out_dot", ("render", "{scene}", "--out", "."), ("--out", "current folder")),
    Case("out_is_a_regular_file", ("render", "{scene}", "--out", "{tmp}/notes.txt"), ("--out", "notes.txt", "not a folder"),
         setup=_write("notes.txt", "keep me")),
    Case("out_locked_by_another_run", ("render", "{scene}", "--out", "{out}"), ("--out", "4242", "lock"),
         setup=_hold_lock("out/run")),
    # -------------------------------------------------------------- issue 14: silent acceptance
    Case("spectrum_csv_unsorted", ("render", "{scene}", "--out", "{out}"), ("{toml}", "spectra.lamp.source", "lamp.csv"),
         toml=_lamp_from("lamp.csv"), setup=_csv("lamp.csv", "400,1\n600,2\n500,3\n700,1\n")),
    Case("spectrum_csv_duplicated", ("render", "{scene}", "--out", "{out}"), ("{toml}", "spectra.lamp.source", "lamp.csv"),
         toml=_lamp_from("lamp.csv"), setup=_csv("lamp.csv", "400,1\n500,2\n500,3\n700,1\n")),
    Case("spectrum_no_visible_power", ("render", "{scene}", "--out", "{out}"),
         ("{toml}", "spectra.lamp.source", "ir.csv", "no visible power"),
         toml=_lamp_from("ir.csv"), setup=_csv("ir.csv", "900,1\n1000,1\n")),
    Case("dmd_window_outside_exposure", ("render", "{scene}", "--out", "{out}", SET, "timing.exposure_s=0.01",
                                         SET, "timing.dmd_window_s=0.01", SET, "timing.dmd_window_offset_s=0.015"),
         ("{toml}", "timing.dmd_window_offset_s")),
    Case("contrast_ratio_1", ("render", "{scene}", "--out", "{out}", SET, "dmd.contrast_ratio=1"),
         ("{toml}", "dmd.contrast_ratio", "no mask could dim")),
    Case("init_frames_ge_frames", ("compare", "{scene}", "--out", "{out}", SET, "predictor.name='hold'",
                                   SET, "loop.init_frames=3"), ("{toml}", "loop.init_frames")),
    Case("mask_min_level_above_dmd_top", ("render", "{scene}", "--out", "{out}", SET, "mask.min_level=300"),
         ("{toml}", "mask.min_level", "255")),
    Case("weights_relative_to_scene_folder", ("validate", "{scene}", SET, "predictor.name='dmvfn_lite'",
                                              SET, "predictor.weights='w.safetensors'"), rc=0, stdout="is valid",
         setup=_copy_weights("scene")),
    Case("weights_relative_not_from_cwd", ("validate", "{scene}", SET, "predictor.name='dmvfn_lite'",
                                           SET, "predictor.weights='w.safetensors'"),
         ("{toml}", "predictor.weights", "{scene}/w.safetensors"), setup=_copy_weights("cwd")),
    Case("weights_with_flow", ("render", "{scene}", "--out", "{out}", SET, "predictor.name='flow'",
                               SET, f"predictor.weights='{LITE_WEIGHTS}'"), ("{toml}", "predictor.weights", "flow")),
    Case("validate_load_missing_weights", ("validate", "{scene}", "--load", SET, "predictor.name='dmvfn_lite'",
                                           SET, "predictor.weights='missing.safetensors'"),
         ("{toml}", "predictor.weights", "missing.safetensors")),
    Case("validate_corrupt_weights", ("validate", "{scene}", SET, "predictor.name='dmvfn_lite'",
                                      SET, "predictor.weights='bad.safetensors'"),
         ("{toml}", "predictor.weights", "bad.safetensors"), setup=_write("{scene}/bad.safetensors", b"\x00" * 64)),
    Case("validate_missing_texture", ("validate", "{scene}"), ("scene.xml", "plate_texture", "nope.png"),
         setup=_xml('value="plates/plate_B4713.png"', 'value="plates/nope.png"')),
    Case("validate_unknown_motion_id", ("validate", "{scene}"), ("{toml}", "motion.truck"),
         toml=lambda t: t.replace("[motion.plate]", "[motion.truck]")),
    Case("spp_flag_after_set_wins", ("validate", "{scene}", SET, "render.spp=8", "--spp", "6"), rc=0, stdout="spp 6"),
    Case("set_after_spp_flag_wins", ("validate", "{scene}", "--spp", "6", SET, "render.spp=8"), rc=0, stdout="spp 8"),
    Case("resolution_flag_after_set_wins", ("validate", "{scene}", SET, "render.resolution=[20,30]",
                                            "--resolution", "10x12"), rc=0, stdout="10x12"),
    # -------------------------------------------------------------- our own
    Case("resolution_malformed", ("render", "{scene}", "--resolution", "abc"), ("--resolution",), issue=False),
    Case("resolution_zero", ("render", "{scene}", "--out", "{out}", "--resolution", "0x64"),
         ("{toml}", "render.resolution"), issue=False),
    Case("frames_0", ("render", "{scene}", "--out", "{out}", "--frames", "0"), ("{toml}", "timing.frames"), issue=False),
    Case("scene_missing", ("render", "{tmp}/nowhere", "--out", "{out}"), ("nowhere", "scene file not found"), issue=False),
    Case("scene_folder_without_toml", ("render", "{tmp}/empty", "--out", "{out}"), ("empty/scene.toml", "not found"),
         setup=_write("empty/readme.txt", "no scene here"), issue=False),
    Case("toml_not_utf8", ("render", "{scene}", "--out", "{out}"), ("{toml}", "UTF-8"),
         setup=_write("{scene}/scene.toml", b"\xff\xfe\x00garbage"), issue=False),
    Case("set_without_equals", ("render", "{scene}", "--out", "{out}", SET, "render.spp"), ("{toml}", "--set render.spp"),
         issue=False),
    Case("spectrum_csv_negative", ("render", "{scene}", "--out", "{out}"), ("{toml}", "spectra.lamp.source", "non-negative"),
         toml=_lamp_from("lamp.csv"), setup=_csv("lamp.csv", "400,1\n500,-2\n700,1\n"), issue=False),
    Case("roi_shape_unknown_in_validate", ("validate", "{scene}", SET, "render.roi_shape='nope'"),
         ("{toml}", "render.roi_shape", "nope"), issue=False),
    Case("motion_attached_unknown", ("validate", "{scene}"), ("{toml}", "motion.plate.attached", "ghost"),
         toml=lambda t: t.replace('kind = "linear"', 'kind = "linear"\nattached = ["ghost"]'), issue=False),
    Case("weights_is_a_folder", ("validate", "{scene}", SET, "predictor.name='dmvfn_lite'", SET, "predictor.weights='.'"),
         ("{toml}", "predictor.weights", "not found"), issue=False),
    Case("weights_of_another_network", ("validate", "{scene}", SET, "predictor.name='dmvfn'",
                                        SET, f"predictor.weights='{LITE_WEIGHTS}'"),
         ("{toml}", "predictor.weights", "expected"), issue=False),
    Case("xml_malformed", ("validate", "{scene}"), ("scene.xml", "malformed XML"),
         setup=_xml("</scene>", "</scen>"), issue=False),
    Case("xml_mesh_missing", ("validate", "{scene}"), ("scene.xml", "none.ply"),
         setup=_xml("</scene>", '<shape type="ply" id="m"><string name="filename" value="meshes/none.ply"/></shape></scene>'),
         issue=False),
    Case("out_is_the_scene_folder", ("render", "{scene}", "--out", "{scene}"), ("--out", "which this run reads"), issue=False),
    Case("out_holds_the_current_folder", ("render", "{scene}", "--out", "{tmp}/a"), ("--out", "current folder"),
         cwd="{tmp}/a/b", setup=_nested_cwd, issue=False),
    Case("out_is_an_output_of_another_kind", ("render", "{scene}", "--out", "{tmp}/out/dr"), ("--out", "chart output"),
         setup=_output_of_kind("out/dr", "chart"), issue=False),
    Case("accuracy_conflicts_with_set", ("render", "{scene}", "--out", "{out}", "--accuracy", "fast",
                                         SET, "relay.support_energy=0.9"), ("--accuracy fast", "relay.support_energy"),
         issue=False),
    Case("threads_not_a_number", ("render", "{scene}", "--threads", "abc"), ("--threads",), issue=False),
    Case("unknown_option", ("render", "{scene}", "--bogus"), ("--bogus",), issue=False),
    Case("dmd_16_bits_4096_subframes", ("render", "{scene}", "--out", "{out}", "--resolution", "368x640", SET, "dmd.bits=16",
                                        SET, "render.subframes=4096"), ("{toml}", "dmd.bits", "GiB"), issue=False),
    Case("sweep_seeds_0", ("sweep", "{scene}", "--grid", "mask.a=0.5", "--seeds", "0"), ("--seeds",), issue=False),
    Case("sweep_workers_0", ("sweep", "{scene}", "--grid", "mask.a=0.5", "--workers", "0"), ("--workers",), issue=False),
    Case("sweep_out_is_a_render_output", ("sweep", "{scene}", "--grid", "mask.a=0.5", "--out", "{tmp}/out/previous"),
         ("--out", "render output"), issue=False),
    Case("sweep_unknown_grid_key", ("sweep", "{scene}", "--grid", "mask.nope=1,2", "--out", "{tmp}/sw"),
         ("{toml}", "mask.nope"), issue=False),
    Case("sweep_retries_negative", ("sweep", "{scene}", "--grid", "mask.a=0.5", "--retries", "-1"), ("--retries",),
         issue=False),
    Case("sweep_scheduler_and_scheduler_file", ("sweep", "{scene}", "--grid", "mask.a=0.5", "--scheduler",
                                                "tcp://127.0.0.1:8786", "--scheduler-file", "{tmp}/s.json"),
         ("--scheduler-file", "--scheduler"), issue=False),
    Case("sweep_scheduler_file_missing", ("sweep", "{scene}", "--grid", "mask.a=0.5", "--out", "{tmp}/sw",
                                          "--scheduler-file", "{tmp}/nope.json"), ("--scheduler-file", "nope.json"),
         issue=False),
    Case("sweep_shared_fs_without_scheduler", ("sweep", "{scene}", "--grid", "mask.a=0.5", "--out", "{tmp}/sw",
                                               "--shared-fs"), ("--shared-fs", "--scheduler"), issue=False),
    Case("compare_unknown_predictor", ("compare", "{scene}", "--predictors", "oracle,nope", "--out", "{out}"),
         ("--predictors", "nope"), issue=False),
    Case("compare_unknown_mode", ("compare", "{scene}", "--modes", "open,sideways", "--out", "{out}"),
         ("--modes", "sideways"), issue=False),
    Case("chart_of_a_scene_without_chart", ("chart", "{scene}", "--out", "{out}"), ("{toml}", "chart.patches"), issue=False),
    Case("variant_rgb", ("render", "{scene}", "--out", "{out}", SET, "render.variant='llvm_ad_rgb'"),
         ("{toml}", "render.variant", "RGB"), issue=False),
    Case("memory_limit_not_a_size", ("render", "{scene}", "--out", "{out}"), ("POEVP_MEMORY_LIMIT",),
         env=(("POEVP_MEMORY_LIMIT", "lots"),), issue=False),
    Case("sensor_qe_file_missing", ("render", "{scene}", "--out", "{out}", SET, "sensor.qe='file:nope.csv'"),
         ("{toml}", "sensor.qe", "nope.csv"), issue=False),
    Case("sensor_bits_25", ("render", "{scene}", "--out", "{out}", SET, "sensor.bits=25"), ("{toml}", "sensor.bits", "24"),
         issue=False),
]


# ---------------------------------------------------------------------------- harness
def prepare(case: Case, tmp: Path) -> tuple[list[str], Path, dict, list]:
    """Build the case's folder: scene copy, earlier outputs, extra files. Returns (argv, cwd,
    env additions, handles to keep open while the case runs)."""
    scene = tmp / "scene"
    scene.mkdir(parents=True)
    toml = (SMOKE / "scene.toml").read_text()
    if case.toml:
        edited = case.toml(toml)
        assert edited != toml, f"{case.id}: the TOML edit did not apply"
        toml = edited
    (scene / "scene.toml").write_text(toml.replace("{scene}", str(scene)))
    shutil.copy(SMOKE / "scene.xml", scene / "scene.xml")
    # earlier outputs that must survive every case: a poevp render output and a user's file
    previous = tmp / "out" / "previous"
    previous.mkdir(parents=True)
    (previous / ".poevp-output.json").write_text('{"kind": "render"}\n')
    (previous / "report.json").write_text('{"scene": "earlier run"}\n')
    (tmp / "out" / "user_notes.txt").write_text("not poevp's")
    handles = []
    if case.setup:
        h = case.setup(tmp, scene)
        if h is not None:
            handles.append(h)
    fill = {"scene": str(scene), "toml": str(scene / "scene.toml"), "out": str(tmp / "out" / "run"),
            "tmp": str(tmp)}
    argv = [a.format(**fill) for a in case.args]
    return argv, Path(case.cwd.format(**fill)), dict(case.env), handles


def snapshot(root: Path) -> dict[str, str]:
    """Every file and folder under `root`: path -> sha256 (folders: 'dir')."""
    out = {}
    for p in sorted(root.rglob("*")):
        rel = str(p.relative_to(root))
        if p.is_dir():
            out[rel] = "dir"
        elif p.is_file():
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def problems(case: Case, tmp: Path, rc, out: str, err: str, before: dict, after: dict) -> list[str]:
    """What the case did wrong (empty: it behaved)."""
    bad = []
    fill = {"scene": str(tmp / "scene"), "toml": str(tmp / "scene" / "scene.toml"),
            "out": str(tmp / "out" / "run"), "tmp": str(tmp)}
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    if rc != case.rc:
        bad.append(f"exit {rc}, expected {case.rc}")
    if "Traceback" in err:
        bad.append("traceback on stderr")
    if case.rc == 2:
        if len(lines) != 1:
            bad.append(f"{len(lines)} stderr lines, expected 1")
        for name in case.names:
            if name.format(**fill) not in err:
                bad.append(f"error does not name {name.format(**fill)!r}")
        if after != before:
            changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
            bad.append(f"files written or lost: {changed[:5]}")
    else:
        lost = sorted(k for k in before if after.get(k) != before[k])
        if lost:
            bad.append(f"earlier files changed or lost: {lost[:5]}")
        for c in case.creates:
            if not Path(c.format(**fill)).is_file():
                bad.append(f"did not create {c.format(**fill)}")
        if case.stdout and case.stdout not in out:
            bad.append(f"stdout lacks {case.stdout!r}")
    return bad


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input(case, tmp_path, monkeypatch, capsys):
    from poevp_optics.cli import main

    argv, cwd, env, handles = prepare(case, tmp_path)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    monkeypatch.chdir(cwd)
    before = snapshot(tmp_path)
    try:
        rc = main(argv)
    finally:
        for fd in handles:
            os.close(fd)
    captured = capsys.readouterr()
    after = snapshot(tmp_path)
    assert not problems(case, tmp_path, rc, captured.out, captured.err, before, after), \
        (problems(case, tmp_path, rc, captured.out, captured.err, before, after), captured.err)


def test_table_holds_the_issue_cases_and_enough_of_our_own():
    assert len([c for c in CASES if c.issue]) >= 40
    assert len([c for c in CASES if not c.issue]) >= 15
    assert len({c.id for c in CASES}) == len(CASES)


def test_memory_refusals_come_within_5_s(tmp_path):
    """The two out-of-memory cases of the issue, as a user runs them (a fresh process), are
    refused before anything is allocated or rendered: within 5 s of the child's CPU time (user +
    system, from getrusage of the children; wall time would measure the machine's other load)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for extra, key, limit in ((["--resolution", "16384x16384"], "render.resolution", None),
                              (["--set", "relay.psf='gaussian'", "--set", "relay.sigma_px=1000",
                                "--resolution", "256x256"], "relay.sigma_px", "1000M")):
        e = {**env, **({"POEVP_MEMORY_LIMIT": limit} if limit else {})}
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        r = subprocess.run([sys.executable, "-m", "poevp_optics.cli", "render", str(SMOKE),
                            "--out", str(tmp_path / "o"), *extra], env=e, capture_output=True,
                           text=True, timeout=120)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        assert r.returncode == 2 and key in r.stderr and "needs about" in r.stderr, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1
        assert cpu_s < 5.0, cpu_s
        assert not (tmp_path / "o").exists()
