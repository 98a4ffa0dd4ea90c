"""A run leaves out what its scene does not need, and says so (issue 7)."""

from __future__ import annotations

import json

import pytest

from poevp_optics.cli import main

from ..conftest import SCENES


def _run(tmp_path, *sets, name="r"):
    out = tmp_path / name
    args = ["render", str(SCENES / "smoke"), "--out", str(out), "--quiet", "--frames", "2",
            "--resolution", "16x24"]
    for s in sets:
        args += ["--set", s]
    assert main(args) == 0
    return json.loads((out / "report.json").read_text())


def test_delta_psf_runs_no_convolution(tmp_path, monkeypatch):
    import poevp_optics.camera.camera as camera

    called = []

    def boom(*a, **k):
        called.append(1)
        raise AssertionError("convolve called for a delta PSF")

    monkeypatch.setattr(camera, "convolve", boom)
    r = _run(tmp_path, "relay.psf='delta'")
    assert "relay" in r["skipped_stages"] and r["errors"]["psf_truncation"]["rel"] == 0.0 and not called
    with pytest.raises(AssertionError):          # the run fails (one line, exit 1): the probe was called
        _run(tmp_path, "relay.psf='gaussian'", name="g")
    assert called


def test_noise_free_sensor_draws_no_random_numbers(tmp_path):
    r = _run(tmp_path, "sensor.noise=false")
    assert "sensor_noise" in r["skipped_stages"]
    assert "(0 draws)" in r["skipped_stages"]["sensor_noise"]
    r2 = _run(tmp_path, name="noisy")
    assert "sensor_noise" not in r2["skipped_stages"]


def test_pwm_lamps_on_static_geometry_render_each_group_once(tmp_path):
    out = tmp_path / "flk"
    assert main(["render", str(SCENES / "led_flicker"), "--out", str(out), "--quiet", "--frames", "3",
                 "--resolution", "16x24", "--spp", "2"]) == 0
    r = json.loads((out / "report.json").read_text())
    # two emitter groups (rest, highbeam) x 2 MC splits, whatever the number of frames
    assert r["stages"]["render"]["calls"] == 4
    assert "subframes" in r["skipped_stages"] and r["errors"]["temporal"]["rel"] == 0.0
