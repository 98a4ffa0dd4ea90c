"""`--scale S`, `--resolution HxW`, POEVP_SCALE and `--dmd-mirrors` (scene/scale.py): the camera at
another mirror count over the same field. The overrides are checked against closed forms from
the scene file (focal length x S, sizes in mirrors x S, areas x S^2), and night_road at 1/6 scale
keeps its plate's white in the exposure controller's band."""

from __future__ import annotations

import json

import pytest

from poevp_optics.cli import _overrides, _overrides_and_scaling, build_parser, main
from poevp_optics.scene.load import load_scene, parse_override
from tests.conftest import SCENES

NIGHT = SCENES / "night_road"


def _sets(*argv) -> dict:
    """{key: value} of the overrides `poevp render NIGHT *argv` computes (cli._overrides)."""
    args = build_parser().parse_args(["render", str(argv[0]), *argv[1:]])
    return {".".join(k): v for k, v in map(parse_override, _overrides(args))}


@pytest.fixture
def no_env(monkeypatch):
    monkeypatch.delenv("POEVP_SCALE", raising=False)


def test_one_sixth_scale_of_night_road_is_the_closed_forms(no_env):
    """S = 1/6 of the DLP6500's 1080x1920 mirrors: 180x320 mirrors, the focal length / 6 (the same
    12 deg field: tan(theta) = r / f with r / 6), the sizes in mirrors / 6, the area / 36."""
    full = load_scene(NIGHT)
    s = 1 / 6
    sets = _sets(NIGHT, "--scale", "1/6")
    assert sets["render.resolution"] == [1080 * s, 1920 * s] == [180, 320]
    assert sets["objective.focal_length_m"] == pytest.approx(full.objective.focal_length_m * s, rel=1e-5)
    assert sets["mask.smooth_px"] == pytest.approx(full.mask.smooth_px * s) == 4.0
    assert sets["objective.guard_max_px"] == round(full.objective.guard_max_px * s) == 4
    assert sets["attenuator.serve_min_mirrors"] == round(full.attenuator.serve_min_mirrors * s * s) == 24
    assert set(sets) == {"render.resolution", "objective.focal_length_m", "mask.smooth_px",
                         "objective.guard_max_px", "attenuator.serve_min_mirrors"}
    # the same field: the image's half-width angle atan(W p / 2 f) is the scene's
    spec = load_scene(NIGHT, _overrides(build_parser().parse_args(["render", str(NIGHT), "--scale", "1/6"])))
    assert spec.render.resolution[1] / spec.objective.focal_length_m == pytest.approx(
        full.render.resolution[1] / full.objective.focal_length_m, rel=1e-5)
    # `--resolution 180x320` alone is the same camera (S from the width ratio)
    assert _sets(NIGHT, "--resolution", "180x320") == sets


@pytest.mark.parametrize("argv", [("--scale", "1"), ("--scale", "6/6"), ("--resolution", "1080x1920")])
def test_scale_one_is_the_identity(no_env, argv):
    assert _sets(NIGHT, *argv) == {}


def test_the_environment_variable_is_the_default_and_a_flag_wins(monkeypatch):
    sixth = _sets(NIGHT, "--scale", "1/6")
    monkeypatch.setenv("POEVP_SCALE", "1/6")
    assert _sets(NIGHT) == sixth
    monkeypatch.setenv("POEVP_SCALE", "1")
    assert _sets(NIGHT) == {}
    monkeypatch.setenv("POEVP_SCALE", "1/3")
    assert _sets(NIGHT)["render.resolution"] == [360, 640]
    assert _sets(NIGHT, "--scale", "1/6") == sixth                 # --scale wins
    assert _sets(NIGHT, "--resolution", "180x320") == sixth        # so does --resolution
    assert _sets(NIGHT, "--scale", "1") == {}
    # a resolution given with --set is a camera size of the user's own: the variable stays out
    assert _sets(NIGHT, "--set", "render.resolution=[90,160]") == {"render.resolution": [90, 160]}


def test_an_explicit_set_wins_over_the_scale(no_env):
    """A scaled key the user also sets keeps the --set value whatever the order; the others scale."""
    for argv in (("--scale", "1/6", "--set", "mask.smooth_px=2"), ("--set", "mask.smooth_px=2", "--scale", "1/6")):
        args = build_parser().parse_args(["render", str(NIGHT), *argv])
        overrides, scaling = _overrides_and_scaling(args)
        spec = load_scene(NIGHT, overrides)
        assert spec.mask.smooth_px == 2.0 and spec.render.resolution == (180, 320)
        assert spec.attenuator.serve_min_mirrors == 24 and scaling.kept == ("mask.smooth_px",)
    # --resolution names the resolution: it wins over --set render.resolution
    spec = load_scene(NIGHT, _overrides(build_parser().parse_args(
        ["render", str(NIGHT), "--set", "render.resolution=[540,960]", "--resolution", "180x320"])))
    assert spec.render.resolution == (180, 320)


def test_dmd_mirrors_is_the_same_scaling_up_to_the_dmds_own_mirrors(no_env):
    """highbeam_plate simulates the DLP6500 at 368x640: --dmd-mirrors is --resolution 1080x1920,
    scale 3 (1920 / 640; the DMD's aspect is not quite the scene's, so not --scale 3's 1104 rows)."""
    scene = SCENES / "highbeam_plate"
    up = _sets(scene, "--dmd-mirrors")
    assert up == _sets(scene, "--resolution", "1080x1920")
    assert {k: v for k, v in _sets(scene, "--scale", "3").items() if k != "render.resolution"} == \
        {k: v for k, v in up.items() if k != "render.resolution"}
    assert up["render.resolution"] == [1080, 1920] and up["mask.smooth_px"] == 4.0 * 3
    # and from a 1/6-scale night_road run back to the scene's own camera
    sixth = _overrides(build_parser().parse_args(["render", str(NIGHT), "--scale", "1/6"]))
    back = load_scene(NIGHT, [*sixth, *_overrides(build_parser().parse_args(
        ["render", str(NIGHT), "--dmd-mirrors", *[a for o in sixth for a in ("--set", o)]]))[len(sixth):]])
    full = load_scene(NIGHT)
    for sec, key in (("render", "resolution"), ("objective", "focal_length_m"), ("objective", "guard_max_px"),
                     ("mask", "smooth_px"), ("attenuator", "serve_min_mirrors")):
        assert getattr(getattr(back, sec), key) == pytest.approx(getattr(getattr(full, sec), key), rel=1e-5)


def test_the_headline_states_the_scale_and_the_way_back(no_env):
    """The lines `poevp render` ends with: what was scaled, and a hint that restores the DMD's own
    mirrors (for night_road, the scene file's own camera: --scale 1, never focal x 6 of the
    already-full focal length)."""
    from poevp_optics.apps.run.headline import dmd_scale_line, scale_line

    for flag in (("--scale", "1/6"), ("--resolution", "180x320")):
        overrides, scaling = _overrides_and_scaling(build_parser().parse_args(["render", str(NIGHT), *flag]))
        spec = load_scene(NIGHT, overrides)
        line = scale_line(scaling)
        for part in ("1/6 scale", " ".join(flag), "180x320 mirrors", "f 11.51 mm", "mask.smooth_px 4",
                     "attenuator.serve_min_mirrors 24", "the same field"):
            assert part in line, (part, line)
        hint = dmd_scale_line(spec, scaling)
        assert "1/6 scale" in hint and f"--scale 1 in place of {' '.join(flag)}" in hint
        assert "focal_length_m" not in hint
    overrides, scaling = _overrides_and_scaling(build_parser().parse_args(["render", str(SCENES / "highbeam_plate"),
                                                                           "--scale", "1/2"]))
    assert "--dmd-mirrors in place of --scale 1/2" in dmd_scale_line(load_scene(SCENES / "highbeam_plate",
                                                                                overrides), scaling)
    assert scale_line(None) == ""


@pytest.mark.parametrize("argv, words", [
    (("--scale", "0"), ("--scale", "outside")),
    (("--scale", "1/0"), ("--scale", "fraction")),
    (("--scale", "abc"), ("--scale",)),
    (("--scale", "1/6", "--resolution", "180x320"), ("--resolution", "--scale")),
    (("--scale", "1/6", "--dmd-mirrors"), ("--dmd-mirrors", "--scale")),
])
def test_bad_scales_are_one_line(no_env, capsys, argv, words):
    assert main(["validate", str(NIGHT), "--no-load", *argv]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and all(w in err for w in words), err


def test_a_bad_environment_variable_is_one_line(monkeypatch, capsys):
    monkeypatch.setenv("POEVP_SCALE", "a sixth")
    assert main(["validate", str(NIGHT), "--no-load"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "POEVP_SCALE" in err


def test_validate_honours_the_environment_variable(monkeypatch, capsys):
    monkeypatch.setenv("POEVP_SCALE", "1/6")
    assert main(["validate", str(NIGHT), "--no-load"]) == 0
    assert "180x320" in capsys.readouterr().out


@pytest.mark.slow
def test_night_road_at_one_sixth_scale_keeps_the_plate_in_band(tmp_path, no_env):
    """`poevp render scenes/night_road --scale 1/6`, 6 frames: after the two white initialisation
    frames the plate's white (90th percentile of its box in the 8-bit capture) sits in the
    exposure controller's 0.4-0.9 band of full scale in every loop frame, as the scene promises
    at its own 1920x1080 mirrors. spp 2 without the plate's extra samples: the percentile pools
    the plate's ~300 pixels, so its MC scatter is a few % of the 0.5 band width."""
    out = tmp_path / "nr"
    assert main(["render", str(NIGHT), "--scale", "1/6", "--frames", "6", "--spp", "2", "--set", "render.roi_spp=0",
                 "--out", str(out), "--quiet"]) == 0
    r = json.loads((out / "report.json").read_text())
    assert r["resolution"] == [180, 320] and r["metrics"]["init_frames"] == 2
    white = r["metrics"]["plate_white_after_init"]
    assert white["band"] == [0.4, 0.9] and len(white["per_frame"]) == 4
    assert all(0.4 <= w <= 0.9 for w in white["per_frame"]), white["per_frame"]
    assert white["in_band_fraction"] == 1.0


def test_every_scaled_key_is_a_scene_key_and_a_scaled_value_stays_in_its_bounds(no_env):
    """scene/scale.py's table names keys the loader accepts; a camera 256x the smoke scene's
    width would ask mask.smooth_px = 4 x 256 = 1024 mirrors, above its bound 1000: it keeps the
    bound, so the run is refused for what it is (its memory), not for a key the user never set."""
    import dataclasses

    from poevp_optics.scene.scale import SCALED_KEYS
    from poevp_optics.scene.spec import SECTIONS

    for key in SCALED_KEYS:
        section, name = key.split(".")
        assert name in {f.name for f in dataclasses.fields(SECTIONS[section])}, key
    big = _sets(SCENES / "smoke", "--resolution", "12288x16384")
    assert big["render.resolution"] == [12288, 16384] and big["mask.smooth_px"] == 1000.0
