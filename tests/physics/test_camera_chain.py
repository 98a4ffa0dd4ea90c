"""Camera chain: float32 vs float64 on the noise-free path, 220 dB scenes, zero masks, PSF
energy, reconstruction without Inf/NaN (issue 3)."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.camera import Camera
from poevp_optics.dmd import transmission_table
from poevp_optics.reconstruct import UNEXPOSED, reconstruct
from poevp_optics.relay import airy_psf, convolve, gaussian_psf, measured_psf
from poevp_optics.scene import load_scene
from poevp_optics.sensor import NoiseSwitches
from poevp_optics import spectra
from tests.conftest import ROOT, SCENES

H, W = 32, 48


def _camera(exposure_s, *extra, noise=False):
    fps = min(30.0, 0.5 / exposure_s)
    spec = load_scene(SCENES / "smoke", [f"render.resolution=[{H},{W}]", f"timing.fps={fps}",
                                         f"timing.exposure_s={exposure_s}",
                                         f"timing.dmd_window_s={exposure_s}", *extra])
    sw = None if noise else NoiseSwitches(False, False, True, False, False, False)
    return spec, Camera(spec, sw)


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
    from poevp_optics.relay import build_psf
    from poevp_optics.scene import RelaySpec

    g = 0.05
    psf = build_psf(RelaySpec(psf="gaussian", sigma_px=1.0, glare_fraction=g, glare_sigma_px=12.0),
                    pixel_pitch_m=3.45e-6)
    assert psf.name == "gaussian+glare"
    assert psf.kernel.sum() == pytest.approx(1.0, abs=1e-12)
    c = psf.kernel.shape[0] // 2
    core = psf.kernel[c - 4:c + 5, c - 4:c + 5].sum()           # the core's 4-sigma box
    halo_in_box = g * 81 / (2 * np.pi * 144)                    # halo peak density x box area
    assert core == pytest.approx(1 - g + halo_in_box, abs=2e-3)
    assert build_psf(RelaySpec(psf="delta"), pixel_pitch_m=3.45e-6) is None
    glare_only = build_psf(RelaySpec(psf="delta", glare_fraction=g), pixel_pitch_m=3.45e-6)
    assert glare_only.kernel[glare_only.kernel.shape[0] // 2, glare_only.kernel.shape[0] // 2] > 1 - g
    img = _blob_image(96 + psf.kernel.shape[0])
    assert abs(convolve(img, psf).sum() / img.sum() - 1) < 1e-5
