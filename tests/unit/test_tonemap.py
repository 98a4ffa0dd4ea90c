"""The previews' tone maps: the default operator (Reinhard & Devlin 2005) on a grey image is
colour-hdri's operator bit for bit and the operator's closed form for a = c = 0."""

import numpy as np
import pytest

from poevp_optics.analysis.tonemap import TONEMAPPERS, tonemap


def _hdr(rng, shape):
    """A grey HDR image in (0, 1]: log-normal over ~10 decades, its peak 1 (as `tonemap` scales)."""
    y = np.exp(rng.normal(-9.0, 4.0, shape))
    return np.maximum(y / y.max(), 1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_reinhard2004_is_colour_hdris_operator_on_three_equal_channels(seed):
    import colour_hdri

    y = _hdr(np.random.default_rng(seed), (61, 97))
    rgb = np.repeat(y[..., None], 3, axis=2)
    want = colour_hdri.tonemapping_operator_Reinhard2004(rgb)
    got = TONEMAPPERS["reinhard2004"](y)
    assert np.array_equal(got, want[..., 0])
    assert np.array_equal(want[..., 0], want[..., 2])          # a grey input stays grey


def test_reinhard2004_closed_form():
    """Reinhard & Devlin (2005), Eq. 5-7 with f = 0 (brightness 1), m = 0.3, a = 0 (global
    adaptation), c = 0 (achromatic): I = x / (x + L_lav^0.3), L_lav = exp(mean log(x + eps))."""
    y = _hdr(np.random.default_rng(11), (40, 70))
    l_lav = np.exp(np.mean(np.log(y + np.finfo(np.float64).eps)))
    want = y / (y + l_lav ** 0.3)
    np.testing.assert_allclose(TONEMAPPERS["reinhard2004"](y), want, rtol=1e-12, atol=0)


def test_tonemap_output_is_srgb_encoded_and_monotone():
    """The 8-bit preview: the peak maps to 255, a zero image to 0, and the codes never fall as
    the radiance rises (IEC 61966-2-1 encoding of a monotone operator)."""
    x = np.geomspace(1e-6, 1e3, 4096).reshape(64, 64)
    out = tonemap(x, "reinhard2004")
    assert out.dtype == np.uint8 and np.all(np.diff(out.ravel().astype(int)) >= 0)
    y_peak = 1.0 / (1.0 + np.exp(np.mean(np.log(x / x.max() + np.finfo(np.float64).eps))) ** 0.3)
    srgb = 1.055 * y_peak ** (1 / 2.4) - 0.055
    assert out.ravel()[-1] == round(srgb * 255)
    assert not tonemap(np.zeros((8, 8))).any()
