"""Camera chain: float32 vs float64 on the noise-free path, 220 dB scenes, zero masks, PSF
energy, reconstruction without Inf/NaN (issue 3)."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.camera.camera import Camera
from poevp_optics.camera.dmd import transmission_table
from poevp_optics.camera.reconstruct import UNEXPOSED, reconstruct
from poevp_optics.camera.relay import airy_psf, convolve, gaussian_psf, measured_psf
from poevp_optics.scene.load import load_scene
from poevp_optics.camera.sensor import NoiseSwitches
from poevp_optics.sources import spectra
from tests.conftest import ROOT, SCENES

H, W = 32, 48


def _camera(exposure_s, *extra, noise=False):
    fps = min(30.0, 0.5 / exposure_s)
    spec = load_scene(SCENES / "smoke", [f"render.resolution=[{H},{W}]", f"timing.fps={fps}",
                                         f"timing.exposure_s={exposure_s}",
                                         f"timing.dmd_window_s={exposure_s}", *extra])
    sw = None if noise else NoiseSwitches(False, False, True, False, False, False)
    return spec, Camera.from_params(spec.resolved.camera, sw)


@pytest.mark.parametrize("exposure_s", [1e-6, 1e-3, 0.0333, 10.0])
@pytest.mark.parametrize("mask_kind", ["zeros", "full", "ramp"])
def test_float32_chain_matches_float64_reference(exposure_s, mask_kind):
    """Radiance 1e-3..1e8 (220 dB) x every mask: electrons from the float32 DrJit chain agree
    with a float64 NumPy evaluation of sum_k T(v, k) L_k x etendue x throughput to 1e-4."""
    spec, cam = _camera(exposure_s)
    rad = np.logspace(-3, 8, H * W).reshape(H, W) * 1e12          # e- s-1 m-2 sr-1
    k = 4
    subs = [rad * (1 + 0.1 * j) for j in range(k)]
    top = cam.top_level
    mask = {"zeros": np.zeros((H, W)), "full": np.full((H, W), top),
            "ramp": np.arange(H * W).reshape(H, W) % (top + 1)}[mask_kind]
    cap = cam.capture([s.astype(np.float32) for s in subs], mask, 0, seed=1)
    table = transmission_table(np.arange(top + 1), spec.dmd, cam.schedule(0), k)   # float64
    ref = sum(table[mask.astype(int), j] * subs[j] for j in range(k)) * cam.electrons_per_radiance()
    assert np.all(np.isfinite(cap.signal_e)) and np.all(np.isfinite(cap.dn))
    np.testing.assert_allclose(cap.signal_e, ref, rtol=1e-4, atol=0)
    assert cap.dn.min() >= 0 and cap.dn.max() <= cam.params.max_dn


def test_reconstruction_never_inf_or_nan_even_with_zero_exposure():
    spec, cam = _camera(0.0333, "dmd.contrast_ratio=1e30", noise=True)
    rad = np.logspace(-3, 8, H * W).reshape(H, W).astype(np.float32) * 1e12
    cap = cam.capture([rad], np.zeros((H, W)), 0, seed=3)
    est, flags, _ = reconstruct(cap.dn, cap.exposure_s, cam.params, cam.etendue_m2_sr,
                                cam.throughput, spec.timing.exposure_s)
    assert np.all(np.isfinite(est)) and np.all(np.isfinite(flags))
    # with 1e-30 leakage the exposure is ~1e-32 s: flagged unexposed, estimate 0
    assert np.all((flags.astype(int) & UNEXPOSED) > 0) and np.all(est == 0)


def test_reconstruction_recovers_radiance_within_noise():
    spec, cam = _camera(0.0333, "sensor.bits=12", noise=True)
    rad = np.full((H, W), 1.0, np.float32)
    # choose a radiance giving ~40 % of full well with the white mask
    rad *= 0.4 * cam.params.full_well_e / (cam.electrons_per_radiance() * cam.white_exposure_s(0))
    mask = np.full((H, W), 64.0)                 # 25 % duty: under-exposed but unsaturated
    cap = cam.capture([rad], mask, 0, seed=4)
    est, flags, _ = reconstruct(cap.dn, cap.exposure_s, cam.params, cam.etendue_m2_sr,
                                cam.throughput, spec.timing.exposure_s)
    assert np.all(flags == 0)
    e = 0.4 * cam.params.full_well_e * cam.level_exposure_s(0)[64] / cam.white_exposure_s(0)
    # relative noise per pixel ~ sqrt(e) / e; mean over H*W pixels: 5 sigma bound
    assert abs(est.mean() / rad[0, 0] - 1) < 5 / np.sqrt(e * H * W) + 1e-3


def _blob_image(n=96):
    img = np.zeros((n, n))
    c = n // 2
    img[c - 8:c + 8, c - 8:c + 8] = 1e6
    img[c, c] = 1e10                            # a 200 dB hot pixel in the middle
    return img


@pytest.mark.parametrize("psf", [
    gaussian_psf(1.5),
    gaussian_psf(0.4),
    airy_psf(8.0, 3.45e-6, spectra.WAVELENGTHS_NM,
             spectra.sensor_response_e_per_J(spectra.load_spectrum("file:spectra/imx253_mono_qe.csv", emissive=True))),
    measured_psf(ROOT / "assets" / "psf" / "relay_example_psf.png"),
], ids=["gaussian1.5", "gaussian0.4", "airy_f8", "measured"])
def test_psf_conserves_flux(psf):
    """Unit-sum kernels; for an image whose content stays inside the frame after blurring, the
    total flux is conserved to 1e-5 (float64 accumulation: error ~1e-12)."""
    assert psf.kernel.sum() == pytest.approx(1.0, abs=1e-12)
    assert np.all(psf.kernel >= 0)
    img = _blob_image(96 + psf.kernel.shape[0])
    out = convolve(img, psf)
    assert abs(out.sum() / img.sum() - 1) < 1e-5
    assert np.all(np.isfinite(out)) and out.min() >= 0


def test_airy_width_scales_with_f_number():
    resp = spectra.sensor_response_e_per_J(spectra.load_spectrum("file:spectra/imx253_mono_qe.csv", emissive=True))
    a = airy_psf(4.0, 3.45e-6, spectra.WAVELENGTHS_NM, resp)
    b = airy_psf(16.0, 3.45e-6, spectra.WAVELENGTHS_NM, resp)
    # the central pixel holds less of the energy when the disc is wider
    ca, cb = a.kernel[a.kernel.shape[0] // 2, a.kernel.shape[0] // 2], b.kernel[b.kernel.shape[0] // 2, b.kernel.shape[0] // 2]
    assert cb < ca
    assert 0 < a.truncation_error < 2e-3


def test_veiling_glare_kernel_splits_energy_and_conserves_flux():
    """(1 - g) core + g halo: unit sum, the halo's share outside the core's support is ~g."""
    from poevp_optics.camera.relay import PSFContext, RelaySpec, build_psf
    g = 0.05
    psf = build_psf(RelaySpec(psf="gaussian", sigma_px=1.0, glare_fraction=g, glare_sigma_px=12.0),
                    PSFContext(3.45e-6, 4.0))
    assert psf.name == "gaussian+glare"
    assert psf.kernel.sum() == pytest.approx(1.0, abs=1e-12)
    c = psf.kernel.shape[0] // 2
    core = psf.kernel[c - 4:c + 5, c - 4:c + 5].sum()           # the core's 4-sigma box
    halo_in_box = g * 81 / (2 * np.pi * 144)                    # halo peak density x box area
    assert core == pytest.approx(1 - g + halo_in_box, abs=2e-3)
    assert build_psf(RelaySpec(psf="delta"), PSFContext(3.45e-6, 4.0)) is None
    glare_only = build_psf(RelaySpec(psf="delta", glare_fraction=g), PSFContext(3.45e-6, 4.0))
    assert glare_only.kernel[glare_only.kernel.shape[0] // 2, glare_only.kernel.shape[0] // 2] > 1 - g
    img = _blob_image(96 + psf.kernel.shape[0])
    assert abs(convolve(img, psf).sum() / img.sum() - 1) < 1e-5


# ---------------------------------------------------------------- issue 13: audit fixes
def test_full_well_clip_is_flagged_when_the_adc_is_not_the_limit():
    """12-bit, 0.3 DN/e-: full well (10500 e- -> 3150 DN + offset) sits far below the top code,
    so clipped pixels read full well plus the read noise and DSNU added after the clip. Every
    pixel driven to 1.2 full well must be flagged saturated: the flag threshold is 5 sigma of
    that post-clip noise below full well, missing a fraction Phi(-5) ~ 3e-7 (expected 4e-4 of
    the 1536 pixels here). The old test (>= full well (1 - 1e-6)) missed about a quarter."""
    from poevp_optics.camera.reconstruct import SATURATED

    spec, cam = _camera(0.0333, "sensor.bits=12", "sensor.gain_dn_per_e=0.3", noise=True)
    p = cam.params
    assert (p.max_dn - p.offset_dn) / p.gain_dn_per_e > 1.2 * p.full_well_e       # the ADC does not clip
    rad = np.full(cam.mirror_shape, 1.2 * p.full_well_e / (cam.electrons_per_radiance() * cam.white_exposure_s(0)),
                  np.float32)
    cap = cam.capture([rad], cam.white_mask(), 0, seed=5)
    est, flags, _ = cam.reconstruct(cap, 0)
    assert np.all((flags.astype(int) & SATURATED) > 0)
    # and a pixel well below full well (70 %) is not flagged
    cap = cam.capture([rad * np.float32(0.7 / 1.2)], cam.white_mask(), 0, seed=6)
    _, flags, _ = cam.reconstruct(cap, 0)
    assert not np.any((flags.astype(int) & SATURATED) > 0)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -1.0])
def test_non_finite_or_negative_radiance_is_a_clear_error_not_a_hang(bad):
    """NaN made the Poisson sampler loop forever (no lane ever accepts), +Inf gave NaN DN."""
    spec, cam = _camera(0.0333, noise=True)
    rad = np.full(cam.mirror_shape, 1e12, np.float32)
    rad[3, 4] = bad
    with pytest.raises(ValueError, match="NaN/Inf|negative"):
        cam.capture([rad], cam.white_mask(), 0, seed=1)
    from drjit.auto import Float

    if not np.isfinite(bad):
        with pytest.raises(ValueError, match="NaN/Inf"):
            cam.sensor.capture(Float(np.array([1.0, bad, 3.0] * (H * W // 3), np.float32)), 0.01, 1)


@pytest.mark.parametrize("relay", [
    ["relay.psf=gaussian", "relay.sigma_px=1.5"],
    ["relay.psf=airy", "sensor.f_number=4.0"],
    ["relay.psf=delta", "relay.glare_fraction=0.05", "relay.glare_sigma_px=40.0"],
], ids=["gaussian1.5", "airy_f4", "glare5%"])
def test_flat_field_stays_flat_to_the_edge_through_the_relay_psf(relay):
    """A uniform scene reads uniform to the sensor's edge and corner: the camera renders a guard
    band of the PSF's radius on the mirror grid, so the blur sees light beyond the field (zero
    padding read 0.63 at an edge and 0.40 in a corner for sigma 1.5 px, 0.975 for 5 % glare).
    Noise-free electrons, float32: 1e-5 relative."""
    spec, cam = _camera(0.0333, *relay)
    assert cam.guard_px > 0 and cam.mirror_shape[0] == H + 2 * cam.guard_px
    rad = np.full(cam.mirror_shape, 1e12, np.float32)
    cap = cam.capture([rad], cam.white_mask(), 0, seed=1)
    np.testing.assert_allclose(cap.signal_e, cap.signal_e[H // 2, W // 2], rtol=1e-5)
    _, flags, _ = cam.reconstruct(cap, 0)
    assert not np.any((flags.astype(int) & 8) > 0)          # uniform mask: no crosstalk anywhere


def test_psf_crosstalk_at_a_mask_edge_is_flagged():
    """sigma 3 px: mirrors at level 0 over a bright scene beside white mirrors over a 100x dimmer
    scene. Near the edge the dark-mirror pixels receive the white side's light through the PSF
    and divide it by their own (tiny) exposure: they read up to ~5x their radiance. They must
    carry flag 8 (crosstalk); pixels far from the edge must not."""
    from poevp_optics.camera.reconstruct import CROSSTALK

    spec, cam = _camera(0.0333, "relay.psf=gaussian", "relay.sigma_px=3.0", "sensor.bits=12")
    g = cam.guard_px
    hm, wm = cam.mirror_shape
    rad = np.full((hm, wm), 1e12, np.float32)
    mask = np.full((hm, wm), float(cam.top_level))
    left = np.arange(wm) < g + W // 2
    rad[:, left] *= 100.0
    mask[:, left] = 0.0
    rad *= np.float32(0.3 * cam.params.full_well_e / (1e14 * cam.electrons_per_radiance() * cam.level_exposure_s(0)[0]))
    cap = cam.capture([rad], mask, 0, seed=2)
    est, flags, _ = cam.reconstruct(cap, 0)
    truth = cam.to_sensor(rad)
    xt = (flags.astype(int) & CROSSTALK) > 0
    ratio = est / truth
    bad = (np.abs(ratio - 1) > 0.2) & ((flags.astype(int) & 7) == 0)
    assert ratio[H // 2].max() > 2.0                              # the effect is there ...
    assert np.all(xt[bad])                                        # ... and every such pixel is flagged
    assert not np.any(xt[:, :W // 2 - 12]) and not np.any(xt[:, W // 2 + 12:])


def test_one_optical_layout_gives_etendue_and_diffraction():
    """Etendue and the Airy PSF use the same working f-number at the sensor (layout.py):
    sensor.f_number = 2 with no relay stop gives f/2 for both (the Airy core is narrower than
    at f/4); the objective's f-number follows as 2 / magnification; contradictions are errors."""
    from poevp_optics.core.exceptions import SceneError
    from poevp_optics.camera.sensor import pixel_etendue_m2_sr

    spec2, cam2 = _camera(0.0333, "relay.psf=airy", "sensor.f_number=2.0")
    spec4, cam4 = _camera(0.0333, "relay.psf=airy", "sensor.f_number=4.0")
    assert cam2.layout.sensor_f_number == 2.0 and cam2.params.f_number == 2.0
    assert cam2.etendue_m2_sr == pytest.approx(pixel_etendue_m2_sr(cam2.params))
    assert cam2.etendue_m2_sr == pytest.approx(4 * cam4.etendue_m2_sr)
    c2, c4 = cam2.psf.kernel, cam4.psf.kernel
    assert c2[c2.shape[0] // 2, c2.shape[0] // 2] > c4[c4.shape[0] // 2, c4.shape[0] // 2]
    m = cam2.layout.relay_magnification
    assert m == pytest.approx(3.45e-6 / 7.56e-6) and cam2.layout.objective_f_number == pytest.approx(2.0 / m)
    # objective f-number alone: the cone at the sensor is N_obj x M
    _, cam = _camera(0.0333, "objective.f_number=8.0")
    assert cam.layout.sensor_f_number == pytest.approx(8.0 * m)
    # a relay stop narrower than the cone the sensor claims, or two disagreeing f-numbers: errors
    for bad, key in ((["relay.f_number=4.0", "sensor.f_number=2.0"], "relay.f_number"),
                     (["objective.f_number=8.0", "sensor.f_number=2.0"], "sensor.f_number"),
                     (["relay.magnification=1.0"], "relay.magnification")):
        with pytest.raises(SceneError, match=key):
            _camera(0.0333, *bad)


def test_unexposed_threshold_is_relative_to_the_white_exposure():
    """Level 0 with contrast 1e9 passes 1e-9 of white: a real (if dim) exposure at 1 us and at
    10 s alike; with contrast 1e13 it is below the 1e-12 relative threshold: unexposed, 0."""
    from poevp_optics.camera.reconstruct import UNEXPOSED

    for exposure in (1e-6, 10.0):
        for cr, unexposed in ((1e9, False), (1e13, True)):
            spec, cam = _camera(exposure, f"dmd.contrast_ratio={cr}")
            rad = np.full(cam.mirror_shape, 1e12, np.float32)
            cap = cam.capture([rad], np.zeros(cam.mirror_shape), 0, seed=1)
            est, flags, _ = cam.reconstruct(cap, 0)
            assert np.all(((flags.astype(int) & UNEXPOSED) > 0) == unexposed), (exposure, cr)


def test_noise_free_dn_honours_the_dark_current_switch():
    from poevp_optics.camera.sensor import NoiseSwitches

    spec, cam = _camera(10.0, "sensor.bits=12", "sensor.dark_current_e_per_s=100.0")
    on = cam.noise_free_dn(np.zeros((2, 2)))
    cam_off = Camera.from_params(spec.resolved.camera, NoiseSwitches(False, False, False, False, False, True))
    off = cam_off.noise_free_dn(np.zeros((2, 2)))
    p = cam.params
    assert np.all(off == np.rint(p.offset_dn))
    assert np.all(on == np.rint(p.offset_dn + p.gain_dn_per_e * 1000.0))
