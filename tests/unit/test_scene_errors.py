"""Malformed scene files: one clear error line naming the file and key; nothing written."""

from __future__ import annotations

import subprocess
import sys

import pytest

from poevp_optics.cli import main
from tests.conftest import SCENES

BASE = (SCENES / "smoke" / "scene.toml").read_text()
XML = (SCENES / "smoke" / "scene.xml").read_text()

# (description, edit of the smoke scene's TOML, text that must appear in the error)
BAD = [
    ("unknown key", BASE.replace("spp = 4", "spp = 4\nspp_typo = 3"), "render.spp_typo: unknown key"),
    ("unknown section", BASE + "\n[camera]\nx = 1\n", "camera: unknown section"),
    ("wrong type", BASE.replace("spp = 4", 'spp = "four"'), "render.spp: expected an integer"),
    ("negative time", BASE.replace("exposure_s = 0.02", "exposure_s = -0.02"), "timing.exposure_s: must be > 0"),
    ("negative offset", BASE.replace("[timing]", "[timing]\nexposure_offset_s = -0.001"),
     "timing.exposure_offset_s: negative times are not allowed"),
    ("NaN value", BASE.replace("intensity_cd = 20000.0", "intensity_cd = nan"), "spectra.lamp.intensity_cd: must be finite"),
    ("Inf value", BASE.replace("fps = 30.0", "fps = inf"), "timing.fps: must be finite"),
    ("missing XML", BASE.replace("[render]", '[render]\nxml = "nowhere.xml"'), "render.xml: Mitsuba scene file not found"),
    ("impossible timing", BASE.replace("exposure_s = 0.02", "exposure_s = 0.05"), "timing.exposure_s: impossible timing"),
    ("bad choice", BASE.replace("[sensor]", '[dmd]\nbit_order = "random"\n[sensor]'), "dmd.bit_order: must be one of"),
    ("wrong array length", BASE.replace("resolution = [48, 64]", "resolution = [48]"), "render.resolution: expected 2 values"),
    ("unknown spectrum", BASE.replace('source = "cie:LED-B4"', 'source = "cie:LED-Z9"'), "spectra.lamp.source: unknown cie spectrum"),
    ("reflectance above 1", BASE.replace('source = "colorchecker:neutral 5 (.70 D)"',
                                         'source = "colorchecker:neutral 5 (.70 D)"\nscale = 9.0'),
     "spectra.wall.scale: reflectance exceeds 1"),
    ("missing photometric", BASE.replace("intensity_cd = 20000.0\n", ""), "spectra.lamp.intensity_cd: required"),
    ("malformed TOML", BASE.replace("[timing]", "[timing"), "malformed TOML"),
    ("moving unknown id", BASE.replace("[motion.plate]", "[motion.truck]"), "motion.truck: no shape or emitter"),
    ("keyframes mismatch", BASE.replace('kind = "linear"\nstart_offset_m = [-0.2, 0.0, 0.0]\nvelocity_m_per_s = [2.0, 0.0, 0.0]',
                                        'kind = "keyframes"\ntimes_s = [0.0, 0.1]\noffsets_m = [[0.0, 0.0, 0.0]]'),
     "motion.plate.offsets_m: keyframes need as many"),
    ("unbound emitter spectrum", BASE.replace("[spectra.lamp]", "[spectra.lampx]"), "spectra.lamp"),
    ("unknown sampler", BASE.replace("spp = 4", 'spp = 4\nsampler = "sobol"'), "render.sampler: must be one of"),
    ("unknown light selection", BASE.replace("spp = 4", 'spp = 4\nlight_selection = "flux"'),
     "render.light_selection: must be one of"),
    ("negative error target", BASE.replace("spp = 4", "spp = 4\ntarget_rel_error = -0.01"),
     "render.target_rel_error: must be >= 0"),
    ("error target above 1", BASE.replace("spp = 4", "spp = 4\ntarget_rel_error = 1.5"),
     "render.target_rel_error: must be <= 1"),
    ("max_spp below spp", BASE.replace("spp = 4", "spp = 4\ntarget_rel_error = 0.01\nmax_spp = 2"),
     "render.max_spp: must be >= render.spp = 4"),
]


@pytest.mark.parametrize("desc,toml,expected", BAD, ids=[b[0] for b in BAD])
def test_bad_scene_gives_one_line_error_and_writes_nothing(tmp_path, capsys, desc, toml, expected):
    assert toml != BASE, "the edit did not apply"
    d = tmp_path / "bad"
    d.mkdir()
    (d / "scene.toml").write_text(toml)
    (d / "scene.xml").write_text(XML)
    out = tmp_path / "out"
    rc = main(["render", str(d), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1, err
    assert str(d / "scene.toml") in err and expected in err, err
    assert not out.exists()
    assert not any(p.name.startswith(".out") for p in tmp_path.iterdir())


def test_bad_override_names_the_override(tmp_path, capsys):
    rc = main(["validate", str(SCENES / "smoke"), "--set", "render.spp=-3"])
    err = capsys.readouterr().err
    assert rc == 2 and "--set render.spp=-3" in err and "render.spp: must be >= 1" in err


def test_existing_output_survives_a_failed_run(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("old result")
    d = tmp_path / "bad"
    d.mkdir()
    (d / "scene.toml").write_text(BASE.replace("[render]", "[render]\nroi_shape = \"nope\""))
    (d / "scene.xml").write_text(XML)
    assert main(["render", str(d), "--out", str(out), "--quiet"]) == 2
    assert (out / "keep.txt").read_text() == "old result"


def test_cli_entry_point_runs():
    r = subprocess.run([sys.executable, "-m", "poevp_optics.cli", "validate", str(SCENES / "smoke")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "is valid" in r.stdout
