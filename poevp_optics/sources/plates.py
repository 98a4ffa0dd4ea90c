"""License-plate textures from text: retroreflective sheeting, dark characters and rim.

The texture is a blend weight for the plate material (255 = sheeting, 0 = ink): the XML plate
uses a `blendbsdf` of an ink BSDF and the sheeting whose reflectances are measured spectra bound
in [spectra], so the plate's reflectance is spectral everywhere. Everything is laid out in
millimetres on the plate and sampled onto the texture's pixels (a texture of another aspect
ratio than its format stretches back onto the XML's rectangle, which must have the format's size).

| format | size (mm)  | characters         | rim                   | source                                  |
|--------|------------|--------------------|-----------------------|-----------------------------------------|
| `eu`   | 520 x 110  | 75 mm tall          | 2 mm, 4 mm inside     | FZV Anlage 4 (1a, 2.2.1: 75 mm Mittelschrift; DIN 74069) |
| `us`   | 305 x 152  | 70 mm (2.75 in)     | 2 mm, 4 mm inside     | the 12 x 6 in US plate (AAMVA); height assumed, states set it (2.5-3 in) |

The rim's nominal stroke is set in DIN 74069 (not public); 2 mm lies within FZV Anlage 4's
tolerance (+2/-1 mm). The text is centred in its field with equal clearance on both sides (FZV
Anlage 4, 2.1) and condensed horizontally where it would come closer than 8 mm to the rim or
band, as the FE-Schrift's Engschrift is for long texts. `band = true` (EU only) draws the blue
Euro field at the left, 40 mm wide (Council Regulation (EC) No 2411/98: 40-50 mm wide, >= 98 mm
tall), as weight 15/255 = 4/70, the blue-to-white ratio of ASTM D4956 Type I's minimum
coefficients of retroreflection (4.0 and 70 cd lx-1 m-2 at 0.2 deg observation), an achromatic
stand-in for blue sheeting (the country code and stars are not drawn).

Characters use the Go Regular TrueType font (`assets/fonts/Go-Regular.ttf`, Bigelow & Holmes
2016, BSD-3-Clause, licence beside it), drawn with Pillow's FreeType renderer. Real plate fonts
draw the pairs an ALPR system confuses apart: the German FE-Schrift ("fälschungserschwerende
Schrift", K. Hoefer for the Bundesanstalt für Straßenwesen 1978-80, on plates since 1994, FZV
Anlage 4 Abschnitt 1 Nr. 2) was designed so that no character can be altered into another and
machines can read it, with a round O against a narrow 0. The FE-Schrift is not freely licensed;
Go Regular keeps the same pairs apart by shape (round O / narrow slashed 0, serifed I / flagged
1, B's straight back / 8), and its stroke, 0.141 of the cap height (10.6 mm at 75 mm), is the
weight of DIN 1451, the plate font before it (stroke one raster of the seven of the cap height). Retroreflective sheeting
is glass-bead or micro-prism film; its faint hexagonal cell pattern is drawn as a 2 %
modulation (its optics are modelled by the sheeting reflectance, not by geometry).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from poevp_optics.core.cache import cache_file, digest
from poevp_optics.core.params import param as _param
from poevp_optics.core.paths import ASSETS_DIR

#: The plate font (TrueType), shipped with its licence.
PLATE_FONT = ASSETS_DIR / "fonts" / "Go-Regular.ttf"


@dataclass(frozen=True)
class PlateFormat:
    """A plate format's layout in millimetres (module table)."""

    width_mm: float
    height_mm: float
    char_height_mm: float      # cap height of the characters
    rim_mm: float              # stroke of the dark rim
    rim_inset_mm: float        # from the plate's edge to the rim's outer side
    clearance_mm: float        # least clearance between the text and the rim or band
    band_mm: float = 0.0       # width of the EU's blue field (0: the format has none)


PLATE_FORMATS = {
    "eu": PlateFormat(520.0, 110.0, 75.0, 2.0, 4.0, 8.0, band_mm=40.0),
    "us": PlateFormat(304.8, 152.4, 69.85, 2.0, 4.0, 8.0),
}
#: Texture resolution when `width_px`/`height_px` are 0, px per mm (EU: 1040 x 220 px).
DEFAULT_PX_PER_MM = 2.0
#: Weight of the EU's blue field: ASTM D4956 Type I minimum R_A, blue 4.0 / white 70 (0.2 deg obs.).
BAND_WEIGHT = 4.0 / 70.0


@dataclass(frozen=True)
class PlateSpec:
    """[plate]: plate text; when set, a texture is generated and bound to `$<param>`."""

    text: str = _param("")
    param: str = _param("plate_texture")
    format: str = _param("eu", choices=tuple(PLATE_FORMATS))
    band: bool = _param(False)
    width_px: int = _param(0, min=64, max=8192, unset=0)
    height_px: int = _param(0, min=16, max=2048, unset=0)


PLATE_WIDTH_M = PLATE_FORMATS["eu"].width_mm / 1000.0
PLATE_HEIGHT_M = PLATE_FORMATS["eu"].height_mm / 1000.0


def texture_size(plate_format: str = "eu", width_px: int = 0, height_px: int = 0) -> tuple[int, int]:
    """(width_px, height_px) of a plate texture: each 0 taken from the format's size at
    DEFAULT_PX_PER_MM (the other given one keeps the format's aspect ratio)."""
    f = PLATE_FORMATS[plate_format]
    if width_px and not height_px:
        height_px = int(round(width_px * f.height_mm / f.width_mm))
    elif height_px and not width_px:
        width_px = int(round(height_px * f.width_mm / f.height_mm))
    elif not width_px and not height_px:
        width_px, height_px = (int(round(DEFAULT_PX_PER_MM * f.width_mm)),
                               int(round(DEFAULT_PX_PER_MM * f.height_mm)))
    return width_px, height_px


def _span_coverage(n: int, lo: float, hi: float) -> np.ndarray:
    """Fraction of each of n unit pixels [i, i+1) that lies inside [lo, hi] (exact area)."""
    edges = np.arange(n + 1, dtype=np.float64)
    return np.clip(np.minimum(edges[1:], hi) - np.maximum(edges[:-1], lo), 0.0, 1.0)


def _rect_coverage(shape, x0, y0, x1, y1) -> np.ndarray:
    """Exact pixel coverage (0-1) of the axis-aligned rectangle [x0, x1] x [y0, y1] in px."""
    return np.outer(_span_coverage(shape[0], y0, y1), _span_coverage(shape[1], x0, x1))


@functools.lru_cache(maxsize=8)
def plate_font(size_px: float):
    from PIL import ImageFont

    return ImageFont.truetype(str(PLATE_FONT), size_px)


@functools.lru_cache(maxsize=1)
def plate_font_sha256() -> str:
    """SHA-256 of the font file (part of the cache key: another font draws other pixels)."""
    import hashlib

    return hashlib.sha256(PLATE_FONT.read_bytes()).hexdigest()


def _cap_ratio() -> float:
    """The font's cap height per em (the 'H' at 1000 px)."""
    top = plate_font(1000.0).getbbox("H", anchor="ls")[1]
    return -top / 1000.0


def _text_coverage(text: str, shape, cap_px: float, centre_px: float, x_lo_px: float,
                   x_hi_px: float, x_scale: float) -> np.ndarray:
    """Ink coverage (0-1) of `text` with cap height `cap_px`, its ink centred on row `centre_px`
    (a descending J stays inside the rim) and between columns x_lo_px and x_hi_px; drawn
    isotropic in rows, then scaled by `x_scale` (texture px per row px) and condensed further
    where it would leave the field."""
    import cv2
    from PIL import Image, ImageDraw

    font = plate_font(cap_px / _cap_ratio())
    left, top, right, bottom = font.getbbox(text, anchor="ls")
    baseline_px = centre_px - 0.5 * (top + bottom)
    pad = 2
    canvas = Image.new("L", (right - left + 2 * pad, shape[0]), 0)
    ImageDraw.Draw(canvas).text((pad - left, baseline_px), text, font=font, fill=255, anchor="ls")
    ink = np.asarray(canvas, dtype=np.float32) / 255.0
    natural = ink.shape[1] * x_scale
    target = max(int(round(min(natural, x_hi_px - x_lo_px + 2 * pad * x_scale))), 1)
    if target != ink.shape[1]:
        interp = cv2.INTER_AREA if target < ink.shape[1] else cv2.INTER_CUBIC
        ink = np.clip(cv2.resize(ink, (target, shape[0]), interpolation=interp), 0.0, 1.0)
    out = np.zeros(shape, np.float32)
    x0 = int(round(0.5 * (x_lo_px + x_hi_px) - 0.5 * target))
    a, b = max(x0, 0), min(x0 + target, shape[1])
    if b > a:
        out[:, a:b] = ink[:, a - x0:b - x0]
    return out


def plate_texture(text: str, width_px: int = 0, height_px: int = 0, sheeting_pattern: bool = True,
                  *, plate_format: str = "eu", band: bool = False) -> np.ndarray:
    """Render `text` on a plate of `plate_format` ("eu" 520 x 110 mm, "us" 305 x 152 mm; module
    table) to a uint8 (height_px, width_px) weight map: 255 sheeting, 0 ink. Sizes of 0 come from
    the format at 2 px/mm; `band` draws the EU's blue field."""
    if not text or not text.strip():
        raise ValueError("plate text must not be empty")
    if plate_format not in PLATE_FORMATS:
        raise ValueError(f"plate format {plate_format!r}: expected one of {', '.join(PLATE_FORMATS)}")
    f = PLATE_FORMATS[plate_format]
    if band and not f.band_mm:
        raise ValueError(f"plate format {plate_format!r} has no blue band (only 'eu' has)")
    width_px, height_px = texture_size(plate_format, width_px, height_px)
    if width_px < 64 or height_px < 16:
        raise ValueError(f"plate texture too small: {width_px}x{height_px} px")
    shape = (height_px, width_px)
    sx, sy = width_px / f.width_mm, height_px / f.height_mm      # px per mm along x and y
    sheet = np.full(shape, 255.0, np.float32)
    if sheeting_pattern:
        yy, xx = np.mgrid[0:height_px, 0:width_px].astype(np.float32)
        cell = max(height_px / 40.0, 2.0)
        hexes = (np.cos(2 * np.pi * xx / cell) + np.cos(np.pi * (xx + np.sqrt(3) * yy) / cell)
                 + np.cos(np.pi * (xx - np.sqrt(3) * yy) / cell))
        sheet = np.clip(255 - 2.5 * (hexes + 1.5), 0, 255).astype(np.uint8).astype(np.float32)
    r0, r1 = f.rim_inset_mm, f.rim_inset_mm + f.rim_mm
    outer = _rect_coverage(shape, r0 * sx, r0 * sy, width_px - r0 * sx, height_px - r0 * sy)
    inner = _rect_coverage(shape, r1 * sx, r1 * sy, width_px - r1 * sx, height_px - r1 * sy)
    keep = 1.0 - (outer - inner)                                   # the rim is ink
    field_lo = r1 + f.clearance_mm
    if band:
        blue = _rect_coverage(shape, r1 * sx, r1 * sy, (r1 + f.band_mm) * sx, height_px - r1 * sy)
        keep = keep * (1.0 - blue * (1.0 - BAND_WEIGHT))
        field_lo += f.band_mm
    field_hi = f.width_mm - r1 - f.clearance_mm
    cap_px = f.char_height_mm * sy
    ink = _text_coverage(text, shape, cap_px, 0.5 * height_px, field_lo * sx, field_hi * sx, sx / sy)
    weight = sheet * keep * (1.0 - ink)
    return np.clip(np.rint(weight), 0, 255).astype(np.uint8)


def cached_plate_path(text: str, width_px: int = 0, height_px: int = 0, *, plate_format: str = "eu",
                      band: bool = False) -> Path:
    """Write (once) and return a plate texture PNG for `text` in the user cache folder, checked
    (checksum, and it decodes to this texture's size and pixels) before anything reads it; a file
    that fails is rebuilt (core/cache.py)."""
    from poevp_optics.core.cache import cached_png

    width_px, height_px = texture_size(plate_format, width_px, height_px)
    key = f"{text}|{width_px}|{height_px}|{plate_format}|{int(band)}|{plate_font_sha256()[:16]}|v2"
    texture = plate_texture(text, width_px, height_px, plate_format=plate_format, band=band)
    return cached_png(cache_file("plates", f"plate_{digest(key)}.png"), texture, f"the plate {text!r}")
