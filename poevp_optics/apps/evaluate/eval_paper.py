"""`poevp evaluate` on a scene whose `[source] kind = "ldr_highlight"`: the paper's own simulation
protocol (He et al., Photonics Research 12(11), 2524 (2024), Sec. 6 and Fig. 3), so its Table 2
can be compared like for like.

Protocol (paper Sec. 6A): the LDR sequence as it is (its own plate, motion and text: the source's
boxes CSV gives the plate box and text per frame), the artificial highlight of Eq. 3,
H = O (E G + 1), formed on the stored 8-bit values as the paper does (Sec. 4.A: the product
"makes some pixel values of the original LDR frames increase beyond 255"; source e_domain =
"display", then sRGB-decoded), at E = 9, 29, 49 and R = 50 px at 720x1280 (scaled to the frame by
sources/ldr_highlight.py), the mask law of Eq. 2 with (Vs, a, b) = (200, 0.9, 0) ("In the
simulation experiment, the mask coefficients (a, b) are set to (0.9, 0)", Fig. 3 caption; Vs = 200,
Sec. 3): a and b are Eq. 2's light-suppression coefficients. Eq. 2 is garbled in our copy
(control/masks.py), which has three readings. `PAPER_LAW`, the linear reading M = 255 (1 - a)
above Vs (a tenfold dimmer at a = 0.9), is the one that reproduces the paper's Table 2 in the
paper's camera (benchmarks/results/recognition.md, `benchmarks.table2`: oracle 100 %, the paper's POE-VP 94.86 %). The ratio
reading, M = 255 (a Vs / x + b), dims a prediction clipped at 255 by at most a Vs / 255 = 0.71: a
pixel of stored value O stays clipped where 0.71 O (E G + 1) > 255, i.e. at the highlight's centre
any O above 36, 12, 7 at E = 9, 29, 49 (black plate ink is ~45 in the demo), and the exponential
reading sends a clipped prediction to level 0 (only the DMD's leakage and the smoothed mask's edge
pass): both read 0 % with every predictor, the oracle included. Without `paper_law`, the paper's
camera runs `PAPER_LAW` and the physical camera this project's exposure controller
(`DEFAULT_LAWS`) with its envelope and per-frame exposure time (`PHYSICAL_CONTROLS`): in linear light Eq. 3's display-encoded highlight puts the plate 3.1e3x and
1.05e4x over saturation at E = 29 and 49, beyond the linear reading's tenfold dimming.
EvalConfig's `paper_law` picks any of `PROTOCOL_LAWS` (this project's reported as ours).
The scene's mask.smooth_px (the band-limited mask, DESIGN.md) is kept. Loop mode `open` (the
predictor sees unmasked LDR frames, Fig. 3), first two frames white (not scored).
Methods and readings are those of apps/evaluate/evaluate.py (LDR, both fusions, every predictor; full ALPR
and recognition only).

Where ours differs from the paper's pipeline: the highlight map drives this project's camera
(DMD PWM with finite contrast, IMX253 shot and read noise, 12-bit ADC, then the 8-bit image) in
place of the paper's noiseless "Hadamard product, then cut off at 255"; the source anchors the
linear value 1 in absolute units (its `luminance_cd_per_m2`).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from poevp_optics.camera.camera import Camera
from poevp_optics.core.exceptions import UserError
from poevp_optics.render.radiance import open_source
from poevp_optics.scene.load import load_scene

#: Paper Sec. 6A: over-exposure rates E of the test sets, and R (px at 720x1280).
PAPER_E = (9.0, 29.0, 49.0)
PAPER_R_PX = 50.0
#: Paper Sec. 3 (Vs = 200) and Fig. 3 caption ((a, b) = (0.9, 0) in simulation).
PAPER_VS, PAPER_A, PAPER_B = 200.0, 0.9, 0.0
#: Eq. 2's reading that reproduces the paper's Table 2 in the paper's camera (module docstring).
PAPER_LAW = "threshold_linear"
#: Paper Sec. 4.A: Eq. 3 multiplies the stored 8-bit values ("pixel values ... beyond 255").
PAPER_E_DOMAIN = "display"
PAPER_LAWS = ("threshold_ratio", "threshold_exp", "threshold_linear")
#: Laws the protocol accepts: Eq. 2's two readings, and this project's (labelled ours in the report).
PROTOCOL_LAWS = (*PAPER_LAWS, "exposure_controller", "target")
#: The protocol's mask law per camera (evaluate --camera) when none is given: the paper's camera
#: (code values) runs the reading that reproduces the paper, the physical camera the project's
#: best law, the exposure controller (control/exposure_control.py).
DEFAULT_LAWS = {"paper": PAPER_LAW, "physical": "exposure_controller"}
#: Scene keys the physical camera's default law runs with, before any `--set`: the mask envelope
#: sized by the loop's measured miss (about a mirror for the oracle) and the exposure time chosen
#: per frame, which puts the coarse part of 1e3-1e4x over saturation into the shutter and keeps
#: the plate's mirrors in the DMD's fine levels. Measured over E = 9/29/49 (18 frames, full ALPR):
#: the oracle 8 -> 17 reads (docs/physics/closed-loop.md, "Mask envelope").
PHYSICAL_CONTROLS = ('mask.envelope="predictor_error"', "mask.exposure_time_auto=true")
KIND = "paper"


def protocol_law(cfg) -> str:
    """The protocol's mask law of `cfg`: its `paper_law`, else the camera's default (DEFAULT_LAWS)."""
    return getattr(cfg, "paper_law", "") or DEFAULT_LAWS[getattr(cfg, "camera", "physical")]


def camera_controls(camera: str) -> tuple[str, ...]:
    """Scene keys that go with the default law of `camera` ('paper' or 'physical')."""
    return PHYSICAL_CONTROLS if camera == "physical" else ()


def protocol_controls(cfg) -> tuple[str, ...]:
    """Scene keys of the protocol's camera with its default law (camera_controls); none where
    `paper_law` names a law."""
    return () if getattr(cfg, "paper_law", "") else camera_controls(getattr(cfg, "camera", "physical"))


def is_paper_scene(scene: Path) -> bool:
    """True when the scene's radiance is an LDR sequence with Eq. 3's highlight."""
    return load_scene(scene).source.kind == "ldr_highlight"


def paper_overrides(e: float, law: str = PAPER_LAW) -> list[str]:
    """Scene overrides of the paper's protocol at over-exposure rate `e`."""
    return [f"source.e={e!r}", f"source.r_px={PAPER_R_PX!r}", f"source.e_domain={json.dumps(PAPER_E_DOMAIN)}",
            f"mask.law={json.dumps(law)}",
            f"mask.vs={PAPER_VS!r}", f"mask.a={PAPER_A!r}", f"mask.b={PAPER_B!r}", "loop.mode=\"open\""]


def paper_exposures(spec, cam: Camera) -> list:
    """The sequence's exposures (Eq. 3 radiance on the mirror grid, boxes and text from the CSV)."""
    return list(open_source(spec.resolved.render, cam.guard_px).exposures(progress=False))


def predictor_models(runner, spec):
    """name -> the predictor the paper camera's loop runs (None for one that needs the truth),
    each built once and kept in runner.models."""
    from poevp_optics.control.predictors import PREDICTORS, make_predictor

    def model_of(name):
        if PREDICTORS[name].needs_truth:
            return None
        if name not in runner.models:
            runner.models[name] = make_predictor(name, spec.predictor.weights, spec.predictor.resolution)
        return runner.models[name]

    return model_of


def paper_camera_images(runner, spec, cfg):
    """The paper's own simulation (apps/evaluate/paper_camera.py) of one E: images, seconds and frame boxes,
    with the predictors built once in runner.models."""
    from poevp_optics.apps.evaluate import paper_camera as pc
    from poevp_optics.camera.sensor import resolve_sensor

    model_of = predictor_models(runner, spec)
    seq = pc.paper_sequence(spec)
    sensor = resolve_sensor(spec.sensor)
    images, secs = pc.method_images(seq, cfg.methods, spec.resolved.loop.mask, pc.effects_from(cfg.paper_effects), model_of,
                                    contrast_ratio=spec.dmd.contrast_ratio,
                                    saturation_e=sensor.saturation_capacity_e, read_noise_e=sensor.read_noise_e,
                                    seed=spec.sensor.seed)
    boxes = {t: seq.boxes.get(t) for t in range(len(seq.hdr))}
    return images, {m: float(np.median(v)) if v else 0.0 for m, v in secs.items()}, boxes


def run_paper(cfg, runner_cls, score, shift_px, log=print) -> list[dict]:
    """Every row of the paper protocol on cfg.scene: one cell per (E, method), frames from
    loop.init_frames on. `runner_cls(cfg, spec, cam)` builds apps/evaluate/evaluate.py's Runner; `score`
    turns one E's images into rows (evaluate.score_rows); `shift_px` measures the plate's speed;
    the mask law: protocol_law(cfg)."""
    rows, runner, t0 = [], None, time.perf_counter()
    for e in PAPER_E:
        spec = load_scene(cfg.scene, [*paper_overrides(e, protocol_law(cfg)), *getattr(cfg, "overrides", ())])
        cam = Camera.from_params(spec.resolved.camera)
        if runner is None:
            runner = runner_cls(dataclasses.replace(cfg, loop_mode="open"), spec, cam)
        runner.spec, runner.cam = spec, cam
        ex = paper_exposures(spec, cam)
        texts = {x.index: (x.ground_truth or {}).get("text", "") for x in ex}
        if not any(texts.values()):
            raise UserError(f"{spec.toml_path}: source.boxes: the paper protocol needs plate text "
                            "(the CSV's text column)")
        if getattr(cfg, "camera", "physical") == "paper":
            images, secs, boxes = paper_camera_images(runner, spec, cfg)
        else:
            images, secs = runner.method_images(ex)
            boxes = {x.index: cam.box_to_sensor(x.roi) if x.roi else None for x in ex}
        meta = {"kind": KIND, "speed_px": 0.0, "direction": 0, "change": "",
                "measured_px_per_frame": shift_px(ex)}
        rows += score(runner, meta, texts, e, images, secs, boxes)
        log(f"poevp evaluate: paper protocol E = {e:g} done ({time.perf_counter() - t0:.0f} s)")
    return rows
