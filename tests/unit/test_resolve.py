"""The scene is resolved once into its stages' inputs (scene/resolve.py).

- No function below apps/ receives the scene object: a profiler follows whole runs (a moving
  render, the night road with its exposure controller and report plug-ins, a DR chart) and lists
  every call of a core/sources/render/camera/control/analysis function given a `SceneSpec`.
- Following the run's scene value, it climbs back up fewer than 8 times.
- The spec stays what the TOML says: the controller prior scaled to our beams is *derived*
  (resolve), with the closed form first_guess x intensity_cd / prior_beam_cd.
- The renderer is built from a `RenderScene` made by hand (no scene TOML) and renders the same
  image, bit for bit, as the one resolved from the scene file; its clock's radiance nodes join
  the DMD's bit-plane boundaries computed here from t_D 2^b / (2^B - 1).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from poevp_optics.core.timing import ExposureClock, PlaneDisplay, TimingSpec
from poevp_optics.render.render_scene import RenderScene
from poevp_optics.render.renderer import Renderer
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES
from tests.scene_flow import RUNS, follow_run_isolated


@pytest.mark.parametrize("run", sorted(RUNS))
def test_no_scene_object_below_apps_and_few_climbs(tmp_path, run):
    flow = follow_run_isolated(run, tmp_path / "out", SCENES)
    assert flow.stops, "the tracer saw no scene value (it would pass vacuously)"
    assert flow.whole_scene_below_apps == [], sorted(set(flow.whole_scene_below_apps))
    # the stages below scene/ do receive their own parts
    assert {p for p, _, _ in flow.stops} & {"render", "camera", "sources"}
    assert flow.climbs < 8, (flow.climbs, flow.stops)


def test_the_controller_prior_is_derived_not_written_into_the_spec():
    cd = 3.0e5
    spec = load_scene(SCENES / "night_road", [f"spectra.highbeam.intensity_cd={cd}"])
    written = spec.mask.first_guess
    assert written == 22.0                                   # what the TOML (and defaults) say
    want = written * cd / spec.mask.prior_beam_cd
    assert spec.resolved.derived == {"mask.first_guess": pytest.approx(want, rel=1e-15)}
    assert spec.resolved.loop.mask.first_guess == pytest.approx(want, rel=1e-15)
    other = load_scene(SCENES / "highbeam_plate")
    assert dict(other.resolved.derived) == {}
    assert other.resolved.loop.mask == other.mask


def test_accuracy_is_one_field_shared_by_every_stage():
    r = load_scene(SCENES / "smoke", ["render.spp=3", "relay.guard_max_px=17"]).resolved
    assert r.accuracy.spp == 3 and r.accuracy.guard_max_px == 17
    assert r.render.accuracy is r.accuracy and r.camera.accuracy is r.accuracy


def test_clock_joins_the_bit_plane_boundaries():
    """B = 3 planes in a window of t_D from the exposure start: boundaries at t_D (1, 3, 7) / 7
    (lsb first: durations 1, 2, 4 sevenths); K = 3 uniform nodes at 0, T/2, T."""
    t = TimingSpec(fps=10.0, exposure_s=0.07, dmd_window_s=0.07)
    clock = ExposureClock(t, 3, PlaneDisplay(3, "lsb_first", 0.0))
    start = 2 / 10.0
    got = clock.subframe_times_s(2) - start
    want = sorted({0.0, 0.035, 0.07, 0.01, 0.03})
    np.testing.assert_allclose(got, want, atol=1e-15)
    w = clock.subframe_weights(2)
    assert w.sum() == pytest.approx(1.0, abs=1e-15)
    h = np.diff(want)
    np.testing.assert_allclose(w, np.r_[h[0], h[:-1] + h[1:], h[-1]] / 2 / 0.07, rtol=1e-12)
    assert np.allclose(ExposureClock(t, 3, None).subframe_times_s(2) - start, [0.0, 0.035, 0.07])


def test_renderer_from_a_render_scene_made_by_hand():
    """A RenderScene built field by field from the stages' params (the scene TOML unread:
    only Mitsuba's XML) renders what the resolved scene renders."""
    spec = load_scene(SCENES / "smoke", ["render.resolution=[12,16]", "render.spp=2"])
    r = spec.resolved.render
    by_hand = RenderScene(
        name="by_hand", toml_path=SCENES / "smoke" / "nowhere.toml", xml_path=r.xml_path, origin="test",
        render=spec.render, timing=spec.timing,
        clock=ExposureClock(spec.timing, spec.render.subframes,
                            PlaneDisplay(spec.dmd.bits, spec.dmd.bit_order, spec.dmd.settle_s)),
        motion=dict(spec.motion), spectra=dict(spec.spectra), flicker={}, sheeting={}, plate=spec.plate,
        road=spec.road, has_road=False, source=spec.source, sensor_qe=r.sensor_qe, accuracy=r.accuracy)
    assert dataclasses.replace(by_hand, name=r.name, toml_path=r.toml_path, origin=r.origin,
                               motion=r.motion, spectra=r.spectra, flicker=r.flicker,
                               sheeting=r.sheeting) == r
    a = Renderer(by_hand).render_with_error([1, 2], spec.render.spp)[0]
    b = Renderer(r).render_with_error([1, 2], spec.render.spp)[0]
    assert np.array_equal(a, b) and np.all(np.isfinite(a)) and a.max() > 0


def test_the_objective_numerics_are_the_runs_accuracy():
    """[objective]'s numerical keys reach the camera through the one Accuracy: the same scene
    with `objective_guard_max_px` = 1 in its accuracy renders a guard of 1 mirror for the
    objective (24 as the scene sets it), nothing else changed."""
    from poevp_optics.camera.camera import Camera

    spec = load_scene(SCENES / "night_road", ["render.resolution=[45,80]", "objective.focal_length_m=0.002878",
                                              "mask.smooth_px=1.0", "attenuator.serve_min_mirrors=6",
                                              "objective.guard_max_px=24"])
    cp = spec.resolved.camera
    assert cp.accuracy.objective_numerics() == {k: getattr(spec.objective, k) for k in
                                                ("field_samples", "band_samples", "pupil_rays", "support_energy",
                                                 "guard_max_px")}
    wide = Camera.from_params(cp)
    narrow = Camera.from_params(dataclasses.replace(cp, accuracy=dataclasses.replace(cp.accuracy,
                                                                                    objective_guard_max_px=1)))
    assert wide.objective_guard_px == 24 and narrow.objective_guard_px == 1
    assert narrow.objective.field_samples == wide.objective.field_samples == spec.objective.field_samples
