"""Tone mapping for previews, by name, through colour-hdri's operators.

| name           | operator                                   | reference |
|----------------|--------------------------------------------|-----------|
| reinhard2004   | `tonemapping_operator_Reinhard2004`'s grey case | Reinhard & Devlin (2005), IEEE TVCG 11(1) |
| filmic         | `tonemapping_operator_filmic`              | Hable (2010), Uncharted 2 filmic curve |
| logarithmic    | `tonemapping_operator_logarithmic`         | Drago et al. (2003) family, colour-hdri |
| linear         | clip(L / L_99.9 %), no compression         | - |

Input is any non-negative linear radiance image; output is an sRGB-encoded uint8 grey image.
Previews are for eyes only: measurements live in the EXR files.
"""

from __future__ import annotations

import warnings

import numpy as np

from poevp_optics.core.registry import Registry


def _rgb(x):
    """The grey image as three equal channels: a read-only broadcast view, not three copies (the
    operators only read it; the same numbers, a third of the memory traffic)."""
    return np.broadcast_to(x[..., None], (*x.shape, 3))


def _reinhard2004(x):
    """Reinhard & Devlin (2005) at colour-hdri's defaults (f = 0, m = 0.3, a = 0, c = 0) on a
    grey image: with no light adaptation (a = 0) and no chromatic adaptation (c = 0) the operator
    is C / (C + (f L_lav)^m) with L_lav the log-average of the image's luminance, one global
    number, so each channel of a grey image is x / (x + L_lav^0.3). L_lav is colour-hdri's own
    `log_average` of colour's `RGB_luminance` (sRGB primaries), as the operator computes it; the
    result is the operator's channel 0 bit for bit (tests/unit/test_tonemap.py), without its
    three-channel intermediates (0.49-0.69 -> 0.15 s a call at 1920x1080)."""
    from colour.models import RGB_COLOURSPACES, RGB_luminance
    from colour_hdri.tonemapping.global_operators.operators import log_average

    srgb = RGB_COLOURSPACES["sRGB"]
    l_lav = log_average(RGB_luminance(_rgb(x), srgb.primaries, srgb.whitepoint))
    # the power of a one-element array, as the operator takes it of an array: NumPy's vector
    # pow (SIMD) and Python's scalar pow differ in the last bit for ~6 % of arguments
    return x / (x + np.power(np.full(1, l_lav), 0.3))          # f = 0: brightness exp(-f) = 1


def _filmic(x):
    import colour_hdri

    return colour_hdri.tonemapping_operator_filmic(_rgb(x / np.mean(x)))[..., 0]


def _logarithmic(x):
    import colour_hdri

    return colour_hdri.tonemapping_operator_logarithmic(_rgb(x))[..., 0]


def _linear(x):
    top = float(np.percentile(x, 99.9))
    return np.clip(x / top, 0, 1) if top > 0 else np.zeros_like(x)


TONEMAPPERS = Registry("tone mapper")
TONEMAPPERS.register("reinhard2004", _reinhard2004, source="Reinhard & Devlin (2005), IEEE TVCG 11(1), colour-hdri")
TONEMAPPERS.register("filmic", _filmic, source="Hable (2010), Uncharted 2 filmic curve, colour-hdri")
TONEMAPPERS.register("logarithmic", _logarithmic, source="Drago et al. (2003) family, colour-hdri")
TONEMAPPERS.register("linear", _linear, source="clip(L / L_99.9 %), no compression")


def tonemap(radiance: np.ndarray, method: str = "reinhard2004") -> np.ndarray:
    """Tone-map a linear (H, W) image to sRGB-encoded uint8 with the named operator."""
    operator = TONEMAPPERS[method]
    x = np.nan_to_num(np.asarray(radiance, dtype=np.float64), nan=0.0, posinf=0.0)
    x = np.maximum(x, 0.0)
    peak = float(x.max())
    if peak <= 0:
        return np.zeros(x.shape, np.uint8)
    x = x / peak                                   # operators see values in (0, 1]
    x = np.maximum(x, 1e-12)                       # log-average needs positive values
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        y = np.clip(np.nan_to_num(operator(x)), 0.0, 1.0)
    srgb = np.where(y <= 0.0031308, 12.92 * y, 1.055 * np.power(y, 1 / 2.4) - 0.055)  # IEC 61966-2-1
    return np.round(srgb * 255).astype(np.uint8)
