"""`poevp search --refine` (apps/search/refine.py) without Dask: a search folder of one finished
trial (its point run as a trial runs, its render stored), refined from there. The refinement
replays the trial exactly (its plate whites are the trial's), lowers the differentiable camera's
objective within the bounds, moves only the searched coefficients, and its objective "after" is
the search metric of a real camera run at the refined settings; a start it cannot move from
and a question it does not model each say why in one line and run nothing."""

from __future__ import annotations

import json

import numpy as np
import pytest

from poevp_optics.apps.run.render_run import run_frames
from poevp_optics.apps.search.refine import FILE, METRIC, refine_best
from poevp_optics.apps.search.search import Question, load_scenes, parse_params
from poevp_optics.apps.search.space import Objective, metric_value
from poevp_optics.render.render_cache import RenderCache
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES

#: smoke at 24x32, 4 frames (2 after the white initialisation), the paper's law with a 1-px
#: mask blur; the lamp at 13 kcd puts the plate's LDR white at ~0.95 of full scale (above the
#: 40-90 % band, not clipped), so Eq. 2's coefficients decide where its white lands
BASE = ["render.resolution=[24,32]", "timing.frames=4", "outputs.previews=false", "outputs.contact_sheet=false",
        "mask.law='threshold_exp'", "mask.smooth_px=1.0", "spectra.lamp.intensity_cd=13000.0"]
PARAMS = ["mask.vs=100.0:250.0", "mask.a=0.5:1.0"]
GROUP = "refine-test"


def run_point(out, base, values: dict, name: str):
    """One point as a search runs it: report.json in points/<name>, the render stored in (or
    replayed from) the search's renders/."""
    spec = load_scene(SCENES / "smoke", [*base, *(f"{k}={v}" for k, v in values.items())])
    folder = out / "points" / name
    folder.mkdir(parents=True)
    cache = RenderCache(GROUP, (out / "renders",), out / "renders", name)
    report = run_frames(spec, folder, False, write_images=False, render_cache=cache)[0]
    return folder, report


def search_folder(tmp_path, base, values):
    out = tmp_path / "s"
    _, report = run_point(out, base, values, "best")
    value = metric_value(report, METRIC)
    best = {"trial": 0, "objective": value, "settings": values, "points": ["best"]}
    return out, best, report


def question(metric=METRIC, direction="maximize", params=PARAMS):
    return Question(parse_params(params), Objective(metric, direction))


#: a trial whose (Vs, a) dim the plate's white below the band on both loop frames
START = {"mask.vs": "243.1100127779888", "mask.a": "0.8767613211963574"}


@pytest.fixture(scope="module")
def searched(tmp_path_factory):
    return search_folder(tmp_path_factory.mktemp("refine"), BASE, START)


def test_refined_settings_run_by_the_camera_put_the_plate_in_the_band(searched):
    out, best, report = searched
    best = dict(best)
    before = report["metrics"]["plate_white_after_init"]["per_frame"]
    assert best["objective"] == 0.0 and all(w < 0.4 for w in before)        # dimmed below the band
    ran = []

    def run_points(values):
        ran.append(values)
        folder, rep = run_point(out, BASE, values, f"refined{len(ran)}")
        return [(folder, {"value": metric_value(rep, METRIC), "constraints": []})]

    r = refine_best(load_scenes([str(SCENES / "smoke")], [BASE]), question(), out, best, run_points,
                    log=lambda *a: None)
    assert json.loads((out / FILE).read_text()) == json.loads(json.dumps(r))
    assert r["refined"] and len(ran) == 1 and r["frames"] == [2]
    assert r["model_after"] < 0.01 * r["model_before"]
    vs, a = float(r["settings"]["mask.vs"]), float(r["settings"]["mask.a"])
    assert 100.0 <= vs <= 250.0 and 0.5 <= a <= 1.0 and (vs, a) != (243.1100127779888, 0.8767613211963574)
    assert set(r["settings"]) == {"mask.vs", "mask.a"}                    # b was not searched: not moved
    assert r["set_line"] == f"--set mask.vs={r['settings']['mask.vs']} --set mask.a={r['settings']['mask.a']}"
    # objective after = the in-band fraction of the refined run's own per-frame whites
    rep = json.loads((out / "points" / "refined1" / "report.json").read_text())
    whites = rep["metrics"]["plate_white_after_init"]["per_frame"]
    assert r["objective_after"] == float(np.mean([0.4 <= w <= 0.9 for w in whites])) == 1.0
    assert r["improved"] and r["feasible"] and r["objective_before"] == 0.0
    assert rep["render_reuse"]["key"] == report["render_reuse"]["key"]    # the stored render, replayed
    (out / FILE).unlink()


def test_a_flat_start_or_another_question_says_why_and_runs_nothing(tmp_path):
    def run_points(values):
        raise AssertionError("nothing should run")

    quiet = {"log": lambda *a: None}
    scenes = load_scenes([str(SCENES / "smoke")], [BASE])
    start = {"mask.vs": "200.0", "mask.a": "0.9"}
    best = {"trial": 0, "objective": 0.0, "settings": start, "points": ["x"]}
    out = tmp_path / "q"
    out.mkdir()
    r = refine_best(scenes, question("metrics.entropy_roi.encoded", "maximize"), out, best, run_points, **quiet)
    assert not r["refined"] and r["note"].startswith("not differentiable:") and "metrics.entropy_roi" in r["note"]
    r = refine_best(scenes, question(params=["mask.target=0.1:0.9"]), out, best, run_points, **quiet)
    assert not r["refined"] and "none of mask.vs, mask.a, mask.b" in r["note"]
    other = load_scenes([str(SCENES / "smoke")], [[*BASE, "mask.law='threshold_ratio'"]])
    r = refine_best(other, question(), out, best, run_points, **quiet)
    assert not r["refined"] and "'threshold_ratio'" in r["note"]
    assert json.loads((out / FILE).read_text())["note"] == r["note"]
    # the shipped lamp (20 kcd) clips the plate in the LDR frame the oracle predicts from: Eq. 2
    # takes a clipped pixel to a^inf = 0 whatever the coefficients
    clipped = [b for b in BASE if not b.startswith("spectra.lamp")]
    out, best, _ = search_folder(tmp_path, clipped, start)
    r = refine_best(load_scenes([str(SCENES / "smoke")], [clipped]), question(), out, best, run_points, **quiet)
    assert not r["refined"] and r["note"].startswith("flat: the plate's prediction is clipped")
    assert r["iterations"] == 0 and r["model_after"] == r["model_before"]


def test_refine_needs_the_trial_it_replays(searched):
    """A replay that does not reproduce the trial's plate whites refuses to refine (here: a
    best.json whose settings are not those its point ran)."""
    out, best, _ = searched
    best = {**best, "settings": {"mask.vs": "200.0", "mask.a": "0.9"}}
    r = refine_best(load_scenes([str(SCENES / "smoke")], [BASE]), question(), out, best,
                    lambda v: pytest.fail("nothing should run"), log=lambda *a: None)
    assert not r["refined"] and "differ from the best trial's" in r["note"]
