"""Predictors, weights files, loop modes and initialisation (issue 4)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from poevp_optics.cli import main
from poevp_optics.control.predictors import make_predictor
from poevp_optics.control.predictors.dmvfn import (FULL, LITE, DMVFN, WeightsError, count_parameters,
                                        load_weights, save_weights)
from poevp_optics.control.predictors.flow import FlowExtrapolation, forward_splat
from poevp_optics.analysis.prediction_metrics import (highlight_iou, ms_ssim, psnr, saturated_iou, tail,
                                                     undimmed_fraction)
from tests.conftest import SCENES


def _square(x0, h=64, w=96):
    img = np.full((h, w), 40.0, np.float32)
    rng = np.random.default_rng(0)
    img += rng.uniform(0, 30, (h, w)).astype(np.float32)     # texture for the flow
    img[20:40, x0:x0 + 16] = 255.0
    return img


def test_flow_extrapolates_a_moving_highlight_better_than_hold():
    frames = [_square(10), _square(16), _square(22)]
    pred_flow = FlowExtrapolation()(frames[:2])
    pred_hold = make_predictor("hold")(frames[:2])
    assert highlight_iou(pred_flow, frames[2]) > highlight_iou(pred_hold, frames[2])


def test_forward_splat_brightest_wins():
    frame = np.array([[10.0, 200.0, 30.0]], np.float32)
    flow = np.zeros((1, 3, 2), np.float32)
    flow[0, 1, 0] = 1.0                                   # the bright pixel moves onto the 30
    out = forward_splat(frame, flow)
    assert out[0, 2] == 200.0


def test_forward_splat_keeps_a_standing_clipped_pixel_under_a_dimmer_landing():
    """A halo pixel (200 DN) carried by the flow onto a clipped pixel that stands (255, no flow)
    leaves it clipped; onto a dim standing pixel (30 DN) it lands. The halo's own place, left
    behind, shows the background (the grey erosion: the darkest pixel within the largest
    displacement + 1 px)."""
    frame = np.array([[10.0, 200.0, 255.0, 200.0, 30.0]], np.float32)
    flow = np.zeros((1, 5, 2), np.float32)
    flow[0, 1, 0] = 1.0                                   # 200 onto the standing 255
    flow[0, 3, 0] = 1.0                                   # 200 onto the standing 30
    out = forward_splat(frame, flow)
    np.testing.assert_array_equal(out[0], [10.0, 10.0, 255.0, 30.0, 200.0])


@pytest.mark.parametrize("corner", [(28, 43), (0, 0), (56, 86)])
def test_forward_splat_background_is_the_whole_frame_erosion(corner):
    """Where a moving pixel leaves, it shows the grey erosion of the whole frame over the
    largest displacement + 1 px (BORDER_REPLICATE at the frame's edges): computed here on the
    whole frame and compared with the splat, for a bright patch inside the frame and on two of
    its corners, with the darkest pixels placed right at the erosion's reach from the patch."""
    import cv2

    rng = np.random.default_rng(sum(corner))
    h, w = 64, 96
    frame = rng.uniform(50, 120, (h, w)).astype(np.float32)
    flow = np.zeros((h, w, 2), np.float32)
    y0, x0 = corner
    frame[y0:y0 + 8, x0:x0 + 10] = 200.0
    flow[y0:y0 + 8, x0:x0 + 10] = (6.0, -4.0)
    r = int(np.ceil(np.hypot(6.0, 4.0))) + 1                 # the erosion's reach: 9 px
    for y, x in ((y0 + 3, x0 - r), (y0 + 3, x0 + 9 + r), (y0 - r, x0 + 4), (y0 + 7 + r, x0 + 4)):
        if 0 <= y < h and 0 <= x < w:
            frame[y, x] = 5.0                                 # darkest, right at the reach
    out = forward_splat(frame, flow)
    background = cv2.erode(frame, np.ones((2 * r + 1, 2 * r + 1), np.uint8), borderType=cv2.BORDER_REPLICATE)
    moving = frame >= 128.0
    ys, xs = np.nonzero(moving)
    tx, ty = xs + 6, ys - 4
    landed = np.zeros((h, w), bool)
    ok = (tx >= 0) & (tx < w) & (ty >= 0) & (ty < h)
    landed[ty[ok], tx[ok]] = True
    left = moving & ~landed                                   # left behind, nothing lands there
    assert left.sum() >= 20 and (background[left] == 5.0).any()
    np.testing.assert_array_equal(out[left], background[left])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_saturated_components_match_opencv_labelling(seed):
    """Region boxes, areas and centroids of `saturated_components` equal OpenCV's 8-connected
    labelling of the same map (its labels put in our raster order of first pixels)."""
    import cv2

    from poevp_optics.control.predictors.flow import saturated_components

    rng = np.random.default_rng(seed)
    sat = rng.random((60, 90)) > 0.93
    sat[0:5, 0:7] = sat[50:60, 80:90] = True                 # regions on the frame's corners
    n, labels, stats, cents, _ = saturated_components(sat)
    m, cv_labels, cv_stats, cv_cents = cv2.connectedComponentsWithStats(sat.astype(np.uint8), connectivity=8)
    assert n == m > 20
    first = {}
    for lab in cv_labels.ravel():                              # raster order of first pixels
        if lab and lab not in first:
            first[lab] = len(first) + 1
    order = sorted(first, key=first.get)
    np.testing.assert_array_equal(stats[1:], cv_stats[order])
    np.testing.assert_allclose(cents[1:], cv_cents[order], rtol=0, atol=1e-9)
    for ours, theirs in enumerate(order, 1):
        np.testing.assert_array_equal(labels == ours, cv_labels == theirs)


@pytest.mark.parametrize("d", [(2.5, -1.5), (-0.5, 3.5), (1.5, 0.0)])
def test_forward_splat_moves_a_region_by_a_half_pixel_whole(d):
    """A clipped 5 x 5 region moved by a shift with half-pixel parts lands as one 5 x 5 block,
    shifted by the shift rounded half up, with no stripes of its old pixels left inside."""
    frame = np.full((20, 20), 10.0, np.float32)
    frame[6:11, 6:11] = 255.0
    flow = np.zeros((20, 20, 2), np.float32)
    flow[6:11, 6:11] = d
    out = forward_splat(frame, flow)
    dx, dy = (int(np.floor(v + 0.5)) for v in d)
    expect = np.zeros((20, 20), bool)
    expect[6 + dy:11 + dy, 6 + dx:11 + dx] = True
    np.testing.assert_array_equal(out >= 254.5, expect)


def test_dmvfn_shapes_params_and_deterministic_inference():
    full, lite = DMVFN(FULL).eval(), DMVFN(LITE).eval()
    assert 3.0e6 < count_parameters(full) < 5.0e6          # paper: about 3.56 M
    assert 0.2e6 < count_parameters(lite) < 0.4e6          # about 0.28 M
    x = torch.rand(1, 3, 64, 96)
    with torch.no_grad():
        a, _, _ = full(x, x.roll(2, -1))
        b, _, _ = full(x, x.roll(2, -1))
    assert a.shape == x.shape and torch.equal(a, b)       # routing thresholded: no sampling


def test_weights_round_trip_and_clear_errors(tmp_path):
    m = DMVFN(LITE)
    p = tmp_path / "w.safetensors"
    save_weights(m, p, {"note": "test"})
    m2, meta = load_weights(p, expect=LITE)
    for (k, v), (_, v2) in zip(m.state_dict().items(), m2.state_dict().items()):
        assert torch.equal(v, v2), k
    assert meta["note"] == "test"
    with pytest.raises(WeightsError, match="expected"):
        load_weights(p, expect=FULL)
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(p.read_bytes()[:200])
    with pytest.raises(WeightsError, match="not a readable safetensors"):
        load_weights(bad)
    with pytest.raises(WeightsError, match="not found"):
        load_weights(tmp_path / "missing.safetensors")


def test_scene_with_corrupt_weights_gives_one_line_error(tmp_path, capsys):
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"\x00" * 64)
    rc = main(["render", str(SCENES / "smoke"), "--out", str(tmp_path / "o"), "--quiet",
               "--set", "predictor.name='dmvfn_lite'", "--set", f"predictor.weights='{bad}'"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "predictor.weights" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_prediction_metrics():
    a = np.random.default_rng(1).uniform(0, 255, (64, 64))
    assert psnr(a, a) == float("inf") and ms_ssim(a, a) == pytest.approx(1.0)
    assert ms_ssim(a, a + 20) < 1.0 and psnr(a, a + 5) == pytest.approx(20 * np.log10(255 / 5))


def _ms_ssim_by_definition(x, y, peak=255.0):
    """MS-SSIM written out (Wang, Simoncelli & Bovik 2003): the 11x11 Gaussian window (sigma 1.5)
    as one 2-D kernel correlated over the 'valid' region, contrast-structure at every scale,
    luminance at the last, 2x2 averaging between scales, the paper's five weights renormalised
    to the scales that fit the window."""
    from scipy.signal import correlate2d

    t = np.arange(11) - 5.0
    g = np.exp(-t * t / (2 * 1.5 ** 2))
    win = np.outer(g, g) / np.outer(g, g).sum()
    weights = np.array([0.0448, 0.2856, 0.3001, 0.2363, 0.1333])
    n = 1
    while n < 5 and min(x.shape) // 2 ** n >= 11:
        n += 1
    weights = weights[:n] / weights[:n].sum()
    c1, c2, out = (0.01 * peak) ** 2, (0.03 * peak) ** 2, 1.0
    for i, wt in enumerate(weights):
        m = {k: correlate2d(v, win, mode="valid") for k, v in
             {"x": x, "y": y, "xx": x * x, "yy": y * y, "xy": x * y}.items()}
        sxx, syy, sxy = m["xx"] - m["x"] ** 2, m["yy"] - m["y"] ** 2, m["xy"] - m["x"] * m["y"]
        cs = np.mean((2 * sxy + c2) / (sxx + syy + c2))
        if i == n - 1:
            out *= (np.mean((2 * m["x"] * m["y"] + c1) / (m["x"] ** 2 + m["y"] ** 2 + c1)) * cs) ** wt
        else:
            out *= cs ** wt
            h, w = x.shape[0] // 2 * 2, x.shape[1] // 2 * 2
            x, y = (v[:h, :w].reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3)) for v in (x, y))
    return out


@pytest.mark.parametrize("shape", [(181, 242), (40, 64)])
def test_ms_ssim_equals_its_definition(shape):
    """The separable, blurred-then-cropped evaluation equals the 2-D 'valid' correlation to float64
    rounding, on odd and even sizes, with five scales and with the fewer that fit a small image."""
    rng = np.random.default_rng(7)
    a = rng.uniform(0, 255, shape)
    b = np.clip(a + rng.normal(0, 25, shape), 0, 255)
    assert ms_ssim(a, b) == pytest.approx(_ms_ssim_by_definition(a, b), rel=1e-12)


def test_saturated_region_scores_count_misses_and_leave_out_empty_truths():
    """Closed forms on 10x10 clipped squares: shifted by 5 px the IoU is 50 / 150 and half the
    true square is left undimmed; a prediction that lost the highlight is a miss (IoU 0,
    undimmed 1); a truth with no highlight is not scored (NaN), never a free 1.0."""
    def sq(x0):
        img = np.full((32, 48), 30.0, np.float32)
        if x0 is not None:
            img[10:20, x0:x0 + 10] = 255.0
        return img
    assert saturated_iou(sq(10), sq(15)) == pytest.approx(1 / 3)
    assert undimmed_fraction(sq(10), sq(15)) == pytest.approx(0.5)
    assert saturated_iou(sq(None), sq(15)) == 0.0 and undimmed_fraction(sq(None), sq(15)) == 1.0
    assert np.isnan(saturated_iou(sq(10), sq(None))) and np.isnan(undimmed_fraction(sq(10), sq(None)))
    assert np.isnan(highlight_iou(sq(None), sq(None)))
    # tail: NaN frames left out and counted; p90 the 10th percentile of a score, the 90th of an
    # error (a real frame's value); an infinite error (a miss) is the worst
    iou = tail([1.0, float("nan"), 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.0], higher_is_better=True)
    assert (iou["n"], iou["left_out"], iou["worst"]) == (11, 1, 0.0)
    assert iou["median"] == pytest.approx(0.5) and iou["mean"] == pytest.approx(0.5) and iou["p90"] == pytest.approx(0.1)
    err = tail([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, float("inf")], higher_is_better=False)
    assert err["p90"] == 9.0 and err["worst"] == float("inf") and err["median"] == pytest.approx(5.5)
    assert np.isnan(tail([float("nan")], True)["mean"]) and tail([float("nan")], True)["left_out"] == 1


@pytest.mark.parametrize("mode", ["open", "raw", "demodulated"])
def test_loop_initialisation_and_modes(tmp_path, mode):
    out = tmp_path / mode
    assert main(["render", str(SCENES / "smoke"), "--out", str(out), "--quiet", "--frames", "4",
                 "--resolution", "48x64", "--set", "predictor.name='hold'",
                 "--set", f"loop.mode='{mode}'"]) == 0
    r = json.loads((out / "report.json").read_text())
    pf = r["per_frame"]
    assert [f.get("init", False) for f in pf] == [True, True, False, False]
    assert all(f["mask_mean"] == 1.0 for f in pf[:2])              # white masks while initialising
    assert r["stages"]["predict"]["frames"] == 2 and r["stages"]["predict"]["mode"] == mode
    assert "predict" not in r["skipped_stages"]
    assert 0 <= r["metrics"]["mask_error"]["iou"] <= 1


def test_oracle_also_starts_with_the_white_initialisation_frames(tmp_path):
    """Paper Sec. 3 / DESIGN.md: the first loop.init_frames frames are white for every predictor,
    the oracle included (it used to encode frame 0 already), so its averages after init are
    comparable with the causal predictors'."""
    out = tmp_path / "oracle"
    assert main(["render", str(SCENES / "smoke"), "--out", str(out), "--quiet", "--frames", "4",
                 "--resolution", "48x64", "--set", "predictor.name='oracle'"]) == 0
    r = json.loads((out / "report.json").read_text())
    pf = r["per_frame"]
    assert [f.get("init", False) for f in pf] == [True, True, False, False]
    assert all(f["mask_mean"] == 1.0 for f in pf[:2]) and all(f["mask_mean"] < 1.0 for f in pf[2:])
    for f in pf[:2]:             # white mask: the encoded capture is the LDR twin's exposure
        assert f["saturated_fraction_roi"]["encoded"] == pytest.approx(f["saturated_fraction_roi"]["ldr"], abs=0.05)
    m = r["metrics"]
    assert m["init_frames"] == 2
    for key in ("saturated_fraction_roi", "entropy_roi"):
        assert {"ldr_after_init", "encoded_after_init", "oracle_after_init"} <= set(m[key])


def test_no_predictor_without_dmd(tmp_path):
    out = tmp_path / "nodmd"
    assert main(["render", str(SCENES / "smoke"), "--out", str(out), "--quiet", "--frames", "2",
                 "--resolution", "24x32", "--set", "dmd.enabled=false",
                 "--set", "predictor.name='flow'"]) == 0
    r = json.loads((out / "report.json").read_text())
    assert "predict" in r["skipped_stages"] and "predict" not in r["stages"]


def test_predictor_input_per_mode():
    from types import SimpleNamespace

    from poevp_optics.camera.camera import Camera
    from poevp_optics.control.loop_step import predictor_input
    from poevp_optics.scene.load import load_scene
    spec = load_scene(SCENES / "smoke", ["render.resolution=[8,8]"])
    cam = Camera.from_params(spec.resolved.camera)
    ldr = SimpleNamespace(dn=np.full((8, 8), float(cam.params.max_dn)))
    enc = SimpleNamespace(dn=np.full((8, 8), 100.0))
    assert np.all(predictor_input("open", cam, ldr, enc, None, None, 0, spec.mask.clipped_gain) == 255)
    assert np.allclose(predictor_input("raw", cam, ldr, enc, None, None, 0, spec.mask.clipped_gain), 100.0 * 255 / cam.params.max_dn)
    # demodulated: a radiance giving 2x saturation with the white mask reads 510 (unclipped)
    est = np.full((8, 8), 2 * cam.params.saturation_capacity_e /
                  (cam.electrons_per_radiance() * cam.white_exposure_s(0)), np.float32)
    flags = np.zeros((8, 8), np.float32)
    x = predictor_input("demodulated", cam, ldr, enc, est, flags, 0, spec.mask.clipped_gain)
    assert np.allclose(x, 510.0, rtol=1e-5)
    flags[0, 0] = 1              # saturated behind a dimmed mirror: lower bound x clipped_gain
    x = predictor_input("demodulated", cam, ldr, enc, est, flags, 0, spec.mask.clipped_gain)
    assert np.isclose(x[0, 0], 510.0 * spec.mask.clipped_gain, rtol=1e-5)
    est[0, 0] *= 0.5             # saturated behind a white mirror (lower bound 255): clipped marker
    assert predictor_input("demodulated", cam, ldr, enc, est, flags, 0, spec.mask.clipped_gain)[0, 0] == 255.0


def _clipped_blob(t, speed, h=184, w=320, x0=20, touch_edge=False):
    """An 8-bit frame with a flat saturated rectangle (no texture inside: a clipped highlight)
    moving `speed` px/frame, a static saturated band along the bottom (a lit road) and a dim
    textured background; touch_edge: the rectangle runs out of the frame's left edge."""
    rng = np.random.default_rng(7)
    img = (30 + rng.uniform(0, 20, (h, w))).astype(np.float32)
    left = 0 if touch_edge else int(x0 + speed * t)
    img[40:110, left:int(x0 + 120 + speed * t)] = 255.0
    img[170:, 60:260] = 255.0
    return img


def _sat_x_range(img, rows=slice(40, 110)):
    xs = np.flatnonzero((img[rows] >= 254.5).any(0))
    return xs.min(), xs.max()


@pytest.mark.parametrize("speed", [16.0, 24.0, 32.0, 48.0])
@pytest.mark.parametrize("touch_edge", [False, True])
def test_flow_moves_a_clipped_region_by_its_speed(speed, touch_edge):
    """Constant velocity: the prediction of frame 2 from frames 0, 1 puts the saturated
    rectangle's leading edge at x0 + 119 + 2 v exactly (closed form), at speeds where DIS alone
    moved it 8-10 px (issue 20); the static band stays where it is."""
    frames = [_clipped_blob(t, speed, touch_edge=touch_edge) for t in range(2)]
    pred = FlowExtrapolation()(frames)
    lo, hi = _sat_x_range(pred)
    assert hi == 20 + 119 + 2 * speed
    if not touch_edge:
        assert lo == 20 + 2 * speed
    assert _sat_x_range(pred, slice(172, 184)) == (60, 259)


def test_flow_sees_texture_above_255_through_the_log_curve():
    """Demodulated-loop frames (above 255): a plate 100x over its surround moving 24 px/frame,
    with characters 30x darker than its white, is predicted 24 px on (its brightest column)."""
    def frame(t):
        img = np.full((96, 160), 20.0, np.float32)
        x = 20 + 24 * t
        img[30:60, x:x + 60] = 25500.0
        img[38:52, x + 10:x + 50:8] = 850.0                # dark strokes
        return img
    pred = FlowExtrapolation()([frame(0), frame(1)])
    cols = np.flatnonzero((pred >= 25500.0).any(0))
    assert (cols.min(), cols.max()) == (68, 127)
