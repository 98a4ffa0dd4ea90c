"""Metered initialisation frames (`loop.meter_init`, control/loop_step.py): a white frame says of a
clipped region only "at least saturated", so without metering the first loop frame dims it by the
controller's prior; with it, the second initialisation frame is dimmed by the prior where the
first clipped, measures the region, and the first loop frame's mask is the law's level for that
measurement. A static EXR scene: a gradient at 10-50 % of full scale and a highlight at X = 20x
saturation (a plate under our beams is 5-300x), the `hold` predictor (no motion to predict)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from poevp_optics.apps.run.render_run import run_frames
from poevp_optics.camera.camera import Camera
from poevp_optics.core.io import write_exr
from poevp_optics.scene.load import load_scene
from tests.helpers import exr_sequence_scene

H, W, N = 40, 64, 4                  # sensor px, frames: two initialisation frames, two loop frames
Y0, Y1, X0, X1 = 10, 30, 20, 44      # the highlight's box
X_SAT, PRIOR, TARGET, LOW, HIGH = 20.0, 40.0, 0.6, 0.4, 0.9


def _scene(folder: Path, meter: bool) -> Path:
    return exr_sequence_scene(folder, H, W, N, f"""\
        [mask]
        law = "exposure_controller"
        target = {TARGET}
        band_low = {LOW}
        band_high = {HIGH}
        smooth_px = 1.0
        min_level = 1
        first_guess = {PRIOR}
        clip_step = 5.0
        [loop]
        mode = "demodulated"
        init_frames = 2
        meter_init = {str(meter).lower()}
        [predictor]
        name = "hold"
        """)


def _write_frames(folder: Path, sat: float) -> None:
    y, x = np.mgrid[0:H, 0:W]
    f = sat * (0.1 + 0.3 * x / W + 0.1 * y / H)
    f[Y0:Y1, X0:X1] = X_SAT * sat
    for j in range(N):
        write_exr(folder / "frames" / f"f_{j:02d}.exr", {"Y": f.astype(np.float32)})


def _law_level(rel: np.ndarray, demand_sat: float, p) -> int:
    """The band law for one mirror of all-white demand `demand_sat` x saturation, from the level
    table alone: the most exposure keeping the signal <= the aim, or where that falls under the
    band, <= the band's top (levels >= 1)."""
    e = demand_sat * p.saturation_capacity_e
    aim, top = [(f * p.max_dn - p.offset_dn) / p.gain_dn_per_e for f in (TARGET, HIGH)]
    lv = np.arange(1, len(rel))
    fit = lv[e * rel[1:] <= aim]
    level = int(fit[np.argmax(rel[fit])]) if fit.size else int(lv[np.argmin(rel[1:])])
    if e * rel[level] < (LOW * p.max_dn - p.offset_dn) / p.gain_dn_per_e:
        fit = lv[e * rel[1:] <= top]
        level = int(fit[np.argmax(rel[fit])]) if fit.size else level
    return level


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = {}
    for meter in (False, True):
        folder = _scene(tmp_path_factory.mktemp(f"meter_{meter}"), meter)
        _write_frames(folder, 1.0)
        cam = Camera.from_params(load_scene(folder).resolved.camera)
        _write_frames(folder, cam.params.saturation_capacity_e / (cam.electrons_per_radiance() * cam.white_exposure_s(0)))
        report, kept = run_frames(load_scene(folder), folder / "out", progress=False, write_images=False,
                                  keep_frames=tuple(range(N)))
        out[meter] = (cam, report, kept)
    return out


def _centre_level(kept, j) -> int:
    return int(kept[j]["mask"][(Y0 + Y1) // 2, (X0 + X1) // 2])


def _white(kept, j) -> float:
    return float(np.percentile(kept[j]["capture"][Y0:Y1, X0:X1], 90)) / 255.0


def test_white_frames_give_the_first_loop_frame_only_the_prior(runs):
    cam, report, kept = runs[False]
    rel = cam.level_exposure_s(2) / cam.level_exposure_s(2)[-1]
    assert _white(kept, 0) == 1.0 and _white(kept, 1) == 1.0       # clipped: "at least saturated"
    assert _centre_level(kept, 2) == _law_level(rel, PRIOR, cam.params)
    assert _white(kept, 2) < LOW                                    # 20x dimmed as if 40x: under the band


def test_metered_frame_is_dimmed_by_the_prior_and_the_first_loop_frame_by_the_measurement(runs):
    cam, report, kept = runs[True]
    rel1 = cam.level_exposure_s(1) / cam.level_exposure_s(1)[-1]
    rel2 = cam.level_exposure_s(2) / cam.level_exposure_s(2)[-1]
    assert _white(kept, 0) == 1.0
    assert _centre_level(kept, 1) == _law_level(rel1, PRIOR, cam.params)
    assert int(kept[1]["mask"][2, 2]) == cam.top_level               # the unclipped gradient stays white
    assert 0.0 < _white(kept, 1) < 1.0                              # measured, not clipped
    # the measurement behind level L1 has shot noise 1/sqrt(e); the envelope takes the largest
    # of the (2R + 1)^2 = 49 mirrors around the centre (R = 3): within 4 sigma above X
    sigma = 1.0 / np.sqrt(X_SAT * cam.params.saturation_capacity_e * rel1[_law_level(rel1, PRIOR, cam.params)])
    assert _law_level(rel2, X_SAT * (1 + 4 * sigma), cam.params) <= _centre_level(kept, 2) <= _law_level(
        rel2, X_SAT, cam.params)
    assert LOW <= _white(kept, 2) <= HIGH
    frames = report["per_frame"]
    assert frames[1].get("init") and frames[1].get("metered") and not frames[0].get("metered")
    assert not frames[2].get("init")


@pytest.mark.parametrize("sets, words", [(['mask.law="target"'], "'exposure_controller' mask law"),
                                         (['predictor.name="oracle"'], "nothing to meter")])
def test_metering_without_the_controller_or_with_the_oracle_is_refused(tmp_path, sets, words):
    from poevp_optics.core.exceptions import SceneError

    folder = _scene(tmp_path, True)
    _write_frames(folder, 1.0)
    with pytest.raises(SceneError, match=words) as err:
        load_scene(folder, sets)
    assert "loop.meter_init" in str(err.value)
