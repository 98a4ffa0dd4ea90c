"""License-plate textures from text: white sheeting, dark characters and border.

The texture is a blend weight for the plate material (1 = sheeting, 0 = ink): the XML plate
uses a `blendbsdf` of two diffuse BSDFs whose reflectances are measured spectra bound in
[spectra] (ink first, sheeting second), so the plate's reflectance is spectral everywhere.
Geometry follows the EU 520 x 110 mm plate (DIN 74069 proportions): 4.73:1, border 1/55 of
the height... characters about 75 mm tall (68 % of the height). Retroreflective sheeting is
glass-bead or micro-prism film; its faint hexagonal cell pattern is drawn as a 2 % modulation
so it looks the part (its optics are modelled by the sheeting reflectance, not by geometry).
Characters use OpenCV's Hershey duplex font (deterministic, no font files needed).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from poevp_optics.core.cache import cache_file, digest
from poevp_optics.core.io import write_png
from dataclasses import dataclass
from poevp_optics.core.params import param as _param


@dataclass(frozen=True)
class PlateSpec:
    """[plate]: plate text; when set, a texture is generated and bound to `$<param>`."""

    text: str = _param("")
    param: str = _param("plate_texture")
    width_px: int = _param(1040, min=64, max=8192)
    height_px: int = _param(220, min=16, max=2048)


PLATE_WIDTH_M = 0.520
PLATE_HEIGHT_M = 0.110


def plate_texture(text: str, width_px: int = 1040, height_px: int = 220,
                  sheeting_pattern: bool = True) -> np.ndarray:
    """Render `text` to a uint8 (height_px, width_px) weight map: 255 sheeting, 0 ink."""
    if not text or not text.strip():
        raise ValueError("plate text must not be empty")
    if width_px < 64 or height_px < 16:
        raise ValueError(f"plate texture too small: {width_px}x{height_px} px")
    img = np.full((height_px, width_px), 255, np.uint8)
    if sheeting_pattern:
        yy, xx = np.mgrid[0:height_px, 0:width_px].astype(np.float32)
        cell = max(height_px / 40.0, 2.0)
        hexes = (np.cos(2 * np.pi * xx / cell) + np.cos(np.pi * (xx + np.sqrt(3) * yy) / cell)
                 + np.cos(np.pi * (xx - np.sqrt(3) * yy) / cell))
        img = np.clip(255 - 2.5 * (hexes + 1.5), 0, 255).astype(np.uint8)
    border = max(int(round(height_px / 55 * 2)), 2)
    inset = max(int(round(height_px * 0.04)), 2)
    cv2.rectangle(img, (inset, inset), (width_px - 1 - inset, height_px - 1 - inset), 0, border,
                  lineType=cv2.LINE_AA)
    font = cv2.FONT_HERSHEY_DUPLEX
    target_h = 0.62 * height_px
    (tw, th), _ = cv2.getTextSize(text, font, 1.0, 1)
    scale = min(target_h / th, 0.86 * width_px / tw)
    thickness = max(int(round(scale * 2.2)), 1)
    (tw, th), base = cv2.getTextSize(text, font, scale, thickness)
    org = ((width_px - tw) // 2, (height_px + th) // 2)
    cv2.putText(img, text, org, font, scale, 0, thickness, lineType=cv2.LINE_AA)
    return img


def cached_plate_path(text: str, width_px: int = 1040, height_px: int = 220) -> Path:
    """Write (once) and return a plate texture PNG for `text` in the user cache folder, checked
    (checksum, and it decodes to this texture's size and pixels) before anything reads it; a file
    that fails is rebuilt (core/cache.py)."""
    from poevp_optics.core.cache import cached_path
    from poevp_optics.core.io import read_png

    path = cache_file("plates", f"plate_{digest(f'{text}|{width_px}|{height_px}|v1')}.png")
    texture = plate_texture(text, width_px, height_px)

    def problem(p: Path) -> str | None:
        img = read_png(p)
        if img.shape != texture.shape or img.dtype != texture.dtype:
            return f"{img.dtype} image of shape {img.shape}, not uint8 {texture.shape}"
        return None if np.array_equal(img, texture) else f"pixels differ from the plate {text!r}"

    return cached_path(path, lambda tmp: write_png(tmp, texture), problem)
