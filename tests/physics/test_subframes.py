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


def test_richardson_temporal_error_estimate_tracks_the_true_error():
    """errors.temporal_error (K vs K/2) against the actual error of K = 4 vs a K = 64 reference
    on the fast_pass scene (plate sweeping ~25 px per exposure at this size)."""
    import numpy as np

    from poevp_optics.errors import temporal_error
    from poevp_optics.loop import _seeds
    from poevp_optics.render import Renderer
    from poevp_optics.scene import load_scene

    from ..conftest import SCENES

    spec = load_scene(SCENES / "fast_pass", ["render.resolution=[46,80]", "render.spp=32",
                                             "render.subframes=4", "timing.frames=2"])
    r = Renderer(spec)

    def mean_k(k, salt):
        a, b = spec.exposure_window_s(1)
        ms, var = [], 0.0
        for j, t in enumerate(a + (np.arange(k) + 0.5) * (b - a) / k):
            r.set_time(float(t))
            m, v = r.render_with_error(_seeds(7, salt, j, 2), spec.render.spp)
            ms.append(m.astype(np.float64))
            var = var + v
        return np.mean(ms, axis=0), var / k ** 2

    m4, v4 = mean_k(4, 1)
    ref, _ = mean_k(64, 2)
    true = float(np.sqrt(np.mean((m4 - ref) ** 2)) / np.mean(ref))
    est = temporal_error(spec, r, 1, m4, v4)
    assert est["resolved"]
    print("temporal error: estimate", est["rel"], "true", true)
    assert 1 / 3 < est["rel"] / true < 3, (est["rel"], true)
