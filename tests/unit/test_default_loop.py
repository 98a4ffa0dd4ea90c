"""Best loop by default (issue 29, scene/defaults.py): a scene that chooses no mask law, loop
mode or predictor gets night_road's causal configuration, says so in its report, and unclips a
moving 100x highlight within two loop frames; the paper's open loop with `flow` does not."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from poevp_optics.apps.run.render_run import run_frames
from poevp_optics.camera.camera import Camera
from poevp_optics.core.io import write_exr
from poevp_optics.scene.defaults import BEST_LOOP
from poevp_optics.scene.load import load_scene
from tests.helpers import exr_sequence_scene

ROOT = Path(__file__).resolve().parents[2]
H, W, N, INIT = 48, 112, 7, 2            # sensor px; frames; night_road's two white frames
BOX_Y, BOX_H, BOX_W, STEP = 16, 16, 24, 8  # the highlight: 16x24 px, 8 px/frame to the right
PAPER = '[mask]\nlaw = "target"\n[loop]\nmode = "open"\n[predictor]\nname = "flow"\n'


def _scene(folder: Path, loop_toml: str) -> Path:
    """An EXR-sequence scene (sensor-weighted photon radiance, one frame per exposure)."""
    return exr_sequence_scene(folder, H, W, N, loop_toml)


def _box_x(j: int) -> int:
    return 8 + STEP * j


def _write_frames(folder: Path, sat: float) -> None:
    """A smooth gradient at 15-60 % of full scale `sat` under a highlight at 100x `sat`."""
    y, x = np.mgrid[0:H, 0:W]
    base = sat * (0.15 + 0.35 * x / W + 0.1 * y / H)
    for j in range(N):
        f = base.copy()
        f[BOX_Y:BOX_Y + BOX_H, _box_x(j):_box_x(j) + BOX_W] = 100.0 * sat
        write_exr(folder / "frames" / f"f_{j:02d}.exr", {"Y": f.astype(np.float32)})


def _run(folder: Path):
    """(spec, report, per-loop-frame highlight captures, 8-bit) of the scene in `folder`; the
    full-scale radiance from the camera's own electrons per radiance and full well."""
    _write_frames(folder, 1.0)
    cam = Camera.from_params(load_scene(folder).resolved.camera)
    sat = cam.params.full_well_e / (cam.electrons_per_radiance() * cam.white_exposure_s(0))
    _write_frames(folder, sat)
    spec = load_scene(folder)
    report, kept = run_frames(spec, folder / "out", progress=False, write_images=False,
                              keep_frames=tuple(range(N)))
    boxes = [kept[j]["capture"][BOX_Y:BOX_Y + BOX_H, _box_x(j):_box_x(j) + BOX_W] for j in range(INIT, N)]
    return spec, report, boxes


def test_a_scene_that_does_not_choose_gets_night_roads_loop():
    night = tomllib.loads((ROOT / "scenes" / "night_road" / "scene.toml").read_text())
    for section, (_, defaults) in BEST_LOOP.items():
        for key, value in defaults.items():
            if (section, key) == ("mask", "smooth_px"):    # in mirrors: night_road's 24 at 1920 mirrors is
                assert night[section][key] / 6 == value    # the 4 of its 1/6-scale camera (320 mirrors)
                continue
            assert night[section].get(key, value) == value, f"{section}.{key} differs from night_road"


@pytest.mark.parametrize("given, applied", [
    ("", {"mask.law=exposure_controller", "loop.mode=demodulated", "predictor.name=track_net"}),
    ('[mask]\nlaw = "threshold_exp"\n', {"loop.mode=demodulated", "predictor.name=track_net"}),
    ('[mask]\ntarget = 0.7\n[loop]\nmode = "open"\n', {"mask.law=exposure_controller", "predictor.name=track_net"}),
    ('[dmd]\nenabled = false\n', set()),
])
def test_defaults_apply_only_where_the_scene_does_not_choose(tmp_path, given, applied):
    folder = _scene(tmp_path, given)
    _write_frames(folder, 1.0)
    spec = load_scene(folder)
    chosen = {d for d in spec.defaults_applied if d.split("=")[0] in ("mask.law", "loop.mode", "predictor.name")}
    assert chosen == applied
    if "[mask]\ntarget" in given:           # a key the scene sets is kept; the law's other keys default
        assert spec.mask.target == 0.7 and "mask.target=0.6" not in spec.defaults_applied
    if "threshold_exp" in given:            # a chosen law keeps the dataclass defaults (paper one key away)
        assert spec.mask.min_level == 0 and spec.mask.target == 0.5
    assert "law" not in spec.raw.get("mask", {}) or "threshold_exp" in given   # raw: the scene as written


def test_default_loop_unclips_a_moving_100x_highlight_within_two_loop_frames(tmp_path):
    spec, report, boxes = _run(_scene(tmp_path / "default", ""))
    assert (spec.mask.law, spec.loop.mode, spec.predictor.name) == ("exposure_controller", "demodulated",
                                                                  "track_net")
    assert "predictor.name=track_net" in report["defaults_applied"]
    unclipped = [k for k, b in enumerate(boxes) if b.max() < 255]
    assert unclipped and unclipped[0] <= 2, [int((b == 255).mean() * 100) for b in boxes]
    assert all(boxes[k].max() < 255 for k in range(unclipped[0], len(boxes)))   # and stays unclipped


def test_paper_open_loop_with_flow_keeps_the_moving_highlight_clipped(tmp_path):
    """Why the default changed (issue 29): the flow-warped prediction of a clipped region falls
    below 255, and the `target` law no longer reads it as clipped."""
    spec, report, boxes = _run(_scene(tmp_path / "paper", PAPER))
    assert spec.defaults_applied == () and "defaults_applied" not in report
    assert all((b == 255).mean() > 0.5 for b in boxes), [int((b == 255).mean() * 100) for b in boxes]
