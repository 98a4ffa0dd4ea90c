"""Plate recognition, one page: every scene, condition and method, full ALPR beside recognition
only, the paper's Table 2 beside, the fusions' gap to the paper attributed, and the cause of every
large ALPR vs recognition-only gap with an example frame.

    .venv/bin/python -m benchmarks.recognition [--quick] [--sections ...] [--set KEY=VALUE ...] [--results]

`--set` changes a scene key in every section after the section's own settings (e.g. the mask
envelope, `mask.envelope="predictor_error"`, with the per-frame exposure time,
`mask.exposure_time_auto=true`; docs/physics/closed-loop.md); the page's header names them in its
command line.

Scenes and conditions:

* `ldr_highlight_demo`, the paper's protocol (paper Sec. 6; apps/evaluate/eval_paper.py): the LDR
  sequence with Eq. 3's highlight H = O (E G + 1) at E = 9, 29, 49, R = 50 px, loop open, frames
  2-7 scored, in the paper's idealised camera (apps/evaluate/paper_camera.py: 8-bit code values,
  noiseless Hadamard product, cut-off at 255, Eq. 2's linear reading) and in the physical camera
  (DMD PWM, sensor noise, sRGB-decoded light, the exposure controller with the mask envelope sized
  by the loop's measured miss and the exposure time chosen per frame: `poevp evaluate`'s physical
  camera, apps/evaluate/eval_paper.py PHYSICAL_CONTROLS). The demo's plate text is
  the one its frames show.
* `highbeam_plate`: the plate carried laterally at a set image speed (px/frame) and scaled to
  over-exposure E (display reading, apps/evaluate/eval_sequences.py), `poevp evaluate`'s sequences.
* Road scenes (`night_road`, `wet_night_road`, `fog_highway`): the scene's own motion (the car
  ahead closing), 21 frames, at its own high beams (x1; night_road also at ten times them, x10,
  re-rendered), at a reduced camera scale (the same field on fewer mirrors, scene/scale.py):
  night_road 1/6 (its 21 frames at two beam levels: at 1/3 they take longer to render than a
  run on two shared cores allows), wet_night_road 1/4, fog_highway 1/6 (its fog is the slowest
  to render).

Methods: `ldr` (the DMD white), `fusion_classic` and `fusion_deghost` (frames t-2, t-1, t at global
exposures 1/8, 1/5, 1, Mertens fusion, the latter after MTB alignment), POE-VP with each predictor,
and the oracle (the true next frame). Readings (analysis/recognition.py): full ALPR (PP-OCRv4
detection + recognition on the whole 8-bit frame; the text over the plate must match every
character, paper Eq. 4) and recognition only (the recogniser on the known plate box). Cells:
reads/frames with Wilson's 95 % interval (analysis/statistics.py). Test texts hold the confusable
pairs 0/O, 1/I and 8/B, so a misread between them shows in the confusion table.

Writes recognition.md, recognition_examples.png, recognition_gaps.png (where a gap exceeds
`GAP_POINTS`) and recognition_frames.csv into out/benchmarks/ (benchmarks/results/ with
--results). The page is generated from the measured rows only (`page`).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import datetime
import io
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.common import ROOT, add_results_flag, machine_line, markdown_table, output_folder, save_text

SCENES_DIR = ROOT / "scenes"
DEMO = SCENES_DIR / "ldr_highlight_demo"
#: Test texts: "LLL DDDD" (the predictors' training texts are "LL D" + 4 digits, never this
#: form), each holding both sides of the pairs an OCR confuses: O/0, I/1, B/8.
TEXTS = ("BIO 1080", "OIB 8101")
#: Confusable character pairs the page counts (both directions).
CONFUSABLE = (("0", "O"), ("1", "I"), ("8", "B"))
#: Paper Table 2 (He et al. 2024), recognition accuracy in %, E = 9/29/49 pooled, its own test set.
PAPER_TABLE2 = {"fusion_classic": 65.07, "fusion_deghost": 88.56, "poevp": 94.86}
#: A POE-VP row whose recognition-only rate exceeds its full-ALPR rate by more than this many
#: percentage points gets its cause and an example frame on the page.
GAP_POINTS = 10.0
#: Confusions other than the confusable pairs the page lists (most frequent first).
CONFUSION_ROWS = 12
#: Where each road scene's plate text is set (the plate the scene's render.roi_shape names).
ROAD_TEXT_KEYS = {"night_road": "plate.text", "wet_night_road": "vehicle.car.plate_text",
                  "fog_highway": "vehicle.truck.plate_text"}
BASELINES = ("ldr", "fusion_classic", "fusion_deghost")
#: Default cache folder (git-ignored); --cache names another (e.g. one shared by several checkouts).
CACHE = ROOT / "out" / "benchmarks" / "recognition_cache"
SECTIONS = ("paper_camera", "physical_camera", "fusion_attribution", "highbeam_plate", *ROAD_TEXT_KEYS)


@dataclass(frozen=True)
class Config:
    """What one run measures (FULL, QUICK below)."""

    predictors: tuple[str, ...]
    paper_e: tuple[float, ...]
    texts: tuple[str, ...]
    speeds_px: tuple[float, ...]
    highbeam_e: tuple[float, ...]
    highbeam_frames: int
    road: dict                       # road scene -> (camera scale, beam gains)
    road_frames: int
    sections: tuple[str, ...] = SECTIONS
    label: str = "full"
    fresh: bool = False               # ignore the render and OCR caches
    cache: Path = CACHE
    overrides: tuple[str, ...] = ()   # --set KEY=VALUE: scene keys for every section's loop (after its own)


FULL = Config(predictors=("hold", "flow", "track_net", "dmvfn_lite", "oracle"), paper_e=(9.0, 29.0, 49.0),
              texts=TEXTS, speeds_px=(4.0, 24.0), highbeam_e=(9.0, 49.0), highbeam_frames=6,
              road={"night_road": (1 / 6, (1.0, 10.0)), "wet_night_road": (1 / 4, (1.0,)),
                    "fog_highway": (1 / 6, (1.0,))}, road_frames=21)
#: Development and CI size: one E, two predictors, one text, one speed, road scenes short and small.
QUICK = Config(predictors=("flow", "oracle"), paper_e=(9.0,), texts=TEXTS[:1], speeds_px=(24.0,),
               highbeam_e=(9.0,), highbeam_frames=5, road={s: (1 / 6, (1.0,)) for s in ROAD_TEXT_KEYS}, road_frames=6,
               label="quick")


# ----------------------------------------------------------------------------------------------
# Caches: renders and OCR readings, by content (a rerun after a change to the loop redoes only
# what the change touched)

#: Bump on a change to what a kept road render stores.
RENDER_CACHE_VERSION = "recognition-render-v2"


def render_key(spec, guard_px: int) -> str:
    """A road render's key: everything the render depends on (eval_sequences.render_fingerprint:
    the resolved scene with its frame timing, the files it reads, the plate font, the render
    code, the software versions and the backend), as `poevp evaluate` keys its sequences."""
    from poevp_optics.apps.evaluate.eval_sequences import render_fingerprint
    from poevp_optics.core.cache import json_digest

    return json_digest([RENDER_CACHE_VERSION, render_fingerprint(spec, guard_px)], sort_keys=True, default=str)


def cached_render(scene: str, overrides: list[str], cache: Path, fresh: bool = False):
    """(spec, exposures, when rendered): benchmarks.plate_band.render_once, kept under `cache` by
    `render_key` and checked on load (core/cache.py: checksum; a damaged file is rendered again);
    `--fresh` renders again."""
    import pickle

    from benchmarks.plate_band import render_once
    from poevp_optics.camera.camera import Camera
    from poevp_optics.core.cache import cached, discard
    from poevp_optics.scene.load import load_scene

    spec = load_scene(scene, overrides)
    guard = Camera.from_params(spec.resolved.camera).guard_px
    path = cache / f"render-{Path(scene).name}-{render_key(spec, guard)}.pkl"
    if fresh:
        discard(path)

    def load(p: Path):
        with open(p, "rb") as f:
            return pickle.load(f)

    def save(tmp: Path, ex) -> None:
        with open(tmp, "wb") as f:
            pickle.dump(ex, f, protocol=pickle.HIGHEST_PROTOCOL)

    def check(ex) -> str | None:
        n = spec.timing.frames
        return None if isinstance(ex, list) and len(ex) == n else f"not a list of {n} rendered exposures"

    ex = cached(path, lambda: render_once(scene, overrides)[2], load=load, save=save, check=check)
    return spec, ex, _stamp(path)


def _stamp(path: Path) -> str:
    return datetime.datetime.fromtimestamp(path.stat().st_mtime, datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def load_ocr_cache(cache: Path) -> dict:
    """Runner.read's cache {(image sha1, box, label): reading} kept under `cache` (by OCR version)."""
    import json

    path = cache / f"ocr-{_ocr_version()}.json"
    if not path.is_file():
        return {}
    return {(k[0], tuple(k[1]), k[2]): v for k, v in json.loads(path.read_text())}


def save_ocr_cache(readings: dict, cache: Path) -> None:
    """`readings` merged into the kept file (another run may have added to it meanwhile)."""
    import json

    cache.mkdir(parents=True, exist_ok=True)
    merged = {**load_ocr_cache(cache), **readings}
    save_text(cache / f"ocr-{_ocr_version()}.json", json.dumps([[list(k[:1]) + [list(k[1]), k[2]], v]
                                                               for k, v in merged.items()]))


def _ocr_version() -> str:
    """The OCR engine's version and the reading code's digest: a kept reading is the engine's
    output through analysis/recognition.py (detection, recognition, the text match) and
    evaluate's Runner.read (the plate box's entropy and exposure)."""
    from importlib.metadata import version

    from poevp_optics.render.render_cache import code_digest

    code = code_digest(("analysis/recognition.py", "analysis/metrics.py", "apps/evaluate/evaluate.py"))
    return f"rapidocr-{version('rapidocr-onnxruntime')}-{code}"


# ----------------------------------------------------------------------------------------------
# Reading and rows


def wilson_cell(k: int, n: int) -> str:
    """'k/n = p % [lo-hi]' with Wilson's 95 % interval; '-' for no frames."""
    from poevp_optics.analysis.statistics import wilson_interval

    if n == 0:
        return "-"
    lo, hi = wilson_interval(k, n)
    return f"{k}/{n} = {100 * k / n:.0f} % [{100 * lo:.0f}-{100 * hi:.0f}]"


def is_poevp(method: str) -> bool:
    return method not in BASELINES


@dataclass
class Reader:
    """Reads frames (both readings, cached by content through evaluate's Runner) into rows, and
    keeps the example frames the page shows."""

    runner: object = None
    cache: dict = field(default_factory=dict)        # OCR readings by image content, shared by every runner
    rows: list = field(default_factory=list)
    examples: dict = field(default_factory=dict)     # (scene, camera, condition, method) -> (img, box, row)
    showcase: dict = field(default_factory=dict)     # method -> (img, box, row), one condition
    renders: dict = field(default_factory=dict)      # road render -> when it was made

    def read(self, img, box, label: str, **meta) -> dict:
        r = self.runner.read(np.asarray(img, np.uint8), tuple(int(v) for v in box), label)
        row = {**meta, "text": label, "alpr_ok": bool(r["alpr_ok"]), "rec_ok": bool(r["rec_ok"]),
               "alpr_text": r["alpr_text"], "rec_text": r["rec_text"], "detections": int(r["detections"]),
               "plate_clipped": round(float(r["plate_clipped"]), 4), "plate_p90": float(r["plate_p90"])}
        self.rows.append(row)
        key = (row["scene"], row["camera"], row["condition"], row["method"])
        if row.get("factor", "") == "" and is_poevp(row["method"]) and row["rec_ok"] and not row["alpr_ok"] \
                and key not in self.examples:
            self.examples[key] = (np.asarray(img, np.uint8).copy(), tuple(box), row)
        return row

    def read_methods(self, images: dict, boxes: dict, texts: dict, first: int, **meta) -> None:
        for m, frames in images.items():
            for t in sorted(frames):
                if t < first or boxes.get(t) is None or not texts.get(t):
                    continue
                self.read(frames[t], boxes[t], texts[t], method=m, frame=int(t), **meta)


def make_runner(reader: Reader, scene: Path, spec, predictors, loop_mode: str = "open"):
    """evaluate's Runner (camera, predictors built once) for `spec`, reading into reader's cache;
    it becomes reader.runner."""
    from poevp_optics.apps.evaluate.evaluate import EvalConfig, Runner
    from poevp_optics.camera.camera import Camera

    cfg = EvalConfig(scene=scene, predictors=tuple(predictors), baselines=BASELINES, loop_mode=loop_mode)
    reader.runner = Runner(cfg, spec, Camera.from_params(spec.resolved.camera), ocr_cache=reader.cache)
    return reader.runner


# ----------------------------------------------------------------------------------------------
# The paper's protocol


def paper_protocol(reader: Reader, cfg: Config, camera: str, log=print) -> dict:
    """Rows of the paper's protocol on the demo in `camera` ('paper' or 'physical'); returns
    {E: PaperSequence} of the paper camera (for the fusion attribution)."""
    from poevp_optics.apps.evaluate import paper_camera as pc
    from poevp_optics.apps.evaluate.eval_paper import (DEFAULT_LAWS, camera_controls, paper_exposures, paper_overrides,
                                                       predictor_models)
    from poevp_optics.camera.camera import Camera
    from poevp_optics.camera.sensor import resolve_sensor
    from poevp_optics.scene.load import load_scene

    law = DEFAULT_LAWS[camera]
    label = "paper camera" if camera == "paper" else "physical camera"
    seqs, runner = {}, None
    for e in cfg.paper_e:
        t0 = time.perf_counter()
        spec = load_scene(DEMO, [*paper_overrides(e, law), *camera_controls(camera), *cfg.overrides])
        if runner is None:
            runner = make_runner(reader, DEMO, spec, cfg.predictors)
        runner.spec, runner.cam = spec, Camera.from_params(spec.resolved.camera)
        meta = dict(scene="ldr_highlight_demo", camera=label, condition=f"E = {e:g}", factor="")
        if camera == "paper":
            seq = pc.paper_sequence(spec)
            seqs[e] = seq
            sensor = resolve_sensor(spec.sensor)
            images, _ = pc.method_images(seq, (*BASELINES, *cfg.predictors), spec.resolved.loop.mask, pc.PaperEffects(),
                                         predictor_models(runner, spec), contrast_ratio=spec.dmd.contrast_ratio,
                                         saturation_e=sensor.saturation_capacity_e, read_noise_e=sensor.read_noise_e,
                                         seed=spec.sensor.seed)
            reader.read_methods(images, seq.boxes, seq.texts, pc.INIT_FRAMES, **meta)
        else:
            ex = paper_exposures(spec, runner.cam)
            images, _ = runner.method_images(ex)
            boxes = {x.index: runner.cam.box_to_sensor(x.roi) if x.roi else None for x in ex}
            texts = {x.index: (x.ground_truth or {}).get("text", "") for x in ex}
            reader.read_methods(images, boxes, texts, spec.loop.init_frames, **meta)
        log(f"recognition: ldr_highlight_demo, {label}, E = {e:g} ({time.perf_counter() - t0:.0f} s)")
    return seqs


# ----------------------------------------------------------------------------------------------
# The fusions attributed (paper camera)


@dataclass(frozen=True)
class FusionVariant:
    """One way of forming the paper's fusion baseline in its camera: which frames (consecutive
    t-2, t-1, t, or frame t three times: no motion), what the coefficients multiply (the HDR map
    H before the 255 cut-off, or the clipped 8-bit frame), the Mertens weights (`bgr_grey`: the grey
    frame replicated into three channels, where Mertens' saturation weight is 0 everywhere and the
    fusion is the plain mean; `grey`: one channel, contrast x well-exposedness), the light
    (code values, as the paper; or linear light, the physical camera's reading of H), and where
    the artifact-reduced fusion's MTB alignment measures its shifts (`align_normalised`: on the
    frames divided by their coefficients, one exposure, instead of the frames as exposed)."""

    name: str
    static: bool = False
    after_clip: bool = False
    weights: str = "bgr_grey"
    linear_light: bool = False
    align_normalised: bool = False


VARIANTS = (
    FusionVariant("as run in the tables (consecutive frames, coefficients on H, Mertens on the grey frame in 3 channels)"),
    FusionVariant("Mertens weights on one grey channel (contrast x well-exposedness)", weights="grey"),
    FusionVariant("no motion: frame t three times", static=True),
    FusionVariant("no motion + one-channel weights", static=True, weights="grey"),
    FusionVariant("coefficients multiply the clipped 8-bit frame", after_clip=True),
    FusionVariant("highlight as linear light (sRGB-decoded H)", linear_light=True),
    FusionVariant("MTB shifts measured on the frames brought to one exposure", align_normalised=True),
)


def exposed(seq, frames, after_clip: bool = False) -> list[np.ndarray]:
    """The fusion's three 8-bit exposures: frames `frames` of `seq` multiplied by the coefficients
    1/8, 1/5, 1 (paper_camera.FUSION_COEFFICIENTS) on the HDR map H, or (`after_clip`) on the
    frame cut off at 255, then rounded and cut off."""
    from poevp_optics.apps.evaluate.paper_camera import FUSION_COEFFICIENTS

    out = []
    for j, c in zip(frames, FUSION_COEFFICIENTS):
        h = np.asarray(seq.hdr[j], np.float64)
        out.append(np.clip(np.rint((np.clip(h, 0, 255) if after_clip else h) * c), 0, 255).astype(np.uint8))
    return out


def fused(seq, t: int, deghost: bool, v: FusionVariant) -> np.ndarray:
    """The 8-bit fusion of frame t under variant `v` (paper_camera.fusion_captures for v = VARIANTS[0])."""
    import cv2

    from poevp_optics.apps.evaluate.paper_camera import FUSION_COEFFICIENTS, as_light

    s = as_light(seq) if v.linear_light else seq
    frames = (t, t, t) if v.static else (t - 2, t - 1, t)
    imgs = [cv2.cvtColor(x, cv2.COLOR_GRAY2BGR) for x in exposed(s, frames, v.after_clip)]
    if deghost and v.align_normalised:
        mtb = cv2.createAlignMTB()
        norm = [np.clip(np.rint(i[..., 0] / c), 0, 255).astype(np.uint8) for i, c in zip(imgs, FUSION_COEFFICIENTS)]
        imgs = [mtb.shiftMat(i, mtb.calculateShift(norm[-1], n)) for i, n in zip(imgs, norm)]
    elif deghost:
        cv2.createAlignMTB().process(imgs, imgs)      # MTB alignment takes 3-channel frames
    if v.weights == "grey":
        imgs = [np.ascontiguousarray(i[..., 0]) for i in imgs]
    out = cv2.createMergeMertens().process(imgs)
    if out.ndim == 3:
        out = cv2.cvtColor(np.clip(out * 255.0, 0, 255).astype(np.float32), cv2.COLOR_BGR2GRAY)
    else:
        out = np.clip(out * 255.0, 0, 255)
    return np.rint(out).astype(np.uint8)


def mertens_deviation(seq) -> tuple[float, float]:
    """(largest, median) |Mertens fusion of the grey frame in 3 channels - the plain mean of the
    three exposures| and the same against the one-channel fusion, code values, over the scored
    frames of `seq`: what the saturation weight (0 on a grey pixel up to float rounding) does."""
    from poevp_optics.apps.evaluate.paper_camera import INIT_FRAMES

    d_mean, d_grey = [], []
    for t in range(INIT_FRAMES, len(seq.hdr)):
        f = fused(seq, t, False, VARIANTS[0]).astype(np.float64)
        g = fused(seq, t, False, VARIANTS[1]).astype(np.float64)
        mean = np.mean(np.asarray(exposed(seq, (t - 2, t - 1, t)), np.float64), axis=0)
        d_mean.append(np.abs(f - mean).ravel())
        d_grey.append(np.abs(f - g).ravel())
    dm, dg = np.concatenate(d_mean), np.concatenate(d_grey)
    return float(dm.max()), float(np.median(dm)), float(dg.max()), float(np.median(dg))


def mtb_shifts_px(seq) -> tuple[float, float]:
    """Largest shift (px, the longer axis) OpenCV's MTB alignment (Ward 2003, as the
    artifact-reduced fusion runs it) finds between the 1/8 or 1/5 exposure and the full one, over
    the scored frames of `seq`: (frame t three times, where the true shift is 0; consecutive frames)."""
    import cv2

    from poevp_optics.apps.evaluate.paper_camera import INIT_FRAMES

    mtb, worst = cv2.createAlignMTB(), [0.0, 0.0]
    for t in range(INIT_FRAMES, len(seq.hdr)):
        for k, frames in enumerate(((t, t, t), (t - 2, t - 1, t))):
            x = exposed(seq, frames)
            for i in x[:-1]:
                worst[k] = max(worst[k], float(np.abs(mtb.calculateShift(x[-1], i)).max()))
    return worst[0], worst[1]


def plate_speed_px(seq) -> float:
    """Median shift (px per frame) of the plate box's centre between consecutive frames of `seq`."""
    c = {t: ((b[1] + b[3]) / 2.0, (b[0] + b[2]) / 2.0) for t, b in seq.boxes.items()}
    d = [float(np.hypot(c[t][0] - c[t - 1][0], c[t][1] - c[t - 1][1])) for t in sorted(c) if t - 1 in c]
    return float(np.median(d)) if d else 0.0


def fusion_attribution(reader: Reader, seqs: dict, log=print) -> tuple:
    """Rows (factor = the variant's name) of both fusions under every variant; returns
    mertens_deviation of the first E's sequence."""
    from poevp_optics.apps.evaluate.paper_camera import INIT_FRAMES

    dev = mertens_deviation(next(iter(seqs.values()))) if seqs else None
    for e, seq in seqs.items():
        for v in VARIANTS:
            for name, dg in (("fusion_classic", False), ("fusion_deghost", True)):
                for t in range(INIT_FRAMES, len(seq.hdr)):
                    if t in seq.boxes and seq.texts.get(t):
                        reader.read(fused(seq, t, dg, v), seq.boxes[t], seq.texts[t], scene="ldr_highlight_demo",
                                    camera="paper camera", condition=f"E = {e:g}", method=name, frame=t,
                                    factor=v.name)
        log(f"recognition: fusion attribution, E = {e:g} done")
    return dev


# ----------------------------------------------------------------------------------------------
# highbeam_plate and the road scenes (physical camera)


def highbeam(reader: Reader, cfg: Config, log=print) -> None:
    """Lateral sequences of `poevp evaluate` (its renders, cached by content) at each speed and E."""
    from poevp_optics.apps.evaluate.evaluate import EvalConfig, run_evaluation

    ecfg = EvalConfig(texts=cfg.texts, speeds_px=cfg.speeds_px, e_levels=cfg.highbeam_e, e_sweep=cfg.highbeam_e,
                      e_speed_px=cfg.speeds_px[0], kinds=("lateral",), motion_speed_px=cfg.speeds_px[0],
                      motion_e=cfg.highbeam_e[0], predictors=cfg.predictors, frames=cfg.highbeam_frames,
                      overrides=cfg.overrides)
    kept = {}          # (text, condition, method, frame) -> (image, box)

    def cond(e, v):
        return f"E = {float(e):g}, {float(v):g} px/frame"

    def keep(seq, e, images, boxes):
        for m, frames in images.items():
            for t, img in frames.items():
                if boxes.get(t) is not None:
                    kept[(seq.text, cond(e, seq.speed_px), m, t)] = (img, boxes[t])

    for r in run_evaluation(ecfg, log=log, keep=keep):
        row = {"scene": "highbeam_plate", "camera": "physical camera", "condition": cond(r["E"], r["speed_px"]),
               "factor": "", "method": r["method"], "frame": int(r["frame"]), "text": r["text"],
               "alpr_ok": bool(r["alpr_ok"]), "rec_ok": bool(r["rec_ok"]), "alpr_text": r["alpr_text"],
               "rec_text": r["rec_text"], "detections": int(r["detections"]),
               "plate_clipped": round(float(r["plate_clipped"]), 4), "plate_p90": float(r["plate_p90"])}
        reader.rows.append(row)
        key = ("highbeam_plate", row["camera"], row["condition"], row["method"])
        img = kept.get((row["text"], row["condition"], row["method"], row["frame"]))
        if img is not None and is_poevp(row["method"]) and row["rec_ok"] and not row["alpr_ok"] \
                and key not in reader.examples:
            reader.examples[key] = (img[0], img[1], row)
    show = cond(min(cfg.highbeam_e), max(cfg.speeds_px))
    rows = [r for r in reader.rows if r["scene"] == "highbeam_plate" and r["condition"] == show
            and r["text"] == cfg.texts[0]]
    frames = sorted({r["frame"] for r in rows if r["method"] == "fusion_classic"} or {r["frame"] for r in rows})
    if frames:
        t = frames[len(frames) // 2]
        for r in rows:
            img = kept.get((r["text"], show, r["method"], t))
            if r["frame"] == t and img is not None:
                reader.showcase[r["method"]] = (img[0], img[1], r, f"highbeam_plate, {show}, frame {t}, plate {r['text']}")


def road_scene(reader: Reader, cfg: Config, scene: str, log=print) -> None:
    """The road scene's own motion at each beam gain, at its camera scale (cfg.road), every method."""
    from benchmarks.plate_band import beam_overrides
    from poevp_optics.scene.load import load_scene
    from poevp_optics.scene.scale import scaled_resolution, scaling_for

    base = load_scene(SCENES_DIR / scene, [])
    scale, gains = cfg.road[scene]
    sc = scaling_for(base, scaled_resolution(base.render.resolution, scale), f"--scale {scale:.4g}")
    text = cfg.texts[0]
    for gain in gains:
        t0 = time.perf_counter()
        ov = [*sc.sets, f"timing.frames={cfg.road_frames}", f'{ROAD_TEXT_KEYS[scene]}="{text}"',
              *beam_overrides(str(SCENES_DIR / scene), gain), *cfg.overrides]
        spec, ex, made = cached_render(str(SCENES_DIR / scene), ov, cfg.cache, cfg.fresh)
        reader.renders[f"{scene}, beams x{gain:g}"] = made
        runner = make_runner(reader, SCENES_DIR / scene, spec, cfg.predictors, loop_mode=spec.loop.mode)
        images, _ = runner.method_images(ex)
        boxes = {e.index: runner.cam.box_to_sensor(e.roi) if e.roi else None for e in ex}
        dist = [e for e in ex if e.roi]
        reader.read_methods(images, boxes, {e.index: text for e in ex}, spec.loop.init_frames, scene=scene,
                            camera="physical camera", condition=f"beams x{gain:g}, {spec.timing.frames} frames "
                            f"at {spec.timing.fps:g} fps, {spec.render.resolution[0]}x{spec.render.resolution[1]}",
                            factor="")
        log(f"recognition: {scene}, beams x{gain:g} ({len(dist)} frames with the plate in view, "
            f"{time.perf_counter() - t0:.0f} s)")


# ----------------------------------------------------------------------------------------------
# The page (pure: rows in, Markdown out)


def _cells(rows, key):
    g = defaultdict(list)
    for r in rows:
        g[key(r)].append(r)
    return g


def rate(rows, what: str) -> float:
    return 100.0 * sum(r[what] for r in rows) / len(rows) if rows else float("nan")


def miss_cause(r: dict) -> str:
    """Why full ALPR missed a frame that recognition on the plate box read (`r`'s texts)."""
    from poevp_optics.analysis.recognition import normalise

    a, want = normalise(r["alpr_text"]), normalise(r["text"])
    if not a:
        return "no text detected over the plate" if r["detections"] == 0 else \
            "text detected elsewhere in the frame, none over the plate"
    if len(a) < len(want) and a in want:
        return "the detector's box covers part of the plate (characters cut off)"
    if want in a:
        return "the detector's box takes in text or edges beside the plate"
    if len(a) == len(want):
        return "characters misread in the whole-frame pass"
    return "a different text over the plate"


def confusions(rows) -> Counter:
    """(label char, read char) -> count over same-length misreads (both readings)."""
    from poevp_optics.analysis.recognition import normalise

    c = Counter()
    for r in rows:
        want = normalise(r["text"])
        for key in ("alpr_text", "rec_text"):
            got = normalise(r[key])
            if len(got) == len(want) and got != want:
                c.update((w, g) for w, g in zip(want, got) if w != g)
    return c


def paper_value(r_method: str, scene: str, camera: str) -> str:
    if scene != "ldr_highlight_demo":
        return ""
    if r_method in PAPER_TABLE2:
        return f"{PAPER_TABLE2[r_method]:.2f} %"
    if is_poevp(r_method):
        return f"{PAPER_TABLE2['poevp']:.2f} % (DMVFN)"
    return ""


def main_table(rows) -> list[str]:
    out = []
    order = []
    for r in rows:
        k = (r["scene"], r["camera"])
        if k not in order:
            order.append(k)
    for scene, camera in order:
        sel = [r for r in rows if (r["scene"], r["camera"]) == (scene, camera)]
        conds = list(dict.fromkeys(r["condition"] for r in sel))
        methods = list(dict.fromkeys(r["method"] for r in sel))
        body = []
        for c in conds:
            for m in methods:
                rr = [r for r in sel if r["condition"] == c and r["method"] == m]
                if rr:
                    body.append([c, m, wilson_cell(sum(r["alpr_ok"] for r in rr), len(rr)),
                                 wilson_cell(sum(r["rec_ok"] for r in rr), len(rr)), ""])
        if len(conds) > 1:
            for m in methods:
                rr = [r for r in sel if r["method"] == m]
                body.append(["**pooled**", m, wilson_cell(sum(r["alpr_ok"] for r in rr), len(rr)),
                             wilson_cell(sum(r["rec_ok"] for r in rr), len(rr)), paper_value(m, scene, camera)])
        else:
            for b in body:
                b[4] = paper_value(b[1], scene, camera)
        texts = ", ".join(f"`{t}`" for t in dict.fromkeys(r["text"] for r in sel))
        out += [f"### {scene}, {camera}", "", f"Plate text {texts}.", "",
                markdown_table(["condition", "method", "full ALPR", "recognition only", "paper (Table 2)"], body), ""]
    return out


def answer(rows) -> list[str]:
    """The headline: per scene and camera, pooled full ALPR of LDR, the better fusion, the best
    POE-VP predictor and the oracle (all from the rows)."""
    out = []
    phys = [r for r in rows if r["camera"] == "physical camera"]
    if phys:
        by = _cells(phys, lambda r: r["method"])
        scenes = ", ".join(dict.fromkeys(r["scene"] for r in phys))
        out.append(f"- **The physical camera, every scene and condition pooled** ({scenes}; full ALPR): " + "; ".join(
            f"{m} {wilson_cell(sum(r['alpr_ok'] for r in rr), len(rr))}" for m, rr in by.items()) + ".")
    for (scene, camera), sel in _cells(rows, lambda r: (r["scene"], r["camera"])).items():
        by = _cells(sel, lambda r: r["method"])

        def fmt(m):
            rr = by[m]
            return f"{m} {wilson_cell(sum(r['alpr_ok'] for r in rr), len(rr))}"

        fus = [m for m in ("fusion_classic", "fusion_deghost") if m in by]
        causal = [m for m in by if is_poevp(m) and m != "oracle"]
        parts = [fmt("ldr")] if "ldr" in by else []
        if fus:
            parts.append("best fusion " + fmt(max(fus, key=lambda m: rate(by[m], "alpr_ok"))))
        if causal:
            parts.append("best predictor " + fmt(max(causal, key=lambda m: rate(by[m], "alpr_ok"))))
        if "oracle" in by:
            parts.append(fmt("oracle"))
        extra = ""
        if scene == "ldr_highlight_demo":
            extra = (f" (paper: fusions {PAPER_TABLE2['fusion_classic']:.2f} / {PAPER_TABLE2['fusion_deghost']:.2f} %, "
                     f"POE-VP {PAPER_TABLE2['poevp']:.2f} %)")
        out.append(f"- **{scene}, {camera}** (full ALPR, pooled over its conditions): " + "; ".join(parts) + extra)
    return out


def attribution_section(rows, dev: tuple | None, speed_px: float | None = None, shape=None,
                        mtb: tuple | None = None) -> list[str]:
    att = [r for r in rows if r.get("factor")]
    if not att:
        return []
    factors = list(dict.fromkeys(r["factor"] for r in att))
    conds = list(dict.fromkeys(r["condition"] for r in att))
    body, rates = [], {}
    for f in factors:
        row = [f]
        for m in ("fusion_classic", "fusion_deghost"):
            rr = [r for r in att if r["factor"] == f and r["method"] == m]
            rates[(f, m)] = rate(rr, "alpr_ok")
            per_e = " / ".join(f"{100 * np.mean([r['alpr_ok'] for r in rr if r['condition'] == c]):.0f}"
                               for c in conds if any(r["condition"] == c for r in rr))
            row += [wilson_cell(sum(r["alpr_ok"] for r in rr), len(rr)), per_e,
                    wilson_cell(sum(r["rec_ok"] for r in rr), len(rr))]
        body.append(row)
    base = factors[0]
    lines = ["## The fusions attributed", "",
             "The paper's fusion baseline (Sec. 6): three consecutive frames multiplied by the global exposure "
             "coefficients 1/8, 1/5 and 1, merged by Mertens exposure fusion (the artifact-reduced variant after "
             "alignment), in the paper's camera on the demo sequence. Each row changes one factor from the first "
             f"row; per-E columns are full ALPR % at {', '.join(conds)}. Paper: classical "
             f"{PAPER_TABLE2['fusion_classic']:.2f} %, artifact-reduced {PAPER_TABLE2['fusion_deghost']:.2f} %.", "",
             markdown_table(["variant", "classical: full ALPR", "per E (%)", "classical: recognition only",
                             "artifact-reduced: full ALPR", "per E (%)", "artifact-reduced: recognition only"], body), ""]
    if speed_px is not None:
        size = f" at {shape[0]}x{shape[1]}" if shape else ""
        lines.append(f"- **Motion.** The demo's plate moves {speed_px:.0f} px a frame{size} (its boxes), so in "
                     f"the fused triple the darkest exposure (1/8, frame t-2) shows it about {2 * speed_px:.0f} px "
                     f"behind where frame t has it; the variants of one frame three times remove that motion.")
    if dev is not None:
        lines.append(f"- **Fusion weights.** Mertens' weight is contrast x colour saturation x well-exposedness. "
                     f"A grey frame replicated into three channels has zero saturation up to float rounding, so its "
                     f"weights are set by rounding noise: measured on the first E's frames, that fusion differs from "
                     f"the plain mean of the three exposures by up to {dev[0]:.0f} code values (median "
                     f"{dev[1]:.0f}) and from the fusion of the one grey channel (contrast x well-exposedness, no "
                     f"saturation term) by up to {dev[2]:.0f} (median {dev[3]:.0f}).")
    static = VARIANTS[2].name
    if mtb is not None and static in factors:
        lines.append(f"- **Alignment.** The artifact-reduced fusion aligns the three exposures by OpenCV's MTB "
                     f"(median threshold bitmaps, Ward 2003) before fusing. At 1/8 and 1/5 of a night frame most "
                     f"pixels are near black, the median bitmap is mostly noise, and MTB shifts exposures of one "
                     f"and the same frame by up to {mtb[0]:.0f} px (its search limit is 63; {mtb[1]:.0f} px on "
                     f"consecutive frames, where the background does not move): with no motion at all it reads "
                     f"{rates[(static, 'fusion_deghost')]:.0f} % where the classical fusion reads "
                     f"{rates[(static, 'fusion_classic')]:.0f} %. MTB is also a global aligner: it cannot undo the "
                     f"plate's own motion against a still background, which the paper's artifact-reduced fusion "
                     f"is named for.")
    for f in factors[1:]:
        d = [f"{m.replace('fusion_', '')} {rates[(f, m)] - rates[(base, m)]:+.0f} points"
             for m in ("fusion_classic", "fusion_deghost")]
        lines.append(f"- {f}: " + ", ".join(d) + ".")
    for m in ("fusion_classic", "fusion_deghost"):
        f = max(factors[1:], key=lambda f: abs(rates[(f, m)] - rates[(base, m)]), default=None)
        if f is not None:
            lines.append(f"- Largest single change for {m}: *{f}*, {rates[(base, m)]:.0f} % -> {rates[(f, m)]:.0f} %.")
    best = {m: min(factors, key=lambda f: abs(rates[(f, m)] - PAPER_TABLE2[m])) for m in ("fusion_classic", "fusion_deghost")}
    for m, f in best.items():
        lines.append(f"- Closest to the paper, {m}: *{f}*, {rates[(f, m)]:.0f} % "
                     f"({rates[(f, m)] - PAPER_TABLE2[m]:+.0f} points from the paper's {PAPER_TABLE2[m]:.2f} %).")
    lines.append("- Not varied here: the paper's own test videos (many plates, its own speeds) and its ALPR "
                 "network (YOLOv5 + CRNN) against one demo plate and PP-OCRv4; the recognition-only columns "
                 "bound what a better detector could add.")
    return lines + [""]


def gap_section(rows, examples: dict, fig_name: str | None) -> list[str]:
    main = [r for r in rows if not r.get("factor") and is_poevp(r["method"])]
    body, panels = [], []
    for key, rr in _cells(main, lambda r: (r["scene"], r["camera"], r["condition"], r["method"])).items():
        a, c = rate(rr, "alpr_ok"), rate(rr, "rec_ok")
        if c - a <= GAP_POINTS:
            continue
        causes = Counter(miss_cause(r) for r in rr if r["rec_ok"] and not r["alpr_ok"])
        ex = examples.get(key)
        panel = ""
        if ex is not None:
            panels.append(key)
            panel = f"panel {len(panels)}: frame {ex[2]['frame']}, ALPR `{ex[2]['alpr_text'] or '-'}`"
        body.append([" / ".join(key), f"{a:.0f} %", f"{c:.0f} %",
                     "; ".join(f"{n} x {k}" for k, n in causes.most_common()), panel])
    lines = ["## Full ALPR against recognition only", "",
             f"Every POE-VP row whose recognition-only rate exceeds its full-ALPR rate by more than "
             f"{GAP_POINTS:g} points, with the causes of the frames the box reads and the whole frame does "
             "not (from the whole-frame pass's own text over the plate)."]
    if not body:
        return lines + ["", "No POE-VP row has such a gap.", ""]
    lines += ["", markdown_table(["scene / camera / condition / method", "full ALPR", "recognition only",
                                  "causes (frames)", "example"], body), ""]
    if fig_name:
        lines += [f"![ALPR misses that recognition only reads]({fig_name})", ""]
    return lines


def zero_read_section(rows) -> list[str]:
    """Per scene, camera and condition where no POE-VP frame reads (full ALPR): why, in the words
    of `poevp evaluate`'s report (eval_report.zero_read_reason: clipped, dark, or not detected)."""
    from poevp_optics.apps.evaluate.eval_report import zero_read_reason

    main = [r for r in rows if not r.get("factor")]
    lines = []
    for key, rr in _cells(main, lambda r: (r["scene"], r["camera"], r["condition"])).items():
        why = zero_read_reason(rr)
        if why:
            lines.append(f"- **{' / '.join(key)}**: {why}")
    if not lines:
        return []
    return ["## Where no POE-VP frame reads", "", *lines, ""]


def confusion_section(rows) -> list[str]:
    c = confusions([r for r in rows if not r.get("factor")])
    pair = [k for k in c if any(set(k) == set(p) for p in CONFUSABLE)]
    other = [k for k, _ in c.most_common() if k not in pair][:CONFUSION_ROWS]
    body = [[f"`{w}`", f"`{g}`", c[(w, g)], "yes" if (w, g) in pair else ""] for w, g in [*pair, *other]]
    lines = ["## Character confusions", "",
             "Same-length misreads (both readings, every row), character by character. Texts are upper-cased and "
             "stripped to A-Z and 0-9, so `0` (zero) and `O` (letter), `1` and `I`, `8` and `B` are different "
             f"characters and a plate with one of them swapped is not read. The confusable pairs first, then the "
             f"{CONFUSION_ROWS} most frequent others."]
    if not body:
        return lines + ["", "No same-length misread.", ""]
    return lines + ["", markdown_table(["plate", "read as", "count", "0/O, 1/I or 8/B"], body), ""]


def page(result: dict) -> str:
    """The results page from a run's rows and settings (no OCR, no rendering)."""
    rows = result["rows"]
    main = [r for r in rows if not r.get("factor")]
    head = ["# Plate recognition: LDR, exposure fusion and POE-VP", "",
            f"Run {result['date']} ({result['label']} settings), `{result['command']}`, "
            f"{result['seconds'] / 60:.0f} min on {result['machine']}."
            + (f" Road scenes at camera scale {result['road_scale']} (of the scene's mirrors; the resolution is "
               "in each condition)." if result.get("road_scale", "-") != "-" else "") + " Cells: reads/frames = % [Wilson 95 %]; full ALPR = PP-OCRv4 detection + "
            "recognition on the whole 8-bit frame, every character (paper Eq. 4); recognition only = the "
            "recogniser on the known plate box.", ""]
    if result.get("renders"):
        head += ["Road-scene renders (kept under a key of everything the render depends on, so a rerun repeats "
                 "only the camera, the loop and the OCR): " + "; ".join(f"{k} rendered {v}" for k, v in result["renders"].items()) + ".", ""]
    if result["label"] != "full":
        head += [f"**These are the {result['label']} settings (a development run): fewer conditions, methods "
                 "and frames than the full page.**", ""]
    lines = head + ["## The answer", "", *answer(main), ""]
    lines += ["![Plate crops per method with what full ALPR read](recognition_examples.png)", ""] \
        if result.get("examples_png") else []
    lines += ["## Every scene, condition and method", "", *main_table(main)]
    lines += attribution_section(rows, result.get("mertens_dev"), result.get("demo_speed_px"),
                                 result.get("demo_shape"), result.get("mtb_shifts"))
    lines += gap_section(rows, result.get("examples", {}), "recognition_gaps.png" if result.get("gaps_png") else None)
    lines += zero_read_section(rows)
    lines += confusion_section(rows)
    lines += ["## How it was measured", "", result.get("protocol", ""), ""]
    return "\n".join(lines).rstrip() + "\n"


# ----------------------------------------------------------------------------------------------
# Figures and files


def _crop(img, box, grow: float = 0.8):
    y0, x0, y1, x1 = box
    h, w = y1 - y0, x1 - x0
    yy0, yy1 = max(0, int(y0 - 1.5 * h)), min(img.shape[0], int(y1 + 1.5 * h))
    xx0, xx1 = max(0, int(x0 - grow * w)), min(img.shape[1], int(x1 + grow * w))
    return img[yy0:yy1, xx0:xx1], (y0 - yy0, x0 - xx0, y1 - yy0, x1 - xx0)


def examples_figure(path: Path, showcase: dict) -> None:
    from matplotlib.patches import Rectangle

    from benchmarks.common import save_figure
    from poevp_optics.core.runtime import pyplot

    plt = pyplot()
    items = list(showcase.items())
    fig, axes = plt.subplots(1, len(items), figsize=(2.3 * len(items), 2.0), squeeze=False)
    for ax, (m, (img, box, row, where)) in zip(axes[0], items):
        c, b = _crop(img, box)
        ax.imshow(c, cmap="gray", vmin=0, vmax=255)
        ax.add_patch(Rectangle((b[1] - 0.5, b[0] - 0.5), b[3] - b[1], b[2] - b[0], fill=False, ec="tab:red", lw=0.6))
        got = (row or {}).get("alpr_text", "") or "-"
        ok = (row or {}).get("alpr_ok")
        ax.set_title(f"{m}\nALPR: {got} {'(read)' if ok else ''}", fontsize=7)
        ax.axis("off")
    fig.suptitle(items[0][1][3] if items else "", fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def gaps_figure(path: Path, examples: dict, keys: list) -> None:
    from matplotlib.patches import Rectangle

    from benchmarks.common import save_figure
    from poevp_optics.core.runtime import pyplot

    plt = pyplot()
    n = len(keys)
    cols = min(n, 3)
    rws = (n + cols - 1) // cols
    fig, axes = plt.subplots(rws, cols, figsize=(3.4 * cols, 2.6 * rws), squeeze=False)
    for a in axes.ravel():
        a.axis("off")
    for i, key in enumerate(keys):
        img, box, row = examples[key]
        c, b = _crop(img, box, grow=1.5)
        ax = axes.ravel()[i]
        ax.imshow(c, cmap="gray", vmin=0, vmax=255)
        ax.add_patch(Rectangle((b[1] - 0.5, b[0] - 0.5), b[3] - b[1], b[2] - b[0], fill=False, ec="tab:red", lw=0.6))
        ax.set_title(f"{i + 1}: {key[0]}, {key[1]}, {key[2]}, {key[3]}\nALPR '{row['alpr_text'] or '-'}', box "
                     f"'{row['rec_text']}'\n{miss_cause(row)}", fontsize=6)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def gap_keys(rows, examples: dict) -> list:
    main = [r for r in rows if not r.get("factor") and is_poevp(r["method"])]
    out = []
    for key, rr in _cells(main, lambda r: (r["scene"], r["camera"], r["condition"], r["method"])).items():
        if rate(rr, "rec_ok") - rate(rr, "alpr_ok") > GAP_POINTS and key in examples:
            out.append(key)
    return out


def write_csv(path: Path, rows: list[dict]) -> None:
    cols = ["scene", "camera", "condition", "factor", "method", "frame", "text", "alpr_ok", "rec_ok", "alpr_text",
            "rec_text", "detections", "plate_clipped", "plate_p90"]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, extrasaction="ignore")
    w.writeheader()
    w.writerows(rows)
    save_text(path, buf.getvalue())


PROTOCOL = __doc__.split("Scenes and conditions:", 1)[1].split("Writes recognition.md", 1)[0].strip()


def run_sections(cfg: Config, log=print) -> dict:
    """Every section of cfg.sections in one process, in SECTIONS order: rows, example frames,
    showcase, road render times, the fusion-weight deviation and the demo plate's speed."""
    from poevp_optics.core import runtime

    runtime.set_threads(2)
    reader = Reader(cache={} if cfg.fresh else load_ocr_cache(cfg.cache))
    seqs, dev = {}, None
    if "paper_camera" in cfg.sections or "fusion_attribution" in cfg.sections:
        seqs = paper_protocol(reader, cfg, "paper", log)
        if "paper_camera" not in cfg.sections:
            reader.rows = [r for r in reader.rows if r.get("factor")]
    mtb = None
    if "fusion_attribution" in cfg.sections:
        dev = fusion_attribution(reader, seqs, log)
        mtb = tuple(max(v) for v in zip(*(mtb_shifts_px(q) for q in seqs.values()))) if seqs else None
        save_ocr_cache(reader.cache, cfg.cache)
    if "physical_camera" in cfg.sections:
        paper_protocol(reader, cfg, "physical", log)
    if "highbeam_plate" in cfg.sections:
        highbeam(reader, cfg, log)
        save_ocr_cache(reader.cache, cfg.cache)
    for scene in ROAD_TEXT_KEYS:
        if scene in cfg.sections:
            road_scene(reader, cfg, scene, log)
            save_ocr_cache(reader.cache, cfg.cache)
    save_ocr_cache(reader.cache, cfg.cache)
    first = next(iter(seqs.values()), None)
    return {"rows": reader.rows, "examples": reader.examples, "showcase": reader.showcase, "renders": reader.renders,
            "mertens_dev": dev, "mtb_shifts": mtb, "demo_speed_px": plate_speed_px(first) if first else None,
            "demo_shape": tuple(first.hdr[0].shape) if first else None}


#: How `--jobs` splits the sections among processes, the longest first (the fusion attribution
#: needs the paper camera's sequences, so they share one); rows come back in SECTIONS order.
JOB_GROUPS = (("night_road",), ("wet_night_road",), ("fog_highway",), ("highbeam_plate",),
              ("paper_camera", "fusion_attribution"), ("physical_camera",))


def _job(cfg: Config) -> dict:
    return run_sections(cfg, log=lambda *a: print(*a, flush=True))


def run(cfg: Config, jobs: int = 1, log=print) -> dict:
    """All sections: in this process (jobs = 1) or spread over `jobs` processes (each reads the OCR
    cache and merges its readings back); rows come back in SECTIONS order."""
    t0 = time.perf_counter()
    if jobs <= 1:
        res = run_sections(cfg, log)
    else:
        import concurrent.futures as cf
        import multiprocessing as mp

        groups = [tuple(s for s in g if s in cfg.sections) for g in JOB_GROUPS]
        groups = [g for g in groups if g]
        with cf.ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("spawn")) as pool:
            done = dict(zip(groups, pool.map(_job, [dataclasses.replace(cfg, sections=g) for g in groups])))
        parts = [done[g] for g in sorted(groups, key=lambda g: SECTIONS.index(g[0]))]
        res = {"rows": [], "examples": {}, "showcase": {}, "renders": {}, "mertens_dev": None, "mtb_shifts": None,
               "demo_speed_px": None, "demo_shape": None}
        for part in parts:
            res["rows"] += part["rows"]
            for k in ("examples", "showcase", "renders"):
                res[k].update(part[k])
            for k in ("mertens_dev", "mtb_shifts", "demo_speed_px", "demo_shape"):
                res[k] = res[k] if part[k] is None else part[k]
    return {**res, "seconds": time.perf_counter() - t0}


def main(argv=None):
    import sys

    from poevp_optics.core import runtime
    from poevp_optics.scene.scale import scale_text

    ap = argparse.ArgumentParser(prog="python -m benchmarks.recognition", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="development size (one E, flow and oracle, one text, short "
                    "road scenes at 1/6 scale): a few minutes")
    ap.add_argument("--sections", help=f"comma-separated subset of {','.join(SECTIONS)} (default all)")
    ap.add_argument("--fresh", action="store_true", help="render and read everything again (by default renders "
                    "and OCR readings are reused by content from the cache folder)")
    ap.add_argument("--jobs", type=int, default=1, help="processes to spread the sections over (default 1)")
    ap.add_argument("--cache", type=Path, default=CACHE, help=f"the cache folder (default {CACHE.relative_to(ROOT)})")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="set a scene key in every section, after the section's own, TOML value syntax "
                         "(repeatable): mask.envelope=\"predictor_error\"")
    add_results_flag(ap)
    a = ap.parse_args(argv)
    cfg = dataclasses.replace(QUICK if a.quick else FULL, fresh=a.fresh, cache=a.cache, overrides=tuple(a.overrides))
    if a.sections:
        secs = tuple(s.strip() for s in a.sections.split(",") if s.strip())
        bad = [s for s in secs if s not in SECTIONS]
        if bad:
            ap.exit(2, f"benchmarks.recognition: --sections: unknown {bad}; choose from {', '.join(SECTIONS)}\n")
        cfg = dataclasses.replace(cfg, sections=secs)
    runtime.set_threads(2)
    dest = output_folder(a.results)
    res = run(cfg, a.jobs)
    rows = res["rows"]
    if not rows:
        sys.exit("benchmarks.recognition: no frame was scored")
    if res["showcase"]:
        examples_figure(dest / "recognition_examples.png", res["showcase"])
    keys = gap_keys(rows, res["examples"])
    if keys:
        gaps_figure(dest / "recognition_gaps.png", res["examples"], keys)
    else:
        (dest / "recognition_gaps.png").unlink(missing_ok=True)
    write_csv(dest / "recognition_frames.csv", rows)
    args = list(argv if argv is not None else sys.argv[1:])
    for i, x in reversed(list(enumerate(args))):      # where the cache lives does not change a number
        if x == "--cache":
            del args[i:i + 2]
        elif x.startswith("--cache="):
            del args[i]
    cmd = " ".join([".venv/bin/python -m benchmarks.recognition", *args])
    text = page({**res, "date": datetime.date.today().isoformat(), "label": cfg.label, "command": cmd,
                 "machine": machine_line(), "road_scale": ", ".join(f"{scale_text(v[0])} ({k})" for k, v in cfg.road.items()
                                                      if k in cfg.sections) or "-",
                 "examples_png": bool(res["showcase"]), "gaps_png": bool(keys), "protocol": PROTOCOL})
    save_text(dest / "recognition.md", text)
    print(text)


if __name__ == "__main__":
    main()
