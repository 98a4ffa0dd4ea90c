"""Where Eq. 3's over-exposure rate E acts (paper Sec. 4.A: on stored 8-bit values) and the peak
gain the rendered benchmark takes from E: closed forms computed here, independently."""

from __future__ import annotations

import math

import numpy as np
import pytest

from poevp_optics.apps.evaluate.eval_paper import paper_overrides
from poevp_optics.apps.evaluate.evaluate import peak_gain
from poevp_optics.core.paths import SCENES_DIR
from poevp_optics.scene.load import load_scene
from poevp_optics.sources.frames import Box
from poevp_optics.sources.ldr_highlight import highlighted_luminance


def _srgb(v: float) -> float:
    """IEC 61966-2-1 decoding above the linear toe, written out (extends above 1)."""
    return ((v + 0.055) / 1.055) ** 2.4


@pytest.mark.parametrize("e", [0.0, 9.0, 49.0])
def test_display_domain_multiplies_code_values_then_decodes(e):
    code, sigma = 120, 3.0
    img = np.full((9, 11), code, dtype=np.uint8)
    box = Box(2.0, 1.0, 9.0, 8.0)                       # centre (5.5, 4.5): pixel (4, 5) is on it
    g = math.exp(-((6.5 - 5.5) ** 2 + (4.5 - 4.5) ** 2) / (2 * sigma ** 2))   # pixel (4, 6)
    disp = highlighted_luminance(img, box, e, sigma, "srgb", 2.2, "display")
    lin = highlighted_luminance(img, box, e, sigma, "srgb", 2.2, "linear")
    v = code / 255.0
    assert disp[4, 5] == pytest.approx(_srgb(v * (e + 1.0)), rel=1e-12)
    assert disp[4, 6] == pytest.approx(_srgb(v * (e * g + 1.0)), rel=1e-12)
    assert lin[4, 5] == pytest.approx(_srgb(v) * (e + 1.0), rel=1e-12)
    if e > 0:
        # display values decode with exponent 2.4: the linear gain exceeds E + 1
        assert disp[4, 5] / disp[0, 0] > (e + 1.0) * 1.5


def test_peak_gain_readings():
    assert peak_gain(9.0, "linear") == 10.0
    assert peak_gain(9.0) == pytest.approx(_srgb(10.0), rel=1e-12)
    assert peak_gain(9.0) == pytest.approx(223.8, abs=0.1)
    assert peak_gain(0.0) == pytest.approx(1.0, rel=1e-12)  # no highlight: the peak at saturation


def test_paper_protocol_forms_eq3_on_display_values():
    spec = load_scene(SCENES_DIR / "ldr_highlight_demo", paper_overrides(29.0))
    assert spec.source.e_domain == "display"
