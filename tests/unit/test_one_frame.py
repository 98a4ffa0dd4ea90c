"""One still frame renders (the first thing an optics engineer renders to check a lens): a run
with fewer frames than the loop's white initialisation frames shows every mask white and says
so, on every shipped scene; a scene whose mask law reads no prediction gets no loop defaults."""

from __future__ import annotations

import json
import math
import re
import shutil

import numpy as np
import pytest

from poevp_optics.cli import main
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES

SHIPPED = sorted(p.parent.name for p in SCENES.glob("*/scene.toml"))
#: The widest render each shipped scene is cut down to here (mirrors across): small enough that
#: the fifteen scenes render in well under a minute, wide enough for each scene's plate or chart.
WIDTH = 80


def _small_scale(scene: str) -> str:
    """1/n with n the smallest integer bringing the scene's width to <= WIDTH."""
    w = load_scene(SCENES / scene).render.resolution[1]
    return f"1/{max(1, math.ceil(w / WIDTH))}"


def _render(tmp_path, scene, *flags) -> dict:
    out = tmp_path / "out"
    assert main(["render", str(scene), "--out", str(out), "--quiet", *flags]) == 0
    return json.loads((out / "report.json").read_text())


def test_every_shipped_scene_is_found():
    assert len(SHIPPED) >= 15 and {"night_road", "dr_chart36", "exr_highbeam", "ldr_highlight_demo"} <= set(SHIPPED)


@pytest.mark.parametrize("scene", SHIPPED)
def test_one_frame_renders_on_every_shipped_scene(tmp_path, capsys, scene):
    """`--frames 1` on each scene (frame sources and the chart included), cut down with --scale:
    one frame, its mask all white where the loop starts with white initialisation frames (every
    mirror at the top level: mask_mean = 1 exactly), the note and the headline line saying so,
    and the headline's noun singular."""
    spec = load_scene(SCENES / scene)
    r = _render(tmp_path, SCENES / scene, "--frames", "1", "--scale", _small_scale(scene), "--spp", "2",
                "--set", "render.roi_spp=0")
    assert r["frames"] == 1 and len(r["per_frame"]) == 1
    assert max(r["resolution"]) <= WIDTH
    said = capsys.readouterr().out
    assert re.search(r"rendered 1 frame of ", said) and "1 frames" not in said
    if spec.dmd.enabled and spec.loop.init_frames >= 1:
        f = r["per_frame"][0]
        assert f["init"] is True and f["mask_mean"] == 1.0
        assert r["metrics"]["init_frames"] == 1
        assert any(n.startswith("the 1 frame is a white initialisation frame") for n in r["notes"])
        assert "the 1 frame is a white initialisation frame" in said and "no predictor ran" in said
        if "predict" in r["stages"]:                 # a causal predictor: built, never run
            assert r["stages"]["predict"]["frames"] == 0


def _scene_with_mask(tmp_path, mask_toml: str):
    """scenes/smoke with its [mask], [loop] and [predictor] replaced by `mask_toml` alone."""
    folder = tmp_path / "scene"
    shutil.copytree(SCENES / "smoke", folder)
    toml = (folder / "scene.toml").read_text()
    toml = toml[:toml.index("[mask]")] + mask_toml
    (folder / "scene.toml").write_text(toml)
    return folder


def test_a_white_law_scene_gets_no_loop_defaults_and_renders_one_frame(tmp_path):
    """mask.law = "white" reads no prediction: no [loop] or [predictor] defaults (the report's
    defaults_applied is absent), so the one-frame run has no predictor to refuse."""
    folder = _scene_with_mask(tmp_path, '[mask]\nlaw = "white"\n')
    spec = load_scene(folder)
    assert spec.defaults_applied == ()
    assert spec.predictor.name == "oracle" and spec.loop.mode == "open"    # the dataclasses' own
    r = _render(tmp_path, folder, "--frames", "1", "--spp", "2")
    assert "defaults_applied" not in r and r["frames"] == 1
    assert r["per_frame"][0]["mask_mean"] == 1.0


def test_a_law_that_reads_a_prediction_still_gets_the_loop_defaults_and_one_frame_renders(tmp_path):
    """The counter-case: mask.law = "target" reads the prediction, so the scene gets the best
    loop (track_net, demodulated, 2 white frames); one frame renders white, no predictor runs."""
    folder = _scene_with_mask(tmp_path, '[mask]\nlaw = "target"\n')
    spec = load_scene(folder)
    assert {"loop.mode=demodulated", "predictor.name=track_net", "loop.init_frames=2"} <= set(spec.defaults_applied)
    r = _render(tmp_path, folder, "--frames", "1", "--spp", "2")
    assert r["per_frame"][0]["init"] is True and r["per_frame"][0]["mask_mean"] == 1.0
    assert r["stages"]["predict"]["frames"] == 0


def test_compare_still_needs_a_frame_after_the_white_ones(tmp_path, capsys):
    """`compare` sets predictors side by side: with no frame after the white ones there is
    nothing to compare, one line naming loop.init_frames."""
    rc = main(["compare", str(SCENES / "smoke"), "--frames", "2", "--out", str(tmp_path / "c"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "loop.init_frames" in err and len(err.strip().splitlines()) == 1


def test_the_prediction_free_laws_are_the_laws_whose_mask_ignores_the_prediction():
    """defaults.PREDICTION_FREE_LAWS against control/masks.py's registry, by behaviour: each law
    applied to two predictions (a mid-grey frame, and the same frame clipped) gives the same mask
    exactly when it reads no prediction."""
    from poevp_optics.camera.camera import Camera
    from poevp_optics.control.loop_step import predicted_mask
    from poevp_optics.control.masks import MASK_LAWS, MaskSpec
    from poevp_optics.scene.defaults import PREDICTION_FREE_LAWS

    camera = Camera.from_params(load_scene(SCENES / "smoke").resolved.camera)
    grey = np.full(camera.shape, 100.0, np.float32)
    clipped = np.full(camera.shape, 255.0, np.float32)
    ignores = {law for law in MASK_LAWS
               if np.array_equal(predicted_mask(camera, MaskSpec(law=law), grey, 0),
                                 predicted_mask(camera, MaskSpec(law=law), clipped, 0))}
    assert ignores == set(PREDICTION_FREE_LAWS)
