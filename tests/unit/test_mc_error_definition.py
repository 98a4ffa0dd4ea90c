"""The MC error a user reads (issue 27): the frame figure leaves out the pixels clipped in the
capture (full scale whatever their radiance estimate) and the guard band the sensor never sees;
the headline leads with the ROI (plate) error and states the clipped share."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from poevp_optics.apps.run.render_run import unclipped_mc_error
from poevp_optics.render.progressive import pixel_rel_errors, rel_error, rel_error_unclipped

MAX_DN = 4095


def _case(seed=3, g=2, h=20, w=30):
    """A road of radiance ~1 with 1 % per-pixel standard error, six lamp pixels at 1e6 with a
    50 % error (clipped in the capture), and a guard band of `g` carrying a 1e5 error."""
    rng = np.random.default_rng(seed)
    H, W = h + 2 * g, w + 2 * g
    mean = rng.uniform(0.5, 1.5, (H, W))
    var = (0.01 * mean) ** 2
    lamps = [(5, 7), (5, 8), (6, 7), (6, 8), (12, 20), (12, 21)]           # field-of-view coordinates
    for y, x in lamps:
        mean[g + y, g + x], var[g + y, g + x] = 1e6, (0.5e6) ** 2
    var[:g, :] = var[-g:, :] = 1e10                                        # guard band: never captured
    dn = np.full((h, w), 1000.0)
    for y, x in lamps:
        dn[y, x] = MAX_DN
    cam = SimpleNamespace(params=SimpleNamespace(max_dn=MAX_DN), guard_px=g, mirror_shape=(H, W),
                          to_mirror=lambda img: np.pad(img, g, mode="edge"))
    ex = SimpleNamespace(radiance=SimpleNamespace(data=mean.astype(np.float32)), variance=var,
                         rel_error=rel_error(mean, var))
    return cam, ex, dn, mean, var, lamps


def test_clipped_pixels_with_huge_variance_leave_the_frame_error():
    cam, ex, dn, mean, var, lamps = _case()
    g, (h, w) = cam.guard_px, dn.shape
    # independent: the unclipped field of view by explicit indexing, RMS error over its mean
    keep = [(y, x) for y in range(h) for x in range(w) if (y, x) not in lamps]
    m = np.array([mean[g + y, g + x] for y, x in keep], dtype=np.float64)
    v = np.array([var[g + y, g + x] for y, x in keep])
    expected = np.sqrt(v.mean()) / m.mean()
    assert 0.009 < expected < 0.012                         # ~1 %: the road's own error
    got = unclipped_mc_error(cam, ex, dn)
    assert np.isclose(got["rel_error_unclipped"], expected, rtol=1e-6)
    assert np.isclose(got["clipped_fraction"], len(lamps) / (h * w))
    assert ex.rel_error > 100 * expected                     # the all-pixel figure the lamps dominate
    # each pixel's own error: 1 % everywhere that is left
    assert np.isclose(got["rel_error_pixel_median"], 0.01, rtol=1e-4)
    assert np.isclose(got["rel_error_pixel_p90"], 0.01, rtol=1e-4)


def test_unclipped_error_without_clipping_is_the_plain_error_and_all_clipped_is_none():
    rng = np.random.default_rng(1)
    mean, var = rng.uniform(1, 2, (8, 9)), rng.uniform(0, 0.1, (8, 9))
    err, frac = rel_error_unclipped(mean, var, np.zeros((8, 9), bool))
    assert frac == 0 and np.isclose(err, rel_error(mean, var))
    assert rel_error_unclipped(mean, var, np.ones((8, 9), bool)) == (None, 1.0)
    med, p90 = pixel_rel_errors(mean, var, np.zeros((8, 9), bool))
    r = np.sort((np.sqrt(var) / mean).ravel())
    assert np.isclose(med, (r[35] + r[36]) / 2) and r[63] <= p90 <= r[65]


def test_headline_leads_with_the_roi_error_and_states_the_clipped_share():
    from poevp_optics.apps.run.headline import mc_error_line

    spec = SimpleNamespace(render=SimpleNamespace(roi_shape="plate"), source=SimpleNamespace(renders=True))
    r = {"rel_error": 3.064, "rel_error_roi": 0.0727, "rel_error_unclipped": 0.021, "clipped_fraction": 0.00017,
         "rel_error_pixel_median": 0.009, "rel_error_pixel_p90": 0.089}
    line = mc_error_line(r, spec)
    assert line.startswith("7.27% plate (ROI)")
    assert "over the 99.98% of the frame not clipped" in line and "2.10%" in line and "306.40% with the clipped" in line
    assert "median 0.90%, p90 8.90%" in line
    r2 = {k: v for k, v in r.items() if "pixel" not in k}
    assert "without the 0.017% of pixels clipped" in mc_error_line(r2, spec)


def test_demo_states_the_dmd_it_simulates_and_the_keys_for_its_own_mirrors():
    """night_road renders the DLP6500's own 1920 x 1080 mirrors (TI DLPS053); at 1/6 scale the
    line names the scale and the keys back: the objective's focal length and the mask's sizes in
    mirrors x 6 (areas x 36), which `--dmd-mirrors` applies in one flag."""
    from poevp_optics.apps.run.headline import dmd_scale_line
    from poevp_optics.scene.load import load_scene
    from tests.conftest import SCENES

    full = load_scene(SCENES / "night_road")
    assert full.render.resolution == (1080, 1920)
    assert "at its own 1920x1080 mirrors" in dmd_scale_line(full)
    sixth = ["render.resolution=[180,320]", f"objective.focal_length_m={full.objective.focal_length_m / 6:.6g}",
             f"mask.smooth_px={full.mask.smooth_px / 6:g}",
             f"attenuator.serve_min_mirrors={full.attenuator.serve_min_mirrors // 36}"]
    spec = load_scene(SCENES / "night_road", sixth)
    line = dmd_scale_line(spec)
    assert "DLP6500" in line and "1/6 scale" in line
    assert "--set render.resolution=[1080,1920]" in line
    assert f"objective.focal_length_m={spec.objective.focal_length_m * 6:.6g}" in line
    assert f"mask.smooth_px={spec.mask.smooth_px * 6:.4g}" in line
    assert f"attenuator.serve_min_mirrors={spec.attenuator.serve_min_mirrors * 36}" in line
    back = load_scene(SCENES / "night_road", [*sixth, *line.split("i.e. ")[1].replace("--set ", "").split()])
    assert (back.render.resolution, back.objective.focal_length_m, back.mask.smooth_px,
            back.attenuator.serve_min_mirrors) == (full.render.resolution, full.objective.focal_length_m,
                                                   full.mask.smooth_px, full.attenuator.serve_min_mirrors)
    from poevp_optics.cli import _overrides, build_parser

    args = build_parser().parse_args(["render", str(SCENES / "night_road"), "--dmd-mirrors",
                                      *[x for o in sixth for x in ("--set", o)]])
    assert _overrides(args)[len(sixth):] == line.split("i.e. ")[1].replace("--set ", "").split()
