"""The paper's own camera simulation (apps/evaluate/paper_camera.py) and Eq. 2's third reading, against
closed forms written out here: Hadamard product then clip at 255, the DMD floor, the noise
statistics, and the loop's frames (He et al. 2024, Sec. 4.A and 6)."""

import numpy as np
import pytest

from poevp_optics.apps.evaluate import paper_camera as pc
from poevp_optics.control.masks import MaskSpec, threshold_linear

PHYS = dict(contrast_ratio=1000.0, saturation_e=10_000.0, read_noise_e=2.0)


@pytest.mark.parametrize("a,b", [(0.9, 0.0), (0.7, 0.2)])
def test_threshold_linear_closed_form(a, b):
    vs = 200.0
    x = np.array([0.0, 199.9, 200.0, 230.0, 255.0])
    want = [255.0, 255.0] + [255.0 - a * (v - b * vs) * 255.0 / v for v in (200.0, 230.0, 255.0)]
    np.testing.assert_allclose(threshold_linear(x, vs, a, b), want, rtol=0, atol=1e-12)


def test_threshold_linear_simulation_setting_is_a_tenfold_dimmer():
    """(a, b) = (0.9, 0): every value above Vs gets transmission 1 - a = 0.1, whatever x."""
    x = np.linspace(200.0, 255.0, 56)
    np.testing.assert_allclose(threshold_linear(x, 200.0, 0.9, 0.0) / 255.0, 0.1, atol=1e-12)


def test_capture_is_hadamard_then_clip_in_code_values():
    h = np.array([[100.0, 1000.0], [300.0, 2550.0]])
    m = np.array([[255.0, 26.0], [255.0, 26.0]])
    got = pc.capture(h, m, pc.PaperEffects(), rng=None, **PHYS)
    # 100 passes; 1000 x 26/255 = 101.96 -> 102; 300 clips at 255; 2550 x 26/255 = 260 -> 255.
    np.testing.assert_array_equal(got, [[100, 102], [255, 255]])
    assert got.dtype == np.uint8


def test_dmd_floor_is_the_off_state_leakage():
    h = np.array([[2000.0, 50_000.0]])
    m = np.array([[0.0, 0.0]])
    ideal = pc.capture(h, m, pc.PaperEffects(), rng=None, **PHYS)
    floor = pc.capture(h, m, pc.PaperEffects(dmd_floor=True), rng=None, **PHYS)
    np.testing.assert_array_equal(ideal, [[0, 0]])
    np.testing.assert_array_equal(floor, [[2, 50]])  # H / CR, CR = 1000


def test_noise_statistics_follow_shot_and_read_noise():
    rng = np.random.default_rng(7)
    n = 400
    h = np.full((n, n), 128.0)
    got = pc.capture(h, np.full((n, n), 255.0), pc.PaperEffects(noise=True), rng=rng, **PHYS)
    e = 128.0 * PHYS["saturation_e"] / 255.0
    sigma = np.sqrt(e + PHYS["read_noise_e"] ** 2) * 255.0 / PHYS["saturation_e"]
    var = sigma**2 + 1.0 / 12.0  # plus the rounding to integer code values
    npx = n * n
    assert abs(got.mean() - 128.0) < 5 * np.sqrt(var / npx)
    assert abs(got.var() - var) < 5 * var * np.sqrt(2.0 / npx)


def _sequence(e=9.0, frames=6, shape=(64, 96)):
    """A plate-like gradient with a Gaussian highlight (peak O (E + 1) in code values) moving 6 px/frame."""
    yy, xx = np.mgrid[: shape[0], : shape[1]].astype(float)
    hdr = []
    for j in range(frames):
        o = 40.0 + 100.0 * xx / shape[1]
        g = np.exp(-((yy - 32) ** 2 + (xx - 20 - 6 * j) ** 2) / (2 * 6.0**2))
        hdr.append(o * (e * g + 1.0))
    return pc.PaperSequence(hdr, {}, {}, e)


def test_oracle_loop_is_the_closed_form():
    """Frames 0-1 white (LDR cut-off), then the oracle's mask from the true LDR frame: Eq. 2
    (third reading, no smoothing) -> 8-bit levels -> Hadamard -> clip, all written out here."""
    seq = _sequence()
    spec = MaskSpec(law="threshold_linear", vs=200.0, a=0.9, b=0.0, smooth_px=0.0)
    caps, secs = pc.poevp_captures(seq, None, spec, pc.PaperEffects(), **PHYS)
    assert len(secs) == len(seq.hdr) - pc.INIT_FRAMES
    for j, h in enumerate(seq.hdr):
        if j < pc.INIT_FRAMES:
            want = np.clip(np.rint(h), 0, 255)
        else:
            ldr = np.clip(h, 0, 255).astype(np.float32).astype(np.float64)  # masks see float32 frames
            # 255 - a x 255 / x = 255 (1 - a) = 25.5, an exact tie: its rounding follows x's float error.
            with np.errstate(divide="ignore", invalid="ignore"):
                m = np.where(ldr < 200.0, 255.0, np.rint(255.0 - 0.9 * ldr * 255.0 / ldr))
            want = np.clip(np.rint(h * m / 255.0), 0, 255)
        np.testing.assert_array_equal(caps[j], want)
    # The law unclips the highlight wherever O (E + 1) x 0.1 < 255 (peak here 140 x 10 x 0.1 < 255).
    assert max(int((caps[j] == 255).sum()) for j in range(pc.INIT_FRAMES, len(seq.hdr))) == 0
    assert int((caps[0] == 255).sum()) > 0


def test_ratio_reading_cannot_unclip_a_clipped_highlight():
    """Under the ratio reading a clipped prediction is dimmed by at most a Vs / 255 = 0.706: a pixel
    with O (E + 1) above 255 / 0.706 stays clipped even with the oracle (why Table 2 needs reading 3)."""
    seq = _sequence()
    spec = MaskSpec(law="threshold_ratio", vs=200.0, a=0.9, b=0.0, smooth_px=0.0)
    caps, _ = pc.poevp_captures(seq, None, spec, pc.PaperEffects(), **PHYS)
    for j in range(pc.INIT_FRAMES, len(seq.hdr)):
        h = seq.hdr[j]
        want_clipped = h * np.rint(255.0 * 0.9 * 200.0 / 255.0) / 255.0 >= 254.5
        assert np.array_equal(caps[j] == 255, want_clipped)
        assert want_clipped.sum() > 0


def test_fusion_uses_the_papers_exposure_coefficients():
    """Mertens fusion of three identical flat frames at 1/8, 1/5, 1 of a value v returns a value
    between v/8 and v (a convex blend of the three exposures)."""
    v = 160.0
    seq = pc.PaperSequence([np.full((32, 32), v)] * 4, {}, {}, 0.0)
    out = pc.fusion_captures(seq, deghost=False)
    assert sorted(out) == [2, 3]
    f = float(out[2].mean())
    assert v / 8 - 1 <= f <= v + 1
    assert np.ptp(out[2]) <= 1


def test_effects_label_names_each_effect():
    assert pc.PaperEffects().label == "paper camera"
    assert pc.PaperEffects(True, False, True).label == "paper camera + DMD floor + noise"


def test_linear_light_is_the_srgb_decoding_extended_above_one():
    """V = 1 -> `white` of full scale; V = 30 (E = 29 at V = 1) -> white ((30.055) / 1.055)^2.4,
    ~3000-fold more light than the paper's 30-fold code value (IEC 61966-2-1 formula written out)."""
    seq = pc.PaperSequence([np.array([[0.0, 0.04045 * 255, 255.0, 30 * 255.0]])], {}, {}, 29.0)
    got = pc.as_light(seq).hdr[0][0]
    w = pc.LINEAR_WHITE * 255.0
    want = [0.0, w * 0.04045 / 12.92, w, w * ((30.0 + 0.055) / 1.055) ** 2.4]
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert want[3] / want[2] > 3000


def test_evaluate_camera_flags_refuse_in_one_line():
    from pathlib import Path

    from poevp_optics.apps.evaluate.evaluate import EvalConfig, check_config
    from poevp_optics.core.exceptions import UserError

    root = Path(__file__).resolve().parents[2] / "scenes"
    with pytest.raises(UserError, match="not an ldr_highlight scene"):
        check_config(EvalConfig(scene=root / "highbeam_plate", camera="paper"))
    with pytest.raises(UserError, match="--paper-effects: unknown"):
        check_config(EvalConfig(scene=root / "ldr_highlight_demo", camera="paper", paper_effects=("glare",)))
    with pytest.raises(UserError, match="only with --camera paper"):
        check_config(EvalConfig(scene=root / "ldr_highlight_demo", paper_effects=("noise",)))
    check_config(EvalConfig(scene=root / "ldr_highlight_demo", camera="paper", paper_effects=("noise", "dmd_floor")))


def test_method_images_run_every_method_on_the_papers_camera():
    seq = _sequence(frames=5)
    spec = MaskSpec(law="threshold_linear", vs=200.0, a=0.9, b=0.0, smooth_px=0.0)
    imgs, secs = pc.method_images(seq, ("ldr", "fusion_classic", "oracle"), spec, pc.PaperEffects(),
                                  lambda name: None, **PHYS)
    assert set(imgs) == {"ldr", "fusion_classic", "oracle"}
    assert sorted(imgs["fusion_classic"]) == [2, 3, 4] and sorted(imgs["oracle"]) == list(range(5))
    assert all(v.dtype == np.uint8 for m in imgs.values() for v in m.values())
    np.testing.assert_array_equal(imgs["ldr"][3], np.clip(np.rint(seq.hdr[3]), 0, 255))
