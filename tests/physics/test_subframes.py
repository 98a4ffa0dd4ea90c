"""K radiance sub-frames on a moving scene converge to the K = 1024 reference (issue 3)."""

from __future__ import annotations

import numpy as np

from poevp_optics.camera import Camera
from poevp_optics.scene import load_scene
from poevp_optics.sensor import NoiseSwitches
from tests.conftest import SCENES

H, W = 24, 96


def _highlight(t_s):
    """Gaussian highlight crossing the frame at 1500 px/s (45 px per 30 ms exposure)."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    return 1e15 + 3e17 * np.exp(-((x - 20 - 1500.0 * t_s) ** 2 + (y - H / 2) ** 2) / (2 * 4.0 ** 2))


def test_subframe_error_falls_as_k_grows():
    spec = load_scene(SCENES / "smoke", [f"render.resolution=[{H},{W}]", "timing.exposure_s=0.03",
                                         "timing.dmd_window_s=0.02", "timing.dmd_window_offset_s=0.005"])
    cam = Camera(spec, NoiseSwitches(False, False, True, False, False, False))
    mask = np.tile(np.linspace(0, 255, W), (H, 1)).round()
    t0, t1 = spec.exposure_window_s(0)

    def exposure(k):
        mids = t0 + (np.arange(k) + 0.5) * (t1 - t0) / k
        return cam.capture([_highlight(t).astype(np.float32) for t in mids], mask, 0, 1).signal_e.astype(np.float64)

    ref = exposure(1024)
    errs = [np.sqrt(np.mean((exposure(k) - ref) ** 2)) / np.mean(ref) for k in (2, 8, 32, 128)]
    assert all(b < a for a, b in zip(errs, errs[1:])), errs
    assert errs[-1] < 1e-3 and errs[0] > 10 * errs[-1]
