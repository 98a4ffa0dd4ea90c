"""Dynamic-range chart (issue 5): the DR figures and each limit's physics.

Runs `run_chart` on the shipped 36-patch chart at 160x160 (patches of ~19 px, 8 repeats). The
closed forms: EMVA 1288 DR of the sensor preset; the headroom the mask adds is -20 log10 of the
darkest usable level's transmission (bit depth 1/(2^B - 1), leakage 1/CR, white fill).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from poevp_optics.apps.run.chart import PAPER_DB, run_chart
from poevp_optics.core.exceptions import SceneError
from poevp_optics.scene.load import load_scene
from ..conftest import SCENES

SMALL = ["render.resolution=[160,160]", "chart.roi_inset_px=2", "chart.repeats=8",
         "chart.reference_camera=''"]


def chart(tmp_path, *extra, name="c"):
    spec = load_scene(SCENES / "dr_chart36", SMALL + list(extra))
    out = tmp_path / name
    out.mkdir()
    return run_chart(spec, out, progress=False), out


def gain_db(r):
    d = r["details"]
    return 20 * math.log10(d["encoded"]["iso15739"]["l_max_cd_m2"] / d["ldr"]["iso15739"]["l_max_cd_m2"])


@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    return chart(tmp_path_factory.mktemp("chart"))


def test_ldr_12bit_matches_emva_and_8bit_is_reported(default_run):
    r, out = default_run
    dr = r["dynamic_range_db"]
    emva = dr["ldr"]["emva"]
    assert 69.0 < emva < 73.0                        # IMX253 preset: 10.4 ke- / ~3.2 e- at SNR 1
    assert abs(dr["ldr"]["iso15739"] - emva) < 3.0
    assert dr["ldr"]["snr10"] < dr["ldr"]["iso15739"] - 20
    # 8-bit readout: per-pixel EMVA capped near 59 dB; the chart figure and the note are there
    assert 55.0 < dr["ldr_8bit"]["emva"] < 59.5
    assert dr["ldr_8bit"]["iso15739"] < dr["ldr"]["iso15739"]
    assert "quantisation" in r["eight_bit_note"]
    saved = json.loads((out / "report.json").read_text())
    assert saved["dynamic_range_db"]["ldr"]["iso15739"] == pytest.approx(dr["ldr"]["iso15739"])
    for f in ("chart_curves.png", "chart_images.png", "patches.csv", "radiance.exr",
              "reconstruction.exr", "mask.png"):
        assert (out / f).is_file(), f


def test_chart_is_rendered_once_and_radiometrically_exact(default_run):
    r, _ = default_run
    assert r["render"]["calls"] == 2                 # one render_with_error: 2 MC splits
    assert r["render"]["patch_radiance_max_rel_error"] < 1e-5
    assert "render_repeat" in r["skipped_stages"] and "relay" in r["skipped_stages"]
    assert r["settle"]["converged"] and 1 <= r["settle"]["frames"] <= 6


def test_encoded_dr_at_least_110_db_and_bit_depth_binds(default_run):
    r, _ = default_run
    enc = r["dynamic_range_db"]["encoded"]["iso15739"]
    assert enc >= 110.0
    lim = r["limits"]
    assert lim["upper_end"] == "mask_bit_depth" and lim["lower_end"] == "sensor_noise"
    floor = 1 / 255 + (1 - 1 / 255) / 1000.0         # level 1 plus leakage while off
    assert lim["available_gain_db"] == pytest.approx(-20 * math.log10(floor), abs=1e-6)
    assert gain_db(r) == pytest.approx(lim["available_gain_db"], abs=1.5)


@pytest.mark.parametrize("override, binding, expect_gain_db", [
    ("dmd.contrast_ratio=100.0", "dmd_contrast", -20 * math.log10(1 / 255 + (254 / 255) / 100)),  # ~37 dB
    ("dmd.bits=6", "mask_bit_depth", -20 * math.log10(1 / 63 + (62 / 63) / 1000)),                # ~35 dB
])
def test_each_dmd_limit_moves_the_gain_as_its_physics_says(tmp_path, default_run, override, binding,
                                                           expect_gain_db):
    r, _ = chart(tmp_path, override)
    assert r["limits"]["upper_end"] == binding
    assert r["limits"]["available_gain_db"] == pytest.approx(expect_gain_db, abs=0.05)
    assert gain_db(r) == pytest.approx(expect_gain_db, abs=1.5)
    base = default_run[0]["dynamic_range_db"]["encoded"]["iso15739"]
    assert r["dynamic_range_db"]["encoded"]["iso15739"] < base - 6


def test_paper_white_fill_caps_the_gain_near_8_db(tmp_path):
    # the paper's Fig. 7 timing: t_I = 33.33 ms, t_D = 20 ms, DMD white outside the window
    r, _ = chart(tmp_path, "timing.exposure_s=0.03333", "timing.dmd_window_s=0.020")
    assert r["limits"]["upper_end"] == "white_fill"
    fill = (0.03333 - 0.020) / 0.03333
    assert r["limits"]["floor_parts"]["white_fill"] == pytest.approx(fill, rel=1e-6)
    assert gain_db(r) == pytest.approx(-20 * math.log10(fill + 0.6 / 255), abs=1.0)
    assert r["dynamic_range_db"]["encoded"]["iso15739"] < r["dynamic_range_db"]["ldr"]["iso15739"] + 10


def test_relay_flare_lowers_the_encoded_dr(tmp_path, default_run):
    r, _ = chart(tmp_path, "relay.glare_fraction=0.05", "relay.glare_sigma_px=40.0")
    base = default_run[0]["dynamic_range_db"]["encoded"]["iso15739"]
    assert r["dynamic_range_db"]["encoded"]["iso15739"] < base - 3
    assert r["limits"]["lower_end"] == "relay_flare"
    assert "by the relay's glare (g = 0.05)" in r["limits"]["explanation"]      # the optic that spreads it
    # the LDR camera, with unattenuated patches 1e3 x saturation, is flooded by the glare
    assert r["dynamic_range_db"]["ldr"]["iso15739"] < 40


def test_reference_camera_reports_the_papers_figures(tmp_path):
    spec = load_scene(SCENES / "dr_chart36", SMALL[:-1] + ["chart.max_iterations=6"])
    out = tmp_path / "ref"
    out.mkdir()
    r = run_chart(spec, out, progress=False)
    ref = r["reference_camera"]
    assert ref["scene"] == "lab_rail" and ref["paper_db"] == PAPER_DB
    assert ref["comparison"]["ldr"]["paper"] == 70.35 and ref["comparison"]["encoded"]["paper"] == 120.74
    sim = ref["comparison"]["encoded"]["simulated"]
    # lab_rail's timing (white fill) caps the gain near 8 dB: the note says so
    assert sim - ref["comparison"]["ldr"]["simulated"] < 10.0
    assert "white fill" in ref["note"]


def test_not_a_chart_is_a_clear_error(tmp_path):
    spec = load_scene(SCENES / "smoke")
    with pytest.raises(SceneError, match="chart.patches"):
        run_chart(spec, tmp_path)
    with pytest.raises(SceneError, match="chart.densities"):
        load_scene(SCENES / "dr_chart36", ["chart.densities=[0.0, 1.0]"])
    with pytest.raises(SceneError, match="spectra.patch_03"):
        load_scene(SCENES / "dr_chart36", ["spectra.patch_03.kind='radiance'",
                                           "spectra.patch_03.source='cie:A'",
                                           "spectra.patch_03.luminance_cd_per_m2=1.0"])


def test_patch_snr_follows_shot_and_read_noise(default_run):
    """Temporal noise of LDR patches (12-bit) against sqrt(mu + sigma_d^2) in electrons."""
    r, _ = default_run
    rows = [p for p in r["patches"]["ldr"] if not p["clipped"] and p["mean_electrons"] > 20]
    sd = r["emva"]["sigma_d_e"]
    for p in rows:
        mu = p["mean_electrons"]
        noise_e = p["temporal_noise"] / p["mean_signal"] * mu
        assert noise_e == pytest.approx(np.sqrt(mu * (1 + 0) + sd ** 2), rel=0.12), p


def test_objective_glare_floor_is_reported_and_matches_its_closed_form(tmp_path, default_run):
    """`poevp chart` with the objective's veiling glare (g = 2 %, halo 0.05-5 deg, r^-2): the
    report's glare floor at the darkest patch is VGI = g x the halo's energy beyond the patch's
    equivalent radius rho, computed here by integrating the normalised halo numerically (not the
    module's closed form), -20 log10 VGI in dB; it sits beside the DMD's floor and binds when it
    is below the LDR DR + the DMD's headroom. The glare is in the image the mirrors see, so the
    measured encoded DR is lower than without it."""
    from scipy.integrate import quad

    g, rc_deg, ro_deg, n = 0.02, 0.05, 5.0, 2.0
    r, out = chart(tmp_path, "objective.glare_fraction=0.02", "objective.glare_core_radius_deg=0.05",
                   "objective.glare_outer_radius_deg=5.0")
    o = r["objective"]
    rho = o["glare"]["black_radius_px"]
    f_px = 0.025 / 7.56e-6                            # focal length in mirrors (objective defaults)
    rc, ro = f_px * math.tan(math.radians(rc_deg)), f_px * math.tan(math.radians(ro_deg))

    def halo(x):                                       # un-normalised: flat core, r^-n out to ro
        return 1.0 if x < rc else (x / rc) ** -n

    total = quad(lambda x: 2 * math.pi * x * halo(x), 0, ro, points=[rc], limit=200)[0]
    beyond = quad(lambda x: 2 * math.pi * x * halo(x), rho, ro, points=[rc] if rho < rc else None, limit=200)[0]
    vgi = g * beyond / total
    assert o["glare"]["vgi"] == pytest.approx(vgi, rel=1e-6)
    # rho is the whole darkest patch's (ISO 18844: the black patch, not its measuring region):
    # the layout's 20 mm patches at a 25 mm pitch (scene.xml) make its side 0.8 x the pitch of
    # the two densest patches' centroids in the written radiance; within a pixel a side
    import cv2
    from poevp_optics.core.io import read_exr

    y = read_exr(out / "radiance.exr")[0]["Y"].astype(np.float64)
    dark2 = sorted(r["patches"]["encoded"], key=lambda p: -p["density"])[:2]
    cents = []
    for row in dark2:
        sel = (np.abs(y - row["true_signal"]) <= 1e-3 * row["true_signal"]).astype(np.uint8)
        _, _, stats, cen = cv2.connectedComponentsWithStats(sel)
        cents.append(cen[1 + np.argmax(stats[1:, 4])])
    side = 0.8 * float(np.hypot(*(cents[0] - cents[1])))          # sensor px
    px_per_mirror = math.sqrt(dark2[0]["pixels"] / math.pi) / o["glare"]["measuring_radius_px"]
    whole_side = math.sqrt(math.pi) * rho * px_per_mirror            # the square of the report's disc
    assert abs(whole_side - side) <= 1.0, (whole_side, side)
    assert rho > o["glare"]["measuring_radius_px"]
    # the lower end names the optic that spreads the light: the objective's veiling glare
    if r["limits"]["lower_end"] != "sensor_noise":
        assert r["limits"]["lower_end"] == "objective_flare"
        assert "the objective's veiling glare (g = 0.02" in r["limits"]["explanation"]
    assert o["glare"]["floor_db"] == pytest.approx(-20 * math.log10(vgi), abs=1e-6)
    assert o["dmd_floor_db"] == pytest.approx(r["limits"]["available_gain_db"])
    cap = r["dynamic_range_db"]["ldr"]["iso15739"] + o["dmd_floor_db"]
    assert o["binding"] == ("objective glare" if o["glare"]["floor_db"] < cap else "DMD attenuation floor")
    # the chart's own veil (dark card around the patches) is below the white-surround VGI
    assert 0 < o["glare"]["chart_veil_ratio"] < o["glare"]["vgi"]
    enc = r["dynamic_range_db"]["encoded"]["iso15739"]
    assert enc < default_run[0]["dynamic_range_db"]["encoded"]["iso15739"]
