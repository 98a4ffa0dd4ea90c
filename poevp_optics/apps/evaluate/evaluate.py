"""`poevp evaluate SCENE`: recognising highlighted moving plates, over plate speed, over-exposure E
and motion kind, with every predictor, exposure fusion and the plain LDR camera.

Test set: the scene's plate carrying each test text along each motion (eval_sequences.py: lateral
at 2 ... 48 px/frame, approaching, receding, swerve, sudden reversal), rendered physically once per
sequence and cached by content. Highlight strength as the paper's over-exposure rate E (Sec. 4A:
H = O (E G + 1)): radiance is linear in the lights' intensity, so each sequence is scaled until the
plate's peak reaches `peak_gain(E)` x the LDR saturation level (here the scene's own beams are the
highlight, not an added Gaussian). The paper forms Eq. 3 on stored 8-bit (display-encoded) values,
"pixel values ... beyond 255" (Sec. 4.A), so its E = 9 puts the peak at 255 x 10 in code value;
reading `display` (default, E_READINGS) takes that peak through the sRGB decoding extended above 1
(IEC 61966-2-1, the LDR source's transfer): gain ((E + 1.055) / 1.055)^2.4 = 224x linear radiance at
E = 9, 1.05e4x at E = 49; reading `linear` (this benchmark's earlier one) is E + 1. With `display`,
E means the same in both protocols (apps/evaluate/eval_paper.py sets the source's e_domain = "display").

Methods, one 8-bit image per frame t (frames < loop.init_frames are the loop's white start, not
scored):
  ldr             the DMD all white
  fusion_classic  captures t-2, t-1, t at global exposures 1/8, 1/5, 1 (paper Sec. 6), Mertens
                  fusion (OpenCV `createMergeMertens`; Mertens, Kautz & Van Reeth 2007)
  fusion_deghost  the same after median-threshold-bitmap alignment (OpenCV `createAlignMTB`;
                  Ward 2003)
  hold, flow, dmvfn, ... oracle   POE-VP single shot (control/loop_step.py LoopStep), loop mode
                  `demodulated` by default, the scene's mask law. `open` (paper Fig. 3, --loop-mode
                  open) feeds the predictor clipped LDR frames: under high beams the whole car
                  clips, the plate is invisible inside it, and the exposure_controller's
                  brightness comes from its demand map carried in place (R = 12 px), so every
                  causal predictor reads like `hold` (benchmarks/results/predictor_alignment.md)
Every method sees the same sensor noise (common seeds), so differences are the methods'.
Reading: full ALPR (PP-OCRv4 detection + recognition on the frame) and recognition only (the
plate box), analysis/recognition.py; Eq. 4 accuracy with Wilson 95 % intervals, Eq. 5 plate
entropy, the reversal's lag (analysis/statistics.py). Deep optics (the paper's third baseline)
is out of scope: it needs a learned optical element.
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from poevp_optics.analysis.metrics import crop, entropy_8bit, to_8bit
from poevp_optics.analysis.recognition import alpr_read, correct, read_plate, search_window
from poevp_optics.apps.evaluate.eval_report import BASELINES
from poevp_optics.apps.evaluate.eval_paper import (PROTOCOL_LAWS, is_paper_scene, protocol_controls, protocol_law,
                                                   run_paper)
from poevp_optics.apps.evaluate.eval_sequences import (E_READINGS, KINDS, SequenceSpec, calibrate, eval_overrides,
                                              peak_gain, render_sequences)
from poevp_optics.camera.camera import Camera
from poevp_optics.control.loop_step import LoopSpec, LoopStep
from poevp_optics.control.predictors import PREDICTORS, make_predictor
from poevp_optics.core.exceptions import UserError
from poevp_optics.core.paths import SCENES_DIR
from poevp_optics.core.seeds import ENCODED_STREAM, FUSION_STREAM, LDR_STREAM, capture_seed
from poevp_optics.render.exposures import RenderedExposure
from poevp_optics.scene.load import load_scene

BASE = SCENES_DIR / "highbeam_plate"
#: Test texts: 6 characters, "LL DDDD"; the predictor's training texts (apps/train/training_data.py
#: random_plate_text) are all 7 characters ("LL D" + 4), so no test text was ever trained on.
TEXTS = ("KA 7391", "MH 2046", "TN 0952", "DL 3817")
FUSION_EXPOSURES = (1 / 8, 1 / 5, 1.0)
@dataclass(frozen=True)
class EvalConfig:
    """What one `poevp evaluate` run measures (defaults: the benchmark in benchmarks/results)."""

    scene: Path = BASE
    texts: tuple[str, ...] = TEXTS                                 # two each way: 16 frames a cell
    speeds_px: tuple[float, ...] = (4, 8, 16, 20, 24, 28, 32, 40, 48)   # lateral, px/frame: dense where hold fails
    e_levels: tuple[float, ...] = (9, 49)                          # speed-sweep panels
    e_sweep: tuple[float, ...] = (2, 4, 9, 29, 49)                  # accuracy vs E (display reading: 13x to 1e4x) ...
    e_speed_px: float = 8                                          # ... at this speed
    kinds: tuple[str, ...] = KINDS                                 # motion sweep ...
    motion_speed_px: float = 16                                    # ... at this speed, E:
    motion_e: float = 9
    predictors: tuple[str, ...] = ("hold", "flow", "dmvfn_lite", "track_net", "oracle")
    baselines: tuple[str, ...] = BASELINES
    resolution: tuple[int, int] = (184, 320)
    spp: int = 8
    frames: int = 6
    motion_frames: int = 7
    search: str = "frame"              # ALPR search region: "frame" or "vehicle"
    loop_mode: str = "demodulated"    # the scene's; open (paper Fig. 3) reads like hold (module docstring)
    e_reading: str = "display"         # E -> plate peak (peak_gain): paper's display-value reading
    paper_law: str = ""                # ldr_highlight scenes (the paper's protocol): the mask law; "": the camera's (DEFAULT_LAWS)
    camera: str = "physical"           # ldr_highlight scenes: physical, or the paper's code-value simulation
    paper_effects: tuple[str, ...] = ()  # --camera paper: physical effects added (apps/evaluate/paper_camera.py)
    overrides: tuple[str, ...] = ()    # --set KEY=VALUE: scene keys set after the protocol's own (e.g. mask.envelope)
    quick: bool = False

    @property
    def methods(self) -> tuple[str, ...]:
        return (*self.baselines, *self.predictors)


def quick_config(scene: Path = BASE, texts: tuple[str, ...] = TEXTS[:1]) -> EvalConfig:
    """The CI set: one text, 4 and 40 px/frame at E = 9, lateral + reversal (about a minute): at
    40 px/frame a held mask lags the plate by more than three times its 12-mirror carry radius."""
    return EvalConfig(scene=scene, texts=texts, speeds_px=(4, 40), e_levels=(9,), e_sweep=(9,),
                      e_speed_px=4, kinds=("lateral", "reversal"), motion_speed_px=40, motion_e=9,
                      predictors=("hold", "flow", "oracle"), spp=4, frames=5, motion_frames=6, quick=True)


def check_config(cfg: EvalConfig) -> None:
    """One-line errors naming the flag for a bad configuration."""
    if not cfg.texts or any(not t.strip() for t in cfg.texts):
        raise UserError("evaluate: --texts: need at least one non-empty plate text")
    bad = [k for k in cfg.kinds if k not in KINDS]
    if bad:
        raise UserError(f"evaluate: --kinds: unknown {bad}; choose from {', '.join(KINDS)}")
    bad = [p for p in cfg.predictors if p not in PREDICTORS]
    if bad:
        raise UserError(f"evaluate: --predictors: unknown {bad}; choose from {', '.join(PREDICTORS)}")
    bad = [b for b in cfg.baselines if b not in BASELINES]
    if bad:
        raise UserError(f"evaluate: --baselines: unknown {bad}; choose from {', '.join(BASELINES)}")
    if any(s <= 0 for s in (*cfg.speeds_px, cfg.e_speed_px, cfg.motion_speed_px)):
        raise UserError("evaluate: --speeds: speeds must be > 0 px/frame")
    if any(e < 0 for e in (*cfg.e_levels, *cfg.e_sweep, cfg.motion_e)):
        raise UserError("evaluate: --E: over-exposure rates must be >= 0")
    if cfg.search not in ("frame", "vehicle"):
        raise UserError(f"evaluate: --search: {cfg.search!r}; choose frame or vehicle")
    if cfg.e_reading not in E_READINGS:
        raise UserError(f"evaluate: --e-reading: {cfg.e_reading!r}; choose from {', '.join(E_READINGS)}")
    if cfg.paper_law and cfg.paper_law not in PROTOCOL_LAWS:
        raise UserError(f"evaluate: --paper-law: {cfg.paper_law!r}; choose from {', '.join(PROTOCOL_LAWS)}")
    from poevp_optics.apps.evaluate.paper_camera import CAMERAS, EFFECTS

    if cfg.camera not in CAMERAS:
        raise UserError(f"evaluate: --camera: {cfg.camera!r}; choose from {', '.join(CAMERAS)}")
    bad = [n for n in cfg.paper_effects if n not in EFFECTS]
    if bad:
        raise UserError(f"evaluate: --paper-effects: unknown {bad}; choose from {', '.join(EFFECTS)}")
    if (cfg.camera == "paper" or cfg.paper_effects) and not is_paper_scene(cfg.scene):
        raise UserError(f"evaluate: --camera paper / --paper-effects: {cfg.scene} is not an ldr_highlight scene "
                        "(the paper's simulation needs its LDR frames)")
    if cfg.paper_effects and cfg.camera != "paper":
        raise UserError("evaluate: --paper-effects: only with --camera paper")
    if cfg.frames < 4 or cfg.motion_frames < 6:
        raise UserError("evaluate: --frames: need >= 4 frames (>= 6 for motion kinds): 2 start the loop")


def plan(cfg: EvalConfig) -> list[tuple[SequenceSpec, tuple[float, ...]]]:
    """(sequence, E levels to run on it): the lateral sweep (+ the E sweep at e_speed_px) and the
    motion kinds at motion_speed_px; directions alternate with the text index."""
    out = []
    for ti, text in enumerate(cfg.texts):
        d = 1 if ti % 2 == 0 else -1
        for v in cfg.speeds_px:
            es = set(cfg.e_levels) | (set(cfg.e_sweep) if v == cfg.e_speed_px else set())
            if v == cfg.motion_speed_px and "lateral" in cfg.kinds:
                es.add(cfg.motion_e)
            out.append((SequenceSpec(text, "lateral", float(v), cfg.frames, d), tuple(sorted(es))))
        if cfg.e_speed_px not in cfg.speeds_px:
            out.append((SequenceSpec(text, "lateral", float(cfg.e_speed_px), cfg.frames, d), tuple(cfg.e_sweep)))
        for kind in cfg.kinds:
            if kind == "lateral" and cfg.motion_speed_px in cfg.speeds_px:
                continue
            n = cfg.motion_frames
            out.append((SequenceSpec(text, kind, float(cfg.motion_speed_px), n, d, change=n // 2),
                        (cfg.motion_e,)))
    return out


def overexposure(cam: Camera, exps) -> float:
    """Peak plate signal over the sequence with the DMD white, in units of saturation."""
    k = cam.electrons_per_radiance() * cam.white_exposure_s(0) / cam.params.saturation_capacity_e
    return max(float(np.max(crop(cam.to_sensor(e.radiance.data), cam.box_to_sensor(e.roi)))) * k for e in exps)


def scaled(exps: list[RenderedExposure], s: float) -> list[RenderedExposure]:
    """The exposures with radiance x s (radiance is linear in the lights' intensity)."""
    out = []
    for e in exps:
        subs = tuple((x.astype(np.float64) * s).astype(np.float32) for x in e.subframes)
        rad = dataclasses.replace(e.radiance, data=(e.radiance.data.astype(np.float64) * s).astype(np.float32))
        out.append(dataclasses.replace(e, subframes=subs, radiance=rad, variance=e.variance.astype(np.float64) * s * s))
    return out


def _fusion(cam, exps, t, deghost: bool, seeds: tuple[int, int]):
    """Mertens fusion of captures t-2, t-1, t at 1/8, 1/5, 1 (seeds: sensor and render seed)."""
    import cv2

    imgs = []
    for j, f in zip((t - 2, t - 1, t), FUSION_EXPOSURES):
        e = exps[j]
        cap = cam.capture([x * np.float32(f) for x in e.subframes], cam.white_mask(), j,
                          capture_seed(seeds[0], seeds[1], j, FUSION_STREAM), times_s=e.subframe_times_s)
        imgs.append(cv2.cvtColor(to_8bit(cap.dn, cam.params.max_dn).astype(np.uint8), cv2.COLOR_GRAY2BGR))
    t0 = time.perf_counter()
    if deghost:
        cv2.createAlignMTB().process(imgs, imgs)
    fused = cv2.createMergeMertens().process(imgs)
    dt = time.perf_counter() - t0
    gray = cv2.cvtColor(np.clip(fused * 255.0, 0, 255).astype(np.float32), cv2.COLOR_BGR2GRAY)
    return np.rint(gray).astype(np.uint8), dt


@dataclass
class Runner:
    """The loaded scene, camera and predictors of one evaluation (built once, used per cell)."""

    cfg: EvalConfig
    spec: object
    cam: Camera
    models: dict = field(default_factory=dict)
    ocr_cache: dict = field(default_factory=dict)

    def method_images(self, ex: list[RenderedExposure]) -> tuple[dict, dict]:
        """{method: {t: 8-bit image}}, {method: seconds per output frame} for one (sequence, E)."""
        spec, cam = self.spec, self.cam
        seeds = (spec.sensor.seed, spec.render.seed)
        init = spec.loop.init_frames
        ldr = [cam.capture(list(e.subframes), cam.white_mask(), e.index,
                           capture_seed(*seeds, e.index, LDR_STREAM), **e.capture_timing()) for e in ex]
        images = {"ldr": {e.index: to_8bit(c.dn, cam.params.max_dn).astype(np.uint8) for e, c in zip(ex, ldr)}}
        secs = {"ldr": [0.0]}
        for deghost, name in ((False, "fusion_classic"), (True, "fusion_deghost")):
            if name in self.cfg.baselines:
                images[name], secs[name] = {}, []
                for t in range(max(2, init), len(ex)):
                    images[name][t], dt = _fusion(cam, ex, t, deghost, seeds)
                    secs[name].append(dt)
        for name in self.cfg.predictors:
            images[name], secs[name] = self._poevp(name, ex, ldr)
        return images, {m: float(np.median(v)) if v else 0.0 for m, v in secs.items()}

    def _poevp(self, name: str, ex, ldr) -> tuple[dict, list]:
        spec, cam = self.spec, self.cam
        pspec = dataclasses.replace(spec.predictor, name=name)
        if name not in self.models and not PREDICTORS[name].needs_truth:
            self.models[name] = make_predictor(name, pspec.weights, pspec.resolution)
        step = LoopStep(cam, spec.resolved.loop.mask, dataclasses.replace(spec.loop, mode=self.cfg.loop_mode), pspec,
                        model=self.models.get(name), attenuator=spec.attenuator)
        out, secs = {}, []
        for e, c in zip(ex, ldr):
            t0 = time.perf_counter()
            dec = step.next_mask(e.index, e.radiance.data)
            dt = time.perf_counter() - t0
            enc = cam.capture(list(e.subframes), dec.levels, e.index,
                              capture_seed(spec.sensor.seed, spec.render.seed, e.index, ENCODED_STREAM),
                              **e.capture_timing(), transmission=dec.transmission,   # the scene's ND, on time
                              exposure=dec.exposure)                                # the frame's T_e and B
            est = flags = None
            if self.cfg.loop_mode == "demodulated" or step.controller is not None:
                # the exposure controller (mask law) reads the demodulated estimate in every mode
                est, flags, _ = cam.reconstruct(enc, e.index)
            step.observe(e.index, c, enc, est, flags)
            out[e.index] = to_8bit(enc.dn, cam.params.max_dn).astype(np.uint8)
            if not dec.init:
                secs.append(dec.predict_seconds if dec.predict_seconds is not None else dt)
        return out, secs

    def read(self, img: np.ndarray, box, label: str) -> dict:
        """Both readings of one frame (cached by image content); a constant plate box (0 bits)
        carries no text and is scored unread without running the OCR."""
        plate = crop(img, box)
        ent = entropy_8bit(plate)
        key = (hashlib.sha1(img.tobytes()).hexdigest(), tuple(box), label)
        if key in self.ocr_cache:
            return self.ocr_cache[key]
        # the plate box's exposure, for the report's why-nothing-reads line: share at 255, 90th percentile
        level = {"plate_clipped": float(np.mean(plate >= 255)) if plate.size else 0.0,
                 "plate_p90": float(np.percentile(plate, 90)) if plate.size else 0.0}
        if ent == 0.0:
            res = {"alpr_text": "", "alpr_ok": False, "alpr_conf": 0.0, "rec_text": "", "rec_ok": False,
                   "rec_conf": 0.0, "entropy": 0.0, "ocr_ms": 0.0, "detections": 0, **level}
        else:
            region = search_window(box, img.shape) if self.cfg.search == "vehicle" else None
            a = alpr_read(img, box, region)
            text, conf, rs = read_plate(img, box)
            res = {"alpr_text": a.text, "alpr_ok": correct(a.text, label), "alpr_conf": a.confidence,
                   "rec_text": text, "rec_ok": correct(text, label), "rec_conf": conf, "entropy": ent,
                   "ocr_ms": (a.seconds + rs) * 1e3, "detections": a.detections, **level}
        self.ocr_cache[key] = res
        return res


def _shift_px(ex) -> float:
    """Median per-frame displacement (px) of the plate box's edges, the measured image speed."""
    d = [max(abs(a.roi[1] - b.roi[1]), abs(a.roi[3] - b.roi[3]), abs(a.roi[0] - b.roi[0]))
         for a, b in zip(ex[1:], ex) if a.roi and b.roi]
    return float(np.median(d)) if d else 0.0


def score_rows(runner: Runner, meta: dict, texts: dict, e_level, images, secs, boxes) -> list[dict]:
    """Rows (one per method and scored frame) of one (sequence, E): `meta` is the sequence's
    columns, texts {t: plate text}, boxes {t: sensor box or None}."""
    rows = []
    for m, frames in images.items():
        if m not in runner.cfg.methods:
            continue
        for t in sorted(frames):
            if t < runner.spec.loop.init_frames or boxes.get(t) is None or not texts.get(t):
                continue
            rows.append({"text": texts[t], **meta, "E": e_level, "method": m, "frame": t,
                         **runner.read(frames[t], boxes[t], texts[t]), "method_ms": secs[m] * 1e3})
    return rows


def evaluate_sequence(runner: Runner, seq: SequenceSpec, e_levels, exps, keep) -> list[dict]:
    """Rows (one per method, E and scored frame) of one sequence; `keep(seq, E, images, boxes)`
    is offered every cell's images (the report keeps a few for figures)."""
    cam = runner.cam
    r0 = overexposure(cam, exps)
    meta = {"kind": seq.kind, "speed_px": seq.speed_px, "direction": seq.direction,
            "change": seq.change if seq.kind == "reversal" else "", "measured_px_per_frame": _shift_px(exps)}
    rows = []
    for e_level in e_levels:
        ex = scaled(exps, peak_gain(e_level, runner.cfg.e_reading) / r0)
        images, secs = runner.method_images(ex)
        boxes = {e.index: cam.box_to_sensor(e.roi) for e in ex}
        keep(seq, e_level, images, boxes)
        rows += score_rows(runner, meta, {e.index: seq.text for e in ex}, e_level, images, secs, boxes)
    return rows


def load_eval_scene(cfg: EvalConfig, text: str, frames: int):
    """The scene under the evaluation's overrides for one text."""
    return load_scene(cfg.scene, [*eval_overrides(cfg.resolution, cfg.spp, frames, text), *cfg.overrides])


def run_evaluation(cfg: EvalConfig, log=print, keep=lambda *a: None) -> list[dict]:
    """Every row of the evaluation (plan, render or load from the cache, run, read)."""
    check_config(cfg)
    jobs = plan(cfg)
    rows, t_start = [], time.perf_counter()
    runner = cal = None
    for text in cfg.texts:
        mine = [(s, es) for s, es in jobs if s.text == text]
        spec = load_eval_scene(cfg, text, max(s.frames for s, _ in mine))
        if runner is None:
            runner = Runner(cfg, spec, Camera.from_params(spec.resolved.camera))
            cal = calibrate(spec, runner.cam.guard_px)
        runner.spec = spec
        exps = render_sequences(spec, [s for s, _ in mine], cal, runner.cam.guard_px, log=log)
        for (seq, es), ex in zip(mine, exps):
            rows += evaluate_sequence(runner, seq, es, ex, keep)
        log(f"poevp evaluate: {text!r} done ({time.perf_counter() - t_start:.0f} s)")
    return rows


@dataclass
class CropKeeper:
    """Keeps plate crops of the first text's lateral sequences (the figures' material):
    {(speed, E): {method: {t: crop}}}, a fixed window around each frame's plate box."""

    cfg: EvalConfig
    crops: dict = field(default_factory=dict)

    def __call__(self, seq: SequenceSpec, e_level, images, boxes) -> None:
        if seq.text != self.cfg.texts[0] or seq.kind != "lateral":
            return
        cell = self.crops.setdefault((seq.speed_px, float(e_level)), {})
        for m, frames in images.items():
            for t, img in frames.items():
                b = boxes.get(t)
                if b is None or t < 2:
                    continue
                cy, cx = (b[0] + b[2]) // 2, (b[1] + b[3]) // 2
                hh, hw = int(1.6 * (b[2] - b[0])), int(0.8 * (b[3] - b[1]))
                pad = np.pad(img, ((hh, hh), (hw, hw)), constant_values=0)
                cell.setdefault(m, {})[t] = pad[cy:cy + 2 * hh, cx:cx + 2 * hw].copy()


def strip_cell(report: dict, cfg: EvalConfig) -> tuple[float, float]:
    """(speed, E) for the frame strip: the first separating speed, else the largest flow/dmvfn
    minus hold gap in the speed sweep."""
    for e, v in report["findings"]["separating_speed_px"].items():
        if v is not None:
            return float(v), float(e)
    cells, best = report["cells"], (-1.0, float(max(cfg.speeds_px)), float(max(cfg.e_levels)))
    for e in cfg.e_levels:
        for v in cfg.speeds_px:
            h = cells.get(f"lateral|{float(v):g}|{float(e):g}|hold")
            others = [cells.get(f"lateral|{float(v):g}|{float(e):g}|{p}") for p in cfg.predictors if p not in ("hold", "oracle")]
            gap = max([c["alpr"]["pct"] for c in others if c] or [0.0]) - (h["alpr"]["pct"] if h else 0.0)
            best = max(best, (gap, float(v), float(e)))
    return best[1], best[2]


def evaluate_paper(out: Path, cfg: EvalConfig, log=print) -> dict:
    """The paper's simulation protocol (apps/evaluate/eval_paper.py) on an ldr_highlight scene, into `out`."""
    from poevp_optics.apps.evaluate.eval_report import write_paper_tables

    check_config(cfg)
    # the report names the law that ran, and the camera's own keys among the scene keys set
    cfg = dataclasses.replace(cfg, paper_law=protocol_law(cfg), overrides=(*protocol_controls(cfg), *cfg.overrides))
    t0 = time.perf_counter()
    rows = run_paper(cfg, Runner, score_rows, _shift_px, log=log)
    if not rows:
        raise UserError(f"evaluate: {cfg.scene}: no frame with a plate box and text to score")
    return write_paper_tables(out, rows, cfg, time.perf_counter() - t0)


def evaluate(out: Path, cfg: EvalConfig | None = None, quick: bool = False, log=print) -> dict:
    """Run the evaluation into `out` (tables, frames.csv, report.json, figures); the report. A scene
    whose source is an LDR sequence with Eq. 3's highlight runs the paper's protocol instead."""
    from poevp_optics.apps.evaluate.eval_plots import accuracy_plots, entropy_examples, strip_plot
    from poevp_optics.apps.evaluate.eval_report import write_tables

    cfg = cfg or (quick_config() if quick else EvalConfig())
    out = Path(out)
    if is_paper_scene(cfg.scene):
        return evaluate_paper(out, cfg, log)
    keeper = CropKeeper(cfg)
    t0 = time.perf_counter()
    rows = run_evaluation(cfg, log=log, keep=keeper)
    if not rows:
        raise UserError(f"evaluate: {cfg.scene}: no frame with the plate in view to score")
    report = write_tables(out, rows, cfg, time.perf_counter() - t0)
    accuracy_plots(out, report["cells"], cfg)
    v, e = strip_cell(report, cfg)
    if (v, e) in keeper.crops:
        strip_plot(out / "strip.png", keeper.crops[(v, e)],
                   f"{cfg.texts[0]}, lateral {v:g} px/frame, E = {e:g} (raw 8-bit captures)")
    ex = keeper.crops.get((float(cfg.e_speed_px), float(max(cfg.e_sweep))))
    if ex:
        t = sorted(next(iter(ex.values())))[len(next(iter(ex.values()))) // 2]
        entropy_examples(out / "examples.png", {m: f[t] for m, f in ex.items() if t in f})
    report["strip"] = {"speed_px": v, "E": e}
    return report
