"""Error-targeted rendering (render/progressive.py): a run reaches its MC error target, or stops
at render.max_spp and says so; the report's error budget names the target each term met."""

from __future__ import annotations

import json

import numpy as np

from poevp_optics.cli import main
from poevp_optics.render.exposures import render_exposures
from poevp_optics.render.progressive import Replicates, replicates_needed
from poevp_optics.render.renderer import Renderer
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES

SMALL = ["--quiet", "--frames", "2", "--resolution", "24x32", "--set", "render.subframes=2"]


def _report(tmp_path, *sets):
    out = tmp_path / "run"
    args = ["render", str(SCENES / "smoke"), "--out", str(out), *SMALL]
    for s in sets:
        args += ["--set", s]
    assert main(args) == 0
    return json.loads((out / "report.json").read_text())


def test_moving_run_reaches_its_target(tmp_path):
    target = 0.04
    r = _report(tmp_path, f"render.target_rel_error={target}", "render.max_spp=4096")
    for f in r["per_frame"]:
        assert f["target_met"] is True and f["rel_error_roi"] <= target
        assert all(s >= 4 for s in f["spp"])
    mc = r["errors"]["render_mc"]
    assert mc["target"] == target and mc["met"] is True and mc["rel"] <= target
    assert mc["spp_used"]["max"] > 4                         # the scene's 4 spp were not enough
    assert r["stages"]["render"]["met"] is True


def test_unreachable_target_stops_at_max_spp_and_says_so(tmp_path):
    r = _report(tmp_path, "render.target_rel_error=0.0005", "render.max_spp=16")
    mc = r["errors"]["render_mc"]
    assert mc["met"] is False and "render.max_spp = 16" in mc["note"]
    assert mc["spp_used"]["max"] <= 16 and mc["rel"] > 0.0005
    assert all(f["target_met"] is False for f in r["per_frame"])


def test_static_scene_renders_once_to_target():
    spec = load_scene(SCENES / "smoke", ["render.resolution=[24,32]", "motion.plate.velocity_m_per_s=[0.0,0.0,0.0]",
                                         "render.target_rel_error=0.03", "timing.frames=3"])
    assert spec.is_static
    r = Renderer(spec.resolved.render)
    exs = list(render_exposures(spec.resolved.render, r, progress=False))
    assert all(e.target_met and e.rel_error_roi <= 0.03 for e in exs)
    assert exs[0].radiance.data is exs[2].radiance.data      # rendered once, reused
    assert sum(exs[0].spp) * 24 * 32 > 0 and r.stats.calls == exs[0].spp[0] // 2


def test_replicates_are_welford_exact_and_prediction_bounded():
    rng = np.random.default_rng(3)
    xs = rng.normal(size=(7, 5, 4))
    reps = Replicates()
    for x in xs:
        reps.add(x, 2)
    np.testing.assert_allclose(reps.mean, xs.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(reps.variance_of_mean(), xs.var(axis=0, ddof=1) / 7, rtol=1e-12)
    assert reps.spp == 14
    # error ~ 1/sqrt(k): twice the target needs 4x the replicates (x SAFETY), capped
    assert replicates_needed(2, 0.02, 0.01, 1000) == 9
    assert replicates_needed(2, 0.02, 0.01, 5) == 5
    assert replicates_needed(4, 0.0101, 0.01, 1000) == 5
