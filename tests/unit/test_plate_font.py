"""Plate textures: the font keeps 0/O, 1/I and 8/B apart, read by the project's OCR on the
texture alone (no camera); each format has its real size and layout."""

import numpy as np
import pytest

from poevp_optics.analysis.recognition import alpr_read, normalise, read_plate
from poevp_optics.core.exceptions import SceneError
from poevp_optics.sources.plates import BAND_WEIGHT, PLATE_FONT, PLATE_FORMATS, plate_texture

#: Held-out texts (no shipped scene uses them), each with the confusable characters, valid for
#: the format: EU as German plates (1-3 letters, 1-2 letters, 1-4 digits without a leading 0);
#: US as a 7-character serial without I, O or Q, as many states issue them (so 0, 1, 8 and B).
EU_TEXTS = ("BO IB 1080", "KO BI 8108", "DO OB 180")
US_TEXTS = ("8BBK108", "1BDB800")
SURROUND = 60      # 8-bit surround of the plate for detection: a dark car body around bright sheeting


def _reads(texture: np.ndarray) -> tuple[str, str]:
    """(recognition on the plate box, full ALPR on the plate in a dark surround) of a texture."""
    h, w = texture.shape
    rec = read_plate(texture, (0, 0, h, w))[0]
    pad = 100
    frame = np.pad(texture, pad, constant_values=SURROUND)
    alpr = alpr_read(frame, (pad, pad, pad + h, pad + w)).text
    return normalise(rec), normalise(alpr)


@pytest.mark.parametrize("text, fmt, band", [*((t, "eu", False) for t in EU_TEXTS), ("BO IB 1080", "eu", True),
                                              *((t, "us", False) for t in US_TEXTS)])
def test_plate_texture_reads_confusable_characters_exactly(text, fmt, band):
    rec, alpr = _reads(plate_texture(text, plate_format=fmt, band=band))
    assert rec == normalise(text), f"recognition read {rec!r} for {text!r}"
    assert alpr == normalise(text), f"full ALPR read {alpr!r} for {text!r}"


def _ink(glyph: str) -> np.ndarray:
    """Ink coverage (0-1) of one glyph on an EU plate without the sheeting pattern, rim excluded."""
    tex = plate_texture(glyph, sheeting_pattern=False).astype(np.float64)
    ink = 1.0 - tex / 255.0
    return ink[20:-20, 20:-20]      # inside the rim (6 mm = 12 px at 2 px/mm)


@pytest.mark.parametrize("a, b", [("0", "O"), ("1", "I"), ("8", "B")])
def test_confusable_glyphs_differ_as_images(a, b):
    """Normalised symmetric difference of the two centred glyphs, sum|ink_a - ink_b| / sum max(ink):
    0 for identical glyphs, 1 for glyphs that share no ink. OpenCV's Hershey duplex font, which
    drew plates before and reads 'T0' as 'TO', scores 0.16 on 0/O and 0.15 on 8/B; Go Regular scores
    0.77, 0.46 (1/I) and 0.47. A plate font keeps at least a quarter of the union's ink apart."""
    ia, ib = _ink(a), _ink(b)
    assert ia.sum() > 1000 and ib.sum() > 1000          # both drew something
    assert np.abs(_ink(a) - ia).max() == 0.0            # deterministic: the same glyph twice is 0
    diff = np.abs(ia - ib).sum() / np.maximum(ia, ib).sum()
    assert diff > 0.25, f"{a!r} and {b!r} differ by only {diff:.3f} of their ink"


@pytest.mark.parametrize("fmt, ratio", [("eu", 520 / 110), ("us", 305 / 152)])
def test_formats_have_their_real_aspect_ratios(fmt, ratio):
    h, w = plate_texture("AB 123", plate_format=fmt).shape
    f = PLATE_FORMATS[fmt]
    assert abs(w / h - f.width_mm / f.height_mm) <= (w / h) / h      # one pixel of rounding
    assert w / h == pytest.approx(ratio, rel=5e-3)                    # 12 x 6 in is 304.8 x 152.4 mm
    assert w == round(2 * f.width_mm) and h == round(2 * f.height_mm)  # 2 px/mm by default


def test_weight_map_semantics_rim_and_band():
    """255 sheeting, 0 ink: the rim (4-6 mm from the edge = rows 8-12 at 2 px/mm) is ink, the
    sheeting beside it and the band's weight are the closed forms."""
    tex = plate_texture("AB 123", sheeting_pattern=False)
    assert tex.dtype == np.uint8 and tex.shape == (220, 1040)
    col = 520
    np.testing.assert_array_equal(tex[8:12, col], 0)
    assert tex[7, col] == 255 and tex[12, col] == 255 and tex[0, col] == 255
    assert (tex == 0).sum() > 0.05 * tex.size                          # the characters' ink
    banded = plate_texture("AB 123", sheeting_pattern=False, band=True)
    # the band covers 6-46 mm from the left (rows 12-208): inside it the weight is 255 * 4/70
    np.testing.assert_array_equal(banded[20:200, 14:90], round(255 * BAND_WEIGHT))
    assert banded[110, 93] == 255                                      # sheeting right of the band


def test_plate_texture_refuses_band_on_us_and_unknown_format():
    with pytest.raises(ValueError, match="no blue band"):
        plate_texture("8BBK108", plate_format="us", band=True)
    with pytest.raises(ValueError, match="plate format 'uk'"):
        plate_texture("AB 123", plate_format="uk")


def test_scene_with_band_on_a_us_plate_is_one_line(tmp_path):
    from poevp_optics.scene.validate import check_plate
    from poevp_optics.core.params import Where
    from poevp_optics.sources.plates import PlateSpec

    with pytest.raises(SceneError, match=r"scene\.toml: plate\.band: a 'us' plate has no blue band"):
        check_plate(Where("scene.toml", SceneError), PlateSpec(text="8BBK108", format="us", band=True))


def test_font_file_ships_with_its_licence():
    assert PLATE_FONT.is_file()
    licence = (PLATE_FONT.parent / "LICENSE-Go-fonts.txt").read_text()
    assert "Bigelow & Holmes" in licence and "Redistribution and use" in licence


def test_stroke_is_din_1451_weight():
    """The characters' stroke is DIN 1451's, one raster of the seven of the cap height: 75/7 =
    10.7 mm on an EU plate; measured across the I's stem at mid-height (2 px/mm, so +-0.5 mm of
    pixel rounding on each edge, +-1 mm in all)."""
    tex = plate_texture("I", sheeting_pattern=False)[:, 20:-20]
    stem = np.flatnonzero(tex[110] < 128)
    assert stem.size and stem.max() - stem.min() + 1 == stem.size     # one run of ink
    assert stem.size / 2.0 == pytest.approx(75.0 / 7.0, abs=1.0)
