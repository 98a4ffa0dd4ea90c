"""The temporal-error check renders only the pixels it reads: the ROI's box on the mono path
(Renderer.render_box, the whole-frame estimator restricted to those pixels:
tests/physics/test_roi_render.py), else whole frames cropped to the ROI."""

from types import SimpleNamespace

import numpy as np

from poevp_optics.apps.run.temporal_check import _render_region


class _Renderer:
    """Records the calls; a whole frame is 6 x 8 with each pixel's value its own index."""

    def __init__(self, mode):
        self.plan = SimpleNamespace(mode=mode)
        self.calls = []

    def render_once(self, seed, spp):
        self.calls.append(("frame", seed, spp))
        return np.arange(48, dtype=np.float32).reshape(6, 8)

    def render_box(self, seed, spp, box):
        self.calls.append(("box", seed, spp, box))
        y0, x0, y1, x1 = box
        return np.arange(48, dtype=np.float64).reshape(6, 8)[y0:y1, x0:x1]


def test_a_mono_run_with_an_roi_renders_the_box_alone():
    r = _Renderer("mono")
    out = _render_region(r, 5, 4, (1, 2, 4, 7))
    assert r.calls == [("box", 5, 4, (1, 2, 4, 7))]
    assert out.dtype == np.float64 and out.shape == (3, 5) and out[0, 0] == 10


def test_without_an_roi_or_off_the_mono_path_the_frame_is_rendered_and_cropped():
    r = _Renderer("mono")
    assert _render_region(r, 5, 4, None).shape == (6, 8) and r.calls == [("frame", 5, 4)]
    r = _Renderer("spectral")
    out = _render_region(r, 9, 2, (1, 2, 4, 7))
    assert r.calls == [("frame", 9, 2)] and out.dtype == np.float64 and out[0, 0] == 10
