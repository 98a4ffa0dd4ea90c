"""Memory estimate, large-kernel FFT, lossless deep captures, prediction checks (issue 14)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from poevp_optics.cli import main
from tests.conftest import ROOT, SCENES


# ---------------------------------------------------------------------------- FFT and kernels
def _brute_force(img: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Same-size convolution by the definition, the image continued by mirror reflection
    (edge pixel repeated, numpy's 'symmetric') as far as one image extent: taps reaching beyond
    that are dropped (relay.convolve)."""
    h, w = img.shape
    c = k.shape[0] // 2
    ry, rx = min(c, h - 1), min(c, w - 1)

    def at(v, u):                    # reflected image value at any v in [-ry, h + ry)
        v = -v - 1 if v < 0 else (2 * h - 1 - v if v >= h else v)
        u = -u - 1 if u < 0 else (2 * w - 1 - u if u >= w else u)
        return img[v, u]

    out = np.zeros((h, w))
    for y in range(h):
        for x in range(w):
            for dy in range(-ry, ry + 1):
                for dx in range(-rx, rx + 1):
                    out[y, x] += at(y - dy, x - dx) * k[c + dy, c + dx]
    return out


def test_fft_path_equals_the_definition_for_kernels_wider_than_the_image():
    from poevp_optics.camera.relay import PSF, convolve

    rng = np.random.default_rng(3)
    img = rng.uniform(0, 1, (5, 7))
    for n in (17, 41):                               # FFT path; 41 reaches past the 5x7 image
        k = rng.uniform(0, 1, (n, n))
        k /= k.sum()
        # float64 FFT: round-off ~1e-16 of the largest term
        np.testing.assert_allclose(convolve(img, PSF("t", k, 0.0)), _brute_force(img, k), rtol=1e-10, atol=1e-14)


def test_fft_size_does_not_grow_with_the_kernel():
    from poevp_optics.camera.relay import fft_bytes, fft_shape

    assert fft_shape((368, 640), 7435) == fft_shape((368, 640), 1279)
    assert fft_bytes((368, 640), 100001) == fft_bytes((368, 640), 1279)
    fh, fw = fft_shape((368, 640), 7435)
    assert fh <= 1.05 * (3 * 368 - 2) and fw <= 1.05 * (3 * 640 - 2)   # image + reflections, fast length


def test_sigma_1000_psf_is_capped_at_the_image_and_runs_by_fft(tmp_path):
    from poevp_optics.camera.relay import DIRECT_MAX_PX, gaussian_psf, max_support_px

    psf = gaussian_psf(1000.0, cap_px=max_support_px((48, 64)))
    assert psf.kernel.shape == (127, 127) and psf.kernel.shape[0] > DIRECT_MAX_PX
    assert "capped" in psf.note
    # energy outside the capped square: 1 - erf(63.5 / (1000 sqrt 2))^2 ~ 0.998; the reported
    # radial tail exp(-r^2 / 2 sigma^2) is its lower bound
    assert 0.99 < psf.truncation_error < 1.0
    out = tmp_path / "wide"
    assert main(["render", str(SCENES / "smoke"), "--out", str(out), "--quiet", "--frames", "1",
                 "--set", "relay.psf='gaussian'", "--set", "relay.sigma_px=1000"]) == 0
    r = json.loads((out / "report.json").read_text())
    t = r["errors"]["psf_truncation"]
    assert t["support_px"] == 127 and "capped" in t["note"] and "relay" not in r["skipped_stages"]
    assert any("capped" in n for n in r["notes"])


# ---------------------------------------------------------------------------- memory
def test_memory_estimate_bounds_the_measured_peak(tmp_path):
    """The estimate is an upper bound of peak RSS, and not a wild one (under 2x)."""
    from poevp_optics.apps.run.memory import estimate_run
    from poevp_optics.scene.load import load_scene
    args = ["--frames", "1", "--resolution", "512x512", "--spp", "2"]
    spec = load_scene(SCENES / "smoke", ["timing.frames=1", "render.resolution=[512,512]", "render.spp=2"])
    est = estimate_run(spec).total_bytes
    # Linux carries a process's RSS high-water mark across fork and exec, so a child forked
    # from this (large) pytest process reports at least pytest's size: a small launcher
    # process starts the run and reads the run's own peak (wait4 ru_maxrss, KiB)
    launcher = ("import os, subprocess, sys\n"
                "p = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL)\n"
                "_, status, usage = os.wait4(p.pid, 0)\n"
                "print(os.waitstatus_to_exitcode(status), usage.ru_maxrss)\n")
    r = subprocess.run([sys.executable, "-c", launcher, sys.executable, "-m", "poevp_optics.cli", "render",
                        str(SCENES / "smoke"), "--out", str(tmp_path / "o"), "--quiet", *args],
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True, timeout=300)
    rc, peak_kib = map(int, r.stdout.split())
    assert rc == 0, r.stderr
    peak = peak_kib * 1024
    assert peak < est < 2 * peak, (peak, est)


def test_available_memory_honours_the_limit(monkeypatch):
    from poevp_optics.apps.run.memory import available_bytes, parse_bytes

    assert parse_bytes("512M") == 512 << 20 and parse_bytes("1.5G") == int(1.5 * (1 << 30))
    monkeypatch.setenv("POEVP_MEMORY_LIMIT", "1G")
    have, source = available_bytes()
    assert have == 1 << 30 and "POEVP_MEMORY_LIMIT" in source


# ---------------------------------------------------------------------------- captures
def test_20_bit_captures_are_written_losslessly(tmp_path):
    from poevp_optics.core.io import read_dn

    out = tmp_path / "deep"
    assert main(["render", str(SCENES / "smoke"), "--out", str(out), "--quiet", "--frames", "1",
                 "--resolution", "16x16", "--set", "sensor.bits=20"]) == 0
    r = json.loads((out / "report.json").read_text())
    assert r["sensor"]["bits"] == 20 and r["sensor"]["offset_dn"] == 10486     # 1 % of 2^20
    dn = read_dn(out / "capture" / "frame_0000.exr")
    assert not (out / "capture" / "frame_0000.png").exists()
    assert np.all(dn == np.rint(dn)) and dn.max() <= (1 << 20) - 1
    # a uint16 PNG would wrap these codes (the bug: 38 DN read against a black level of 10486)
    assert dn.min() > 65535 / 8 and np.median(dn) > r["sensor"]["offset_dn"] - 100


def test_capture_writer_never_wraps(tmp_path):
    from poevp_optics.core.io import read_dn, write_dn

    with pytest.raises(ValueError, match="integers in"):
        write_dn(tmp_path / "a", np.array([[70000.0]]), 16)
    with pytest.raises(ValueError, match="integers in"):
        write_dn(tmp_path / "b", np.array([[1.5]]), 8)
    codes = np.array([[0.0, 1.0], [(1 << 24) - 1.0, 123456.0]])
    path = write_dn(tmp_path / "c", codes, 24)
    assert path.suffix == ".exr"
    np.testing.assert_array_equal(read_dn(path), codes)                  # float32 holds 24 bits
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.exr"]


# ---------------------------------------------------------------------------- predictions
class _NaNPredictor:
    name = "broken"
    needs_frames = 2
    min_input_px = 1

    def __call__(self, history):
        out = np.array(history[-1], dtype=np.float32)
        out[: out.shape[0] // 2] = np.nan
        return out

    def describe(self):
        return {"name": self.name}


def test_non_finite_prediction_falls_back_and_is_reported(tmp_path):
    from poevp_optics.control.predictors import PREDICTORS, PredictorEntry, checked_prediction

    hist = [np.full((4, 6), 7.0, np.float32), np.full((4, 6), 9.0, np.float32)]
    pred, n_bad = checked_prediction(_NaNPredictor(), hist)
    assert n_bad == 12 and np.all(np.isfinite(pred)) and np.all(pred == 9.0)
    PREDICTORS.register("nan_test", PredictorEntry(lambda w, r: _NaNPredictor()), source="a broken predictor (test)")
    out = tmp_path / "nan"
    try:
        assert main(["render", str(SCENES / "smoke"), "--out", str(out), "--quiet", "--frames", "4",
                     "--resolution", "24x32", "--set", "predictor.name='nan_test'"]) == 0
    finally:
        PREDICTORS.unregister("nan_test")
    r = json.loads((out / "report.json").read_text())
    flagged = [f["index"] for f in r["per_frame"] if f.get("prediction_fallback_pixels")]
    assert flagged == [2, 3]                          # every predicted frame, none of the 2 init frames
    assert all(f["prediction_fallback_pixels"] == 368 * 640 // 2 for f in r["per_frame"][2:])
    assert any("NaN/Inf" in n and "[2, 3]" in n for n in r["notes"])


def test_nan_weights_are_refused_at_load(tmp_path):
    from safetensors import safe_open
    from safetensors.torch import load_file, save_file

    from poevp_optics.control.predictors.dmvfn import WeightsError, load_weights

    src = ROOT / "assets" / "predictor" / "dmvfn_lite.safetensors"
    with safe_open(str(src), framework="pt") as f:
        meta = f.metadata()
    tensors = load_file(str(src))
    key = sorted(tensors)[-1]
    tensors[key].view(-1)[3] = float("inf")
    bad = tmp_path / "inf.safetensors"
    save_file(tensors, str(bad), metadata=meta)
    with pytest.raises(WeightsError, match=f"NaN or Inf .*{key}"):
        load_weights(bad)
