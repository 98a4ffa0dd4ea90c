"""End-to-end `poevp render` on the smoke scene: outputs, report keys, static reuse."""

from __future__ import annotations

import json

import numpy as np

from poevp_optics.cli import main
from poevp_optics.core.io import read_exr
from tests.conftest import SCENES


def test_render_writes_complete_report_and_float32_exr(tmp_path):
    out = tmp_path / "run"
    assert main(["render", str(SCENES / "smoke"), "--out", str(out), "--quiet", "--frames", "2",
                 "--spp", "4", "--resolution", "24x32", "--seed", "5", "--set", "render.subframes=4"]) == 0
    r = json.loads((out / "report.json").read_text())
    for key in ("scene", "version", "seed", "resolution", "frames", "skipped_stages"):
        assert key in r
    assert r["seed"] == 5 and r["resolution"] == [24, 32] and r["frames"] == 2
    st = r["stages"]["render"]
    assert st["seconds"] > 0 and 0 < st["rel_error"] < 1 and st["rel_error_roi"] is not None
    # frames x radiance nodes x mc_splits, plus the temporal check's renders of one frame's nodes
    # and midpoints (apps.run.temporal_check.temporal_error); nodes: 4 uniform + the DMD's 7 inner plane boundaries
    from poevp_optics.scene.load import load_scene
    spec = load_scene(SCENES / "smoke", ["render.subframes=4", "timing.frames=2"])
    n = len(spec.subframe_times_s(1))
    assert n == 4 + 7
    e = r["errors"]
    assert st["calls"] == 2 * n * 2 + (2 * n - 1) * 2 == 2 * n * 2 + e["temporal"]["renders"]
    assert e["temporal"]["nodes"] == n and e["temporal"]["rel"] is not None
    assert e["dominant"] in e and e["total"]["rel"] >= e["render_mc"]["rel"]
    assert "quantisation" not in e and r["physics_noise"]["quantisation"]["rel"] > 0
    chans, header = read_exr(out / "radiance" / "frame_0001.exr")
    assert set(chans) == {"Y", "mc_stderr"} and chans["Y"].dtype == np.float32
    assert header["poevp_unit"] == "e- s-1 m-2 sr-1"
    assert (out / "preview" / "frame_0001.png").exists()
    # the plate moved between frames: the images differ
    c0, _ = read_exr(out / "radiance" / "frame_0000.exr")
    assert np.any(c0["Y"] != chans["Y"])


def test_static_scene_renders_once(tmp_path):
    out = tmp_path / "static"
    assert main(["render", str(SCENES / "smoke"), "--out", str(out), "--quiet", "--frames", "4",
                 "--resolution", "16x24", "--set", "motion.plate.velocity_m_per_s=[0.0,0.0,0.0]"]) == 0
    r = json.loads((out / "report.json").read_text())
    assert r["stages"]["render"]["calls"] == 2       # one render, split in 2 for the MC error
    assert "render_repeat" in r["skipped_stages"]
    a, _ = read_exr(out / "radiance" / "frame_0000.exr")
    b, _ = read_exr(out / "radiance" / "frame_0003.exr")
    np.testing.assert_array_equal(a["Y"], b["Y"])
