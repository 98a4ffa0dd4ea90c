"""End-to-end `poevp render` on the smoke scene: outputs, report keys, static reuse."""

from __future__ import annotations

import json

import numpy as np

from poevp_optics.cli import main
from poevp_optics.io import read_exr
from tests.conftest import SCENES


def test_render_writes_complete_report_and_float32_exr(tmp_path):
    out = tmp_path / "run"
    assert main(["render", str(SCENES / "smoke"), "--out", str(out), "--quiet", "--frames", "2",
                 "--spp", "4", "--resolution", "24x32", "--seed", "5"]) == 0
    r = json.loads((out / "report.json").read_text())
    for key in ("scene", "version", "seed", "resolution", "frames", "skipped_stages"):
        assert key in r
    assert r["seed"] == 5 and r["resolution"] == [24, 32] and r["frames"] == 2
    st = r["stages"]["render"]
    assert st["seconds"] > 0 and 0 < st["rel_error"] < 1 and st["rel_error_roi"] is not None
    # frames x sub-frames x mc_splits, plus the K/2 renders of the temporal-error check
    assert st["calls"] == 2 * 2 * 2 + 1 * 2
    e = r["errors"]
    assert e["temporal"]["renders"] == 2 and e["dominant"] in e and e["total"]["rel"] >= e["render_mc"]["rel"]
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
