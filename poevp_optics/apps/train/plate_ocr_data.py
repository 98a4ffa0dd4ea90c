"""Training and test crops for the plate recogniser (analysis/plate_ocr.py): plates drawn with the
scene's own plate texture (sources/plates.py: font, layout, rim, EU band) as a camera behind the
DMD delivers them, and cropped as the text detector hands them over.

One crop (`plate_crop`), every parameter drawn from the sample's own generator:
- the plate: EU (p 0.8, a quarter with the blue band) or US format, 14-46 px tall, turned up to
  4 deg, foreshortened to 0.8-1 of its width (a plate seen 0-37 deg off its normal), sheeting
  pattern or not; drawn at 4x and area-averaged to the sensor's pixels at a random sub-pixel
  offset (a pixel integrates what falls on it);
- its surround: a bumper at 0-35 % of the plate's white, sometimes (p 0.15) a saturated lamp
  beside it;
- the optics: a Gaussian blur of 0.3-1.3 px (the relay's and objective's PSF, FACTS.md lens
  design: 1-2 px spot), horizontal motion blur up to 3 px (p 0.3), glare as a linear ramp up to
  30 % of white, the mask's transmission over the plate (`_mask_field`: smooth, sometimes a step);
- the exposure: white at 35-250 DN (p 0.1 over full scale, clipped), ink at 2-15 % of white,
  noise of a photon-transfer curve sigma^2 = g x signal + read^2 (g 0-1.5 DN/DN, read 0-3 DN),
  8-bit quantisation;
- the crop: the plate's box or the text's ink box (p 0.5 each), each side moved out by a random
  fraction of the plate's height (plate box: -0.12..0.35 in rows, -0.1..0.6 in columns; ink box:
  0..0.35 and 0..0.6), the spread of PP-OCRv4's detection boxes on the scene library's plates.

Texts (`training_texts`): one to three groups of one to four characters, five to eight in all,
uniform over A-Z and 0-9, from a seeded stream; a stream's text equal to any held-out text
(`HELD_OUT`: every scene's) is skipped, so training never sees a text the benchmarks read.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from poevp_optics.analysis.plate_ocr import CHARSET
from poevp_optics.analysis.recognition import normalise
from poevp_optics.core.paths import REPO_ROOT
from poevp_optics.sources.plates import PLATE_FORMATS, plate_texture

SUPER = 4                      # the plate is drawn at SUPER x the sensor's pixels, then area-averaged


def scene_texts(root: Path = REPO_ROOT / "scenes") -> set[str]:
    """Every plate text the shipped scenes draw (`text` / `plate_text` keys), normalised."""
    import tomllib

    out: set[str] = set()

    def walk(node):
        if isinstance(node, dict):
            for k, v in node.items():
                if k in ("text", "plate_text") and isinstance(v, str):
                    out.add(normalise(v))
                walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)

    for f in sorted(root.glob("*/scene.toml")):
        walk(tomllib.loads(f.read_text()))
    out.discard("")
    return out


def training_texts(seed: int, n: int, held_out: set[str]) -> list[str]:
    """n plate texts from the stream `seed` (module docstring), none of them in `held_out`."""
    rng = np.random.default_rng([seed, 7])
    out: list[str] = []
    while len(out) < n:
        total = int(rng.integers(5, 9))
        groups = int(rng.integers(1, 4))
        cuts = np.sort(rng.choice(np.arange(1, total), size=groups - 1, replace=False)) if groups > 1 else []
        chars = "".join(CHARSET[i] for i in rng.integers(0, len(CHARSET), total))
        parts = np.split(np.array(list(chars)), cuts)
        if any(len(p) > 4 for p in parts):
            continue
        if chars in held_out:
            continue
        out.append(" ".join("".join(p) for p in parts))
    return out


def _ink_box(tex: np.ndarray) -> tuple[int, int, int, int]:
    """(y0, x0, y1, x1) of the text's ink inside the rim (rows 15-85 % of the plate)."""
    h, w = tex.shape
    core = tex[int(0.15 * h):int(0.85 * h), int(0.03 * w):int(0.97 * w)] < 128
    rows, cols = np.nonzero(core.any(1))[0], np.nonzero(core.any(0))[0]
    if not rows.size:
        return 0, 0, h, w
    return (rows[0] + int(0.15 * h), cols[0] + int(0.03 * w), rows[-1] + 1 + int(0.15 * h),
            cols[-1] + 1 + int(0.03 * w))


def _mask_field(shape, h_px: float, rng: np.random.Generator) -> np.ndarray:
    """The DMD's transmission over the crop: a smooth field (a 3 x 6 grid of 1 +- 0.35 bilinearly
    spread) and, p 0.4, a step of 0.6-1.5x across a row or column, blurred by 0.5-2 px (the mask's
    smoothing and the relay)."""
    import cv2

    grid = 1.0 + rng.uniform(-1.0, 1.0, (3, 6)).astype(np.float32) * rng.uniform(0.0, 0.35)
    field = cv2.resize(grid, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)
    if rng.random() < 0.4:
        step = np.ones(shape, np.float32)
        if rng.random() < 0.5:
            step[:, int(rng.uniform(0.1, 0.9) * shape[1]):] = rng.uniform(0.6, 1.5)
        else:
            step[int(rng.uniform(0.2, 0.8) * shape[0]):, :] = rng.uniform(0.6, 1.5)
        field = field * cv2.GaussianBlur(step, (0, 0), rng.uniform(0.5, 2.0))
    return field


def plate_crop(text: str, rng: np.random.Generator, height_px: float | None = None) -> np.ndarray:
    """One uint8 grayscale crop of `text` on a plate (module docstring), the plate `height_px`
    tall when given."""
    import cv2

    fmt = "eu" if rng.random() < 0.8 else "us"
    f = PLATE_FORMATS[fmt]
    h_px = rng.uniform(14.0, 46.0) if height_px is None else float(height_px)
    w_px = h_px * f.width_mm / f.height_mm * rng.uniform(0.8, 1.0)
    band = fmt == "eu" and rng.random() < 0.25
    tex = plate_texture(text, max(64, int(round(SUPER * w_px))), max(16, int(round(SUPER * h_px))),
                        sheeting_pattern=bool(rng.random() < 0.5), plate_format=fmt, band=band)
    tex = tex.astype(np.float32) / 255.0
    th, tw = tex.shape
    iy0, ix0, iy1, ix1 = _ink_box((tex * 255).astype(np.uint8))
    # canvas at SUPER x: the plate in the middle of a bumper
    pad = int(SUPER * h_px)
    ch, cw = th + 2 * pad, tw + 2 * pad
    ink = rng.uniform(0.02, 0.15)
    surround = rng.uniform(0.0, 0.35)
    canvas = np.full((ch, cw), surround, np.float32)
    canvas[pad:pad + th, pad:pad + tw] = ink + (1.0 - ink) * tex
    if rng.random() < 0.15:                      # a saturated lamp beside the plate
        side = pad // 2 if rng.random() < 0.5 else cw - pad // 2
        cv2.circle(canvas, (side, int(ch * rng.uniform(0.3, 0.7))), int(pad * rng.uniform(0.2, 0.5)), 4.0, -1)
    angle = rng.uniform(-4.0, 4.0)
    off = rng.uniform(0.0, SUPER, 2)
    m = cv2.getRotationMatrix2D((cw / 2.0, ch / 2.0), angle, 1.0)
    m[:, 2] += off
    canvas = cv2.warpAffine(canvas, m, (cw, ch), flags=cv2.INTER_LINEAR, borderValue=surround)
    img = cv2.resize(canvas, (cw // SUPER, ch // SUPER), interpolation=cv2.INTER_AREA)
    img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.3, 1.3))
    if rng.random() < 0.3:
        k = int(rng.integers(2, 4))
        img = cv2.blur(img, (k, 1))
    ramp = rng.uniform(0.0, 0.3) * np.linspace(0, 1, img.shape[1], dtype=np.float32)[None, :]
    img = (img + (ramp if rng.random() < 0.5 else ramp[:, ::-1])) * _mask_field(img.shape, h_px, rng)
    white = rng.uniform(255.0, 320.0) if rng.random() < 0.1 else rng.uniform(35.0, 250.0)
    dn = img * white
    sigma = np.sqrt(rng.uniform(0.0, 1.5) * np.maximum(dn, 0.0) + rng.uniform(0.0, 3.0) ** 2)
    dn = np.clip(np.rint(dn + sigma * rng.standard_normal(dn.shape)), 0, 255).astype(np.uint8)
    # the crop, in sensor pixels (rotation ignored: a few degrees move the box by < 1 px per side)
    s = 1.0 / SUPER
    if rng.random() < 0.5:
        y0, x0, y1, x1 = pad * s, pad * s, (pad + th) * s, (pad + tw) * s
        gy, gx = rng.uniform(-0.12, 0.35, 2) * h_px, rng.uniform(-0.1, 0.6, 2) * h_px
    else:
        y0, x0, y1, x1 = (pad + iy0) * s, (pad + ix0) * s, (pad + iy1) * s, (pad + ix1) * s
        gy, gx = rng.uniform(0.0, 0.35, 2) * h_px, rng.uniform(0.0, 0.6, 2) * h_px
    oy, ox = off[1] * s, off[0] * s
    r0 = int(np.clip(np.floor(y0 + oy - gy[0]), 0, dn.shape[0] - 2))
    r1 = int(np.clip(np.ceil(y1 + oy + gy[1]), r0 + 2, dn.shape[0]))
    c0 = int(np.clip(np.floor(x0 + ox - gx[0]), 0, dn.shape[1] - 2))
    c1 = int(np.clip(np.ceil(x1 + ox + gx[1]), c0 + 2, dn.shape[1]))
    return dn[r0:r1, c0:c1]


def dataset(seed: int, n: int, held_out: set[str]) -> tuple[np.ndarray, list[str], str]:
    """(n, INPUT_H, INPUT_W) float32 prepared crops, their texts, and the SHA-256 of the uint8
    crops and texts (the data's identity in the weights' metadata)."""
    from poevp_optics.analysis.plate_ocr import INPUT_H, INPUT_W, prepare

    texts = training_texts(seed, n, held_out)
    x = np.empty((n, INPUT_H, INPUT_W), np.float32)
    sha = hashlib.sha256()
    for i, t in enumerate(texts):
        crop = plate_crop(t, np.random.default_rng([seed, 11, i]))
        sha.update(t.encode() + b"|" + str(crop.shape).encode() + crop.tobytes())
        x[i] = prepare(crop)
    return x, texts, sha.hexdigest()
