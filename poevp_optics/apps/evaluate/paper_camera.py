"""The paper's own simulation of its camera, for Table 2 like for like (He et al., Photonics
Research 12(11), 2524 (2024), Sec. 6 and Fig. 3), beside this project's physical camera.

The paper's pipeline, in its 8-bit code values: H = O (E G + 1) on the stored frames (Eq. 3,
Sec. 4.A); the simulated LDR frame is H "cut off to 255"; the predictor sees the last two LDR
frames resized to 368x640; the mask law (Eq. 2) maps the predicted frame to an 8-bit mask M; the
capture is "the Hadamard product ... between the mask predictions and HDR information maps", then
"the over-255-cutoff that simulates the sensor's dynamic range clipping"; frames T = 0, 1 initialise
the loop (white mask) and are not scored; the capture goes to the ALPR as it is (Sec. 6: "we
directly send the simulated sensor captures into ALPR Net"). So: noiseless, an ideal per-pixel
transmission M / 255 (no DMD floor, no smoothing, no relay, no sensor), rounding to integers.

Fusion baselines as the paper applies them (Sec. 6): three consecutive frames multiplied by the
global exposure coefficients 1/8, 1/5 and 1 in code values, each cut off at 255, merged by
Mertens fusion (OpenCV; the artifact-reduced variant aligns them with MTB first, as
apps/evaluate/evaluate.py does for the physical camera).

`PaperEffects` adds one physical effect at a time, to attribute the loss from the paper's camera
to ours: the DMD's floor (transmission M/255 (1 - 1/CR) + 1/CR, the off-state leakage of the
scene's contrast ratio), the mask's smooth upper envelope (the scene's mask.smooth_px), and the
sensor's noise (Poisson shot noise on the code value's electrons at the scene sensor's
saturation capacity plus its read noise, then the 8-bit cut-off), and linear light: the physical
camera receives H as light, i.e. decoded by the frames' sRGB transfer (IEC 61966-2-1, extended
above 1, as sources/ldr_highlight.py does with e_domain = "display"), so a stored value raised
(E + 1)-fold becomes ((E + 1) V + 0.055)^2.4 / 1.055^2.4 in linear units (E = 29: ~3500-fold at
V = 1) and the capture is the raw linear value (linear 1 = `white` of full scale, the demo
scene's anchor), as the physical camera's 8-bit images are.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from poevp_optics.control.loop_step import resize_keeping_clip
from poevp_optics.control.masks import MASK_LAWS, MaskSpec

#: Paper Sec. 6: the fusion's global exposure coefficients (low, medium, high).
FUSION_COEFFICIENTS = (1.0 / 8.0, 1.0 / 5.0, 1.0)
#: Paper Sec. 6: the simulated LDR frames are resized to the VP model's input size.
PREDICTOR_SIZE = (368, 640)
INIT_FRAMES = 2
#: scenes/ldr_highlight_demo: luminance_cd_per_m2 = 36, "0.8 x this camera's saturation" (linear 1).
LINEAR_WHITE = 0.8


@dataclass(frozen=True)
class PaperEffects:
    """Physical effects added to the paper's ideal camera (module docstring); all off = the paper."""

    dmd_floor: bool = False
    smoothing: bool = False
    noise: bool = False
    linear_light: bool = False

    @property
    def label(self) -> str:
        on = [n for n, v in (("DMD floor", self.dmd_floor), ("smoothing", self.smoothing), ("noise", self.noise),
                             ("linear light", self.linear_light)) if v]
        return "paper camera" + (" + " + " + ".join(on) if on else "")


@dataclass(frozen=True)
class PaperSequence:
    """One E's code-value frames: HDR maps H (float64, can exceed 255), plate boxes, texts."""

    hdr: list
    boxes: dict
    texts: dict
    e: float


def paper_sequence(spec) -> PaperSequence:
    """The ldr_highlight scene's frames as the paper forms them: H = O (E G + 1) on the stored
    values in code values (0-255 scale), grey (Rec. 709 luma of RGB frames)."""
    from poevp_optics.sources.ldr_highlight import (REC709_LUMA, RADIUS_RULES, LdrHighlightSource,
                                                    artificial_highlight, frame_radius_px, stored_values)

    from poevp_optics.camera.sensor import resolve_sensor

    src = LdrHighlightSource(spec.resolved.render, 0, resolve_sensor(spec.sensor).qe)
    sigma = RADIUS_RULES[spec.source.radius_rule](frame_radius_px(spec.source.r_px, src.shape_in))
    hdr, boxes, texts = [], {}, {}
    n = min(spec.timing.frames, len(src.files) if src._video is None else src._video.count)
    for j in range(n):
        v = stored_values(src.decoded(j))
        if v.ndim == 3:
            v = v[..., :3] @ np.asarray(REC709_LUMA)
        box = src.boxes.get(j)
        hdr.append(255.0 * artificial_highlight(v, box, spec.source.e, sigma))
        if box is not None:
            boxes[j] = (int(box.y0), int(box.x0), int(np.ceil(box.y1)), int(np.ceil(box.x1)))
            texts[j] = box.text
    return PaperSequence(hdr, boxes, texts, float(spec.source.e))


def as_light(seq: PaperSequence, white: float = LINEAR_WHITE) -> PaperSequence:
    """The sequence as the physical camera's light: H decoded by sRGB (extended above 1) and
    scaled so that linear 1 is `white` of full scale, in code values (module docstring)."""
    from poevp_optics.sources.ldr_highlight import srgb_to_linear

    hdr = [255.0 * white * srgb_to_linear(np.asarray(h, np.float64) / 255.0) for h in seq.hdr]
    return dataclasses.replace(seq, hdr=hdr)


def capture(h: np.ndarray, mask255: np.ndarray, effects: PaperEffects, *, contrast_ratio: float,
            saturation_e: float, read_noise_e: float, rng: np.random.Generator | None) -> np.ndarray:
    """The paper's capture: clip(H x T, 0, 255) rounded to 8 bits, T = M / 255 (ideal) or with
    the DMD floor; with noise, shot and read noise on the electrons (255 = saturation_e) first."""
    t = np.asarray(mask255, np.float64) / 255.0
    if effects.dmd_floor:
        t = t * (1.0 - 1.0 / contrast_ratio) + 1.0 / contrast_ratio
    x = np.asarray(h, np.float64) * t
    if effects.noise:
        e = x * (saturation_e / 255.0)
        e = rng.poisson(np.minimum(e, 1e12)).astype(np.float64) + rng.normal(0.0, read_noise_e, e.shape)
        x = e * (255.0 / saturation_e)
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def mask_from(pred_8bit: np.ndarray, mask: MaskSpec, effects: PaperEffects) -> np.ndarray:
    """Eq. 2 (the scene's law and coefficients) on a predicted frame; the smooth envelope only
    with the smoothing effect; 8-bit mask values 0-255 (the law's own rounding)."""
    spec = mask if effects.smoothing else dataclasses.replace(mask, smooth_px=0.0)
    from poevp_optics.control.masks import mask_levels

    return mask_levels(spec, 8, pred_8bit=pred_8bit)


def poevp_captures(seq: PaperSequence, predictor, mask: MaskSpec, effects: PaperEffects, *,
                   contrast_ratio: float, saturation_e: float, read_noise_e: float, seed: int = 0):
    """{t: 8-bit capture} of the loop over the sequence, and predictor + law seconds per frame.
    `predictor`: a built causal predictor, or None for the oracle (the true LDR frame)."""
    if effects.linear_light:
        seq = as_light(seq)
    rng = np.random.default_rng(seed)
    shape = seq.hdr[0].shape
    ldr = [np.clip(h, 0, 255) for h in seq.hdr]
    hist = [resize_keeping_clip(f.astype(np.float32), PREDICTOR_SIZE) for f in ldr]
    out, secs = {}, []
    for j, h in enumerate(seq.hdr):
        if j < INIT_FRAMES:
            m = np.full(shape, 255.0)
        else:
            t0 = time.perf_counter()
            if predictor is None:
                pred = ldr[j]
            else:
                p = predictor(hist[max(0, j - 4):j])
                pred = resize_keeping_clip(np.asarray(p, np.float32), shape)
            m = mask_from(np.clip(pred, 0, 255), mask, effects)
            secs.append(time.perf_counter() - t0)
        out[j] = capture(h, m, effects, contrast_ratio=contrast_ratio, saturation_e=saturation_e,
                         read_noise_e=read_noise_e, rng=rng)
    return out, secs


def fusion_captures(seq: PaperSequence, deghost: bool) -> dict:
    """{t: fused 8-bit frame} of frames t-2, t-1, t at the paper's coefficients (module docstring)."""
    import cv2

    out = {}
    for t in range(INIT_FRAMES, len(seq.hdr)):
        imgs = [cv2.cvtColor(np.clip(np.rint(seq.hdr[j] * c), 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
                for j, c in zip((t - 2, t - 1, t), FUSION_COEFFICIENTS)]
        if deghost:
            cv2.createAlignMTB().process(imgs, imgs)
        fused = cv2.createMergeMertens().process(imgs)
        gray = cv2.cvtColor(np.clip(fused * 255.0, 0, 255).astype(np.float32), cv2.COLOR_BGR2GRAY)
        out[t] = np.rint(gray).astype(np.uint8)
    return out


def ldr_captures(seq: PaperSequence, effects: PaperEffects = PaperEffects()) -> dict:
    """{t: 8-bit LDR frame}: H cut off at 255 (of the light with the linear-light effect)."""
    if effects.linear_light:
        seq = as_light(seq)
    return {t: np.clip(np.rint(h), 0, 255).astype(np.uint8) for t, h in enumerate(seq.hdr)}


#: `poevp evaluate --camera`: the physical camera (DMD, sensor, light) or the paper's simulation.
CAMERAS = ("physical", "paper")
EFFECTS = tuple(f.name for f in dataclasses.fields(PaperEffects))


def effects_from(names) -> PaperEffects:
    """PaperEffects from effect names (`--paper-effects dmd_floor,noise`); one-line error on a typo."""
    bad = [n for n in names if n not in EFFECTS]
    if bad:
        raise ValueError(f"--paper-effects: unknown {bad}; choose from {', '.join(EFFECTS)}")
    return PaperEffects(**{n: True for n in names})


def method_images(seq: PaperSequence, methods, mask: MaskSpec, effects: PaperEffects, model_of, *,
                  contrast_ratio: float, saturation_e: float, read_noise_e: float, seed: int = 0):
    """{method: {t: 8-bit frame}}, {method: seconds per frame} of the paper's camera for `methods`
    (ldr, fusion_classic, fusion_deghost, or a predictor name; `model_of(name)` builds it, None for
    the oracle). Fusions stay in code values as the paper applies them (no effects)."""
    phys = dict(contrast_ratio=contrast_ratio, saturation_e=saturation_e, read_noise_e=read_noise_e)
    images, secs = {}, {}
    for m in methods:
        t0 = time.perf_counter()
        if m == "ldr":
            images[m], secs[m] = ldr_captures(seq, effects), [0.0]
        elif m in ("fusion_classic", "fusion_deghost"):
            images[m] = fusion_captures(seq, m == "fusion_deghost")
            secs[m] = [(time.perf_counter() - t0) / max(len(images[m]), 1)]
        else:
            images[m], secs[m] = poevp_captures(seq, model_of(m), mask, effects, **phys, seed=seed)
    return images, secs
