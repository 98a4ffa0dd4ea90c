"""Plate recognition with a real OCR engine that ships its models: RapidOCR (PP-OCRv4 ONNX).

RapidOCR (https://github.com/RapidAI/RapidOCR, `rapidocr-onnxruntime` on PyPI) bundles PaddleOCR's
PP-OCRv4 detection (DB, Liao et al. AAAI 2020), angle and recognition (SVTR-based CRNN) networks as
ONNX files inside the wheel, so no download happens at run time. Two readings of an 8-bit frame:

- `alpr_read`, full ALPR (the paper's protocol, Sec. 6: a detector then a recogniser on the captured
  frame, there YOLOv5 + CRNN): PP-OCRv4 detection + recognition on a search region (the whole frame,
  or a vehicle-sized window around the plate, as a two-stage system's vehicle detector would hand
  over) at its own size (not upscaled); the text counts when the detections whose centres lie over
  the plate's position, joined left to right, match the label in every character (paper Eq. 4).
  With `recogniser="plate"` the detections over the plate are read as one crop by a CRNN trained
  on the plate font (analysis/plate_ocr.py), whose reading has no language prior to turn a round
  O between digits into a zero.
- `read_plate`, recognition only: the recogniser on the geometric plate box (the scene knows it:
  `render.roi_shape`), upscaled 2x (`UPSCALE`). No detection can miss, but the box's edges
  (plate border, neighbouring paint) enter the recogniser's input.

Both sides are upper-cased and stripped of everything but A-Z and 0-9 before comparing.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass

import numpy as np

#: Detection on the search region at its own size: RapidOCR's default ("min", 736) upscales the
#: short side to 736 px, 4-16x the work on our frames; PP-OCRv4 finds 10 px tall plate text
#: without it. In "max" mode RapidOCR 1.4.4 ignores `det_limit_side_len` (ch_ppocr_det/
#: text_detect.py get_preprocess): it takes the limit from the image's long side (960 px below
#: 960, 1500 below 1500, else 2000), so a region up to 2000 px long is detected at its own size
#: (rounded to multiples of 32) and a longer one is scaled down to 2000 px.
DET_CONFIG = {"det_limit_type": "max", "det_limit_side_len": 1280}
UPSCALE = 2          # recognition only: the plate crop, upscaled
#: Whole-frame ALPR's recognisers: PP-OCRv4's general scene-text recogniser, or the CRNN trained
#: on the plate font (analysis/plate_ocr.py), as the paper's protocol reads plates.
RECOGNISERS = ("ppocr", "plate")
#: The plate recogniser's crop: the detections over the plate, grown by this x their height on
#: every side (inside the margins its training crops draw, apps/train/plate_ocr_data.py).
PLATE_CROP_GROW = 0.1


def normalise(text: str) -> str:
    return re.sub(r"[^A-Z0-9]", "", text.upper())


def _bgr_upscaled(gray: np.ndarray, factor: int = UPSCALE):
    import cv2

    img = np.ascontiguousarray(gray).astype(np.uint8)
    if factor != 1:
        img = cv2.resize(img, None, fx=factor, fy=factor, interpolation=cv2.INTER_CUBIC)
    return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img


def read_plate(img_8bit: np.ndarray, box, margin_px: int = 2) -> tuple[str, float, float]:
    """Recognition only: (text, confidence, seconds) of the plate inside `box` (y0, x0, y1, x1)."""
    from poevp_optics.core.runtime import ocr_engine

    h, w = img_8bit.shape[:2]
    y0, x0, y1, x1 = box
    crop = img_8bit[max(0, y0 - margin_px):min(h, y1 + margin_px), max(0, x0 - margin_px):min(w, x1 + margin_px)]
    if crop.size == 0:
        return "", 0.0, 0.0
    bgr = _bgr_upscaled(crop)
    t0 = time.perf_counter()
    res, _ = ocr_engine()(bgr, use_det=False, use_cls=False, use_rec=True)
    dt = time.perf_counter() - t0
    if not res:
        return "", 0.0, dt
    return str(res[0][0]), float(res[0][1]), dt


def search_window(box, shape, widths: float = 3.5, heights: float = 10.0):
    """A vehicle-sized search window (y0, x0, y1, x1) centred on the plate box, clipped to `shape`:
    a car's rear is ~3.5 plate widths wide (1.8 m / 0.52 m) and ~10 plate heights tall (1.1 m /
    0.11 m), what a vehicle detector hands a plate detector in a two-stage ALPR system."""
    y0, x0, y1, x1 = box
    cy, cx = (y0 + y1) / 2.0, (x0 + x1) / 2.0
    hh, hw = heights * (y1 - y0) / 2.0, widths * (x1 - x0) / 2.0
    return (max(0, int(cy - hh)), max(0, int(cx - hw)), min(shape[0], int(np.ceil(cy + hh))),
            min(shape[1], int(np.ceil(cx + hw))))


@dataclass(frozen=True)
class AlprRead:
    """A full-ALPR reading: the text over the plate, its mean confidence, the detections in the
    search region (all of them, plate or not) and the detector + recogniser time."""

    text: str
    confidence: float
    detections: int
    seconds: float


def _over_plate(quad, box, offset) -> bool:
    """Whether a detection's centre lies over the plate `box` grown by half its height."""
    y0, x0, y1, x1 = box
    m = 0.5 * (y1 - y0)
    q = np.asarray(quad, dtype=np.float64)
    cx, cy = q[:, 0].mean() + offset[1], q[:, 1].mean() + offset[0]
    return x0 - m <= cx <= x1 + m and y0 - m <= cy <= y1 + m


def alpr_read(img_8bit: np.ndarray, box, region=None, recogniser: str = "ppocr") -> AlprRead:
    """Detection + recognition on `region` (y0, x0, y1, x1; None: the whole frame) of an 8-bit
    frame. `recogniser` "ppocr": PP-OCRv4 reads each detection, and the text is the detections
    whose centres lie over the plate `box` (grown by half its height), joined left to right.
    "plate": the plate-font CRNN (analysis/plate_ocr.py) reads one crop, the detections over the
    plate joined into one box grown by `PLATE_CROP_GROW` of its height on every side."""
    from poevp_optics.core.runtime import ocr_engine

    if recogniser not in RECOGNISERS:
        raise ValueError(f"recogniser {recogniser!r}: expected one of {', '.join(RECOGNISERS)}")
    h, w = img_8bit.shape[:2]
    ry0, rx0, ry1, rx1 = region if region is not None else (0, 0, h, w)
    sub = img_8bit[ry0:ry1, rx0:rx1]
    if sub.size == 0:
        return AlprRead("", 0.0, 0, 0.0)
    bgr = _bgr_upscaled(sub, 1)
    t0 = time.perf_counter()
    if recogniser == "plate":
        quads, _ = ocr_engine(**DET_CONFIG)(bgr, use_det=True, use_cls=False, use_rec=False)
        return _plate_read(sub, [q for q in quads or () if _over_plate(q, box, (ry0, rx0))],
                           len(quads or ()), t0)
    res, _ = ocr_engine(**DET_CONFIG)(bgr, use_det=True, use_cls=False, use_rec=True)
    dt = time.perf_counter() - t0
    hits = sorted((np.asarray(quad, dtype=np.float64)[:, 0].mean(), str(text), float(conf))
                  for quad, text, conf in res or () if _over_plate(quad, box, (ry0, rx0)))
    return AlprRead("".join(t for _, t, _ in hits), float(np.mean([c for *_, c in hits])) if hits else 0.0,
                    len(res or ()), dt)


def _plate_read(sub: np.ndarray, quads: list, detections: int, t0: float) -> AlprRead:
    """The plate-font CRNN on the union of `quads` (in `sub`'s pixels), grown by PLATE_CROP_GROW."""
    from poevp_optics.analysis.plate_ocr import read_crops

    if not quads:
        return AlprRead("", 0.0, detections, time.perf_counter() - t0)
    pts = np.concatenate([np.asarray(q, dtype=np.float64) for q in quads])
    (qx0, qy0), (qx1, qy1) = pts.min(0), pts.max(0)
    g = PLATE_CROP_GROW * (qy1 - qy0)
    y0, x0 = max(0, int(np.floor(qy0 - g))), max(0, int(np.floor(qx0 - g)))
    y1, x1 = min(sub.shape[0], int(np.ceil(qy1 + g))), min(sub.shape[1], int(np.ceil(qx1 + g)))
    crop = sub[y0:y1, x0:x1]
    if crop.shape[0] < 2 or crop.shape[1] < 2:
        return AlprRead("", 0.0, detections, time.perf_counter() - t0)
    text, conf = read_crops([crop])[0]
    return AlprRead(text, conf, detections, time.perf_counter() - t0)


def correct(read: str, label: str) -> bool:
    """Paper Eq. 4: a plate counts only when every character matches."""
    return normalise(read) == normalise(label) and normalise(label) != ""


def read_frame(img_8bit: np.ndarray) -> list[tuple[str, float, float]]:
    """Detection + recognition on a whole 8-bit frame (no crop from a known box): the texts
    RapidOCR finds, each as (text, confidence, x of its box centre), left to right."""
    import cv2

    from poevp_optics.core.runtime import ocr_engine

    img = np.ascontiguousarray(img_8bit).astype(np.uint8)
    bgr = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img
    res, _ = ocr_engine()(bgr, use_det=True, use_cls=False, use_rec=True)
    out = [(str(text), float(conf), float(np.mean([p[0] for p in box]))) for box, text, conf in (res or [])]
    return sorted(out, key=lambda r: r[2])


def frame_reads(img_8bit: np.ndarray, label: str) -> tuple[bool, str]:
    """Whether a whole frame reads the plate: some run of consecutive texts found in it (left
    to right) joins to exactly the label (paper Eq. 4: every character). (read?, texts)."""
    texts = [normalise(t) for t, _, _ in read_frame(img_8bit)]
    want = normalise(label)
    ok = any("".join(texts[i:j]) == want for i in range(len(texts)) for j in range(i + 1, len(texts) + 1))
    return ok and want != "", " | ".join(texts)
