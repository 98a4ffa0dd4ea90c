"""Mask laws by name: predicted frame -> grayscale DMD mask levels in [0, 2^B - 1].

| law              | formula (x: predicted 8-bit value, 0-255)                      | reference |
|------------------|----------------------------------------------------------------|-----------|
| threshold_exp    | M = 255 if x < Vs, else 255 a^((x - b Vs) / (255 - x))          | paper Eq. 2, reading 1 |
| threshold_ratio  | M = 255 if x < Vs, else 255 (a Vs / x + b)                      | paper Eq. 2, reading 2 |
| threshold_linear | M = 255 if x < Vs, else 255 - a (x - b Vs) 255 / x              | paper Eq. 2, reading 3 |
| target           | the largest level whose exposure brings the predicted signal to `target` x full well | ours |
| exposure_controller | per-region controller: where from the prediction, how bright from past masks and captures; signal into [band_low, band_high] of full scale | ours (exposure_control.py) |
| white            | M = 255 everywhere (the LDR twin)                               | - |

The paper's Eq. 2 is garbled in our copy (its second branch's symbols read, in order,
"255 a x b Vs 255 x"). Two readings fit its settings (Vs = 200; (a, b) = (0.9, 0) in
simulation, (0.7, 0.2) in hardware): the exponential one matches the symbol order and tends to
0 as x -> 255; the ratio one is the plain physical law (dim by Vs/x) and has a + b = 0.9 in both
settings. A third reading keeps every printed symbol in its order with the operators a fraction
bar and a minus restore: "255 - a (x - b Vs) 255 / x", i.e. M = 255 [1 - a (1 - b Vs / x)]: the
transmission falls from 1 - a (1 - b) at x = Vs towards 1 - a, so with the simulation's (a, b) =
(0.9, 0) every pixel above Vs is dimmed tenfold (transmission 0.1, whatever x), and with the
hardware's (0.7, 0.2) from 0.44 at Vs to 0.41 at 255; it is continuous at Vs only when b = 1.
It is the one reading under which the paper's own simulation (clipped 8-bit predictions, E = 9 to
49) can unclip a plate at all: the ratio reading dims a clipped pixel by at most a Vs / 255 =
0.71, the exponential one to 0 (benchmarks/results/recognition.md, the paper's protocol). All three are shipped; at x = 255
the exponential law is taken at its limit (0 for a < 1).
Outputs are finite and clipped to [0, 255] everywhere, then scaled to the DMD's 2^B - 1 levels.
`min_level` (default 0) bars the lowest levels: level 0 passes only the off-state leakage, whose
value depends on f-number, wavelength and angle (FACTS.md) and so is poorly calibrated for
reconstruction; with min_level = 1 the deepest attenuation is the smallest PWM step, 1/(2^B - 1).

A clipped predicted pixel (>= 254.5 on the 8-bit scale) says only "at least saturated". The
`target` law then assumes it is `clipped_gain` times the saturation level (default 32, about the
paper's strongest over-exposure E = 29-49); the paper's laws act on the clipped value as is.

Masks are computed from a band-limited picture of the frame (DESIGN.md, FACTS.md): an exact
per-pixel mask flattens the capture to a constant and destroys the characters' contrast. Before
any law, the predicted frame is replaced by its smooth upper envelope: a grey dilation of radius
R = ceil(3 smooth_px) (square window) followed by a Gaussian blur of sigma smooth_px truncated at the same R.
Every tap of the blur kernel around a pixel then lies inside that pixel's dilated neighbourhood,
so the envelope is >= the frame everywhere: the mask is smooth and never under-attenuates.

The envelope's radius (`mask.envelope`). With "fixed" it is R = ceil(3 smooth_px) in every
frame: wide enough for a predictor that lags the highlight by up to R mirrors, but it also gives
a plate's ends the dimming meant for the mirrors R nearer the highlight's peak (a Gaussian
plate highlight at 29x saturation: about 7.9x where the ends are 1.4x, so the ends come out at
a tenth of the band and the detector loses the leading characters). With "predictor_error" the
loop sizes it from its own history (`envelope_sigma`): the distance by which the highlight the
camera captured in the last frame reached beyond the bright region the mask had been computed
from (`highlight_miss_px`: the shift of the region's centroid plus the growth of its radius),
sigma = miss, floored at `ENVELOPE_FLOOR_SIGMA` (1 mirror: the
ink stays dark under a mask that fills the strokes with the plate's white; with no envelope the
mask flattens the characters) and capped at smooth_px. Sigma = miss rather than miss / 3: the
blur of the dilated frame falls off over the last 2 sigma of the radius R = 3 sigma, so a
mirror `miss` beyond the aimed region still gets Phi(2) = 98 % of the highlight's envelope. A
predictor that misses by v < smooth_px mirrors (hold at v px/frame) gets R = 3 v; one that
misses by more (hold, flow at speed) the fixed envelope; the oracle, which misses by about the
relay's blur, the floor (R = 3).
Causal: the miss is measured on the frame already captured (the demodulated capture is where
the highlight really was), and the exposure controller's carry radius follows the same R.
With "region_body" (exposure controller only) each bright region's body, its median demand,
takes the fixed envelope, and its brighter parts the envelope the region's own last miss asks
for (control/envelope.py): a plate partly in a shadow keeps the dimming its lit part needs on
that part, while several highlights are each sized by their own prediction's miss.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poevp_optics.control.envelope import body_envelope, smooth_envelope
from poevp_optics.core.params import param
from poevp_optics.core.registry import Registry


#: How the envelope's radius is chosen (module docstring).
ENVELOPE_MODES = ("fixed", "predictor_error", "region_body")
#: The envelope's smallest sigma under "predictor_error" and for a region's brighter parts under
#: "region_body", mirrors (module docstring): R = 3.
ENVELOPE_FLOOR_SIGMA = 1.0


def highlight_miss_px(predicted: np.ndarray, captured: np.ndarray) -> float | None:
    """How far (mirrors) the captured bright region reached beyond the predicted one: the shift
    of its centroid plus the growth of its equivalent radius sqrt(area / pi) (0 if it shrank).
    Both boolean maps on one grid. None when nothing was captured bright (no highlight: nothing
    to measure); the map's diagonal when nothing was predicted bright. Region moments, not the
    region's boundary: a plate's highlight is a smooth peak whose saturation contour moves by
    several mirrors under a few per cent of noise or blur (the oracle's own contour does), while
    its centroid and area do not."""
    captured = np.asarray(captured, dtype=bool)
    predicted = np.asarray(predicted, dtype=bool)
    if not captured.any():
        return None
    if not predicted.any():
        return float(np.hypot(*captured.shape))
    cy, cx = (float(np.mean(i)) for i in np.nonzero(captured))
    py, px = (float(np.mean(i)) for i in np.nonzero(predicted))
    grow = np.sqrt(np.count_nonzero(captured) / np.pi) - np.sqrt(np.count_nonzero(predicted) / np.pi)
    return float(np.hypot(cy - py, cx - px) + max(grow, 0.0))


def envelope_sigma(spec, miss_px: float | None) -> float:
    """The envelope's sigma (mirrors) for one frame (module docstring): smooth_px under "fixed"
    and "region_body" (its regions' brighter parts sized apart: envelope.py) or before any miss
    was measured; else the miss within [min(ENVELOPE_FLOOR_SIGMA, smooth_px), smooth_px] (the
    radius ceil(3 sigma) covers the miss with 2 sigma to spare)."""
    if spec.envelope != "predictor_error" or miss_px is None:
        return float(spec.smooth_px)
    floor = min(ENVELOPE_FLOOR_SIGMA, spec.smooth_px)
    return float(min(max(miss_px, floor), spec.smooth_px))


def _as_8bit(x) -> np.ndarray:
    """Predicted values on the 8-bit scale, NaN taken as clipped (255: the safe side for a
    highlight), clipped to [0, 255]."""
    return np.clip(np.nan_to_num(np.asarray(x, dtype=np.float64), nan=255.0), 0.0, 255.0)


def threshold_exp(x: np.ndarray, vs: float, a: float, b: float) -> np.ndarray:
    """Paper Eq. 2, exponential reading: 255 a^((x - b Vs) / (255 - x)) above Vs."""
    x = _as_8bit(x)
    with np.errstate(divide="ignore", invalid="ignore"):
        expo = (x - b * vs) / np.maximum(255.0 - x, 0.0)
        expo = np.where(255.0 - x > 0, expo, np.inf)
        if a >= 1.0:
            att = np.ones_like(x)
        elif a <= 0.0:
            att = np.where(expo > 0, 0.0, 1.0)
        else:
            att = np.exp(np.minimum(expo, 1e6) * np.log(a))   # a^inf -> 0, finite everywhere
    m = np.where(x < vs, 255.0, 255.0 * np.clip(att, 0.0, 1.0))
    return np.clip(m, 0.0, 255.0)


def threshold_ratio(x: np.ndarray, vs: float, a: float, b: float) -> np.ndarray:
    """Paper Eq. 2, ratio reading: 255 (a Vs / x + b) above Vs."""
    x = _as_8bit(x)
    m = np.where(x < vs, 255.0, 255.0 * (a * vs / np.maximum(x, 1e-12) + b))
    return np.clip(m, 0.0, 255.0)


def threshold_linear(x: np.ndarray, vs: float, a: float, b: float) -> np.ndarray:
    """Paper Eq. 2, third reading: 255 - a (x - b Vs) 255 / x above Vs (module docstring)."""
    x = _as_8bit(x)
    m = np.where(x < vs, 255.0, 255.0 - a * (x - b * vs) * 255.0 / np.maximum(x, 1e-12))
    return np.clip(m, 0.0, 255.0)


def target_levels(pred_electrons: np.ndarray, full_well_e: float, target: float,
                  level_exposure: np.ndarray, min_level: int = 0) -> np.ndarray:
    """Largest-exposure level keeping predicted electrons <= target x full well.

    pred_electrons: electrons the pixel would collect with the all-white mask.
    level_exposure: effective exposure of each level (any unit; index = level), e.g. from
    `dmd.transmission_table(...).sum(1)`. Works for non-monotone tables (partial window overlap).
    Where even the darkest level is too bright, that darkest level is used. Levels below
    `min_level` are never used. A prediction of 0 or below (-0.0 included) needs no dimming
    (white); NaN is taken as infinitely bright (the darkest usable level).
    """
    e = np.asarray(pred_electrons, dtype=np.float32)
    e = np.maximum(np.nan_to_num(e, nan=np.inf), np.float32(0.0)) + np.float32(0.0)   # -0.0 -> +0.0
    white = float(level_exposure[-1])
    rel = np.asarray(level_exposure, dtype=np.float64) / white   # exposure relative to white
    order = min_level + np.argsort(rel[min_level:], kind="stable")
    # compare in "electrons the pixel would get": e x rel <= target x FW, i.e. rel <= need
    with np.errstate(divide="ignore"):
        need = np.float32(target * full_well_e) / e               # inf where e == 0
    pos = np.searchsorted(rel[order].astype(np.float32), need, side="right") - 1
    np.clip(pos, 0, len(order) - 1, out=pos)
    return order[pos].astype(np.float64)


def band_levels(e_white: np.ndarray, level_exposure: np.ndarray, e_low: float, e_aim: float,
                e_high: float, min_level: int = 0, nearest: bool = False) -> np.ndarray:
    """DMD level per mirror that puts `e_white` x rel(level) in the band [e_low, e_high] (e-):
    the largest-exposure level at or below `e_aim`; where that lands below `e_low`, the
    largest-exposure level at or below `e_high` (the band is wider than one PWM step except
    between level 0 and 1, so this lands in the band wherever a level can). With `nearest`
    (`mask.aim_rounding = "nearest"`), the next brighter level instead where its signal lies
    nearer the aim in ratio (e_up / e_aim < e_aim / e_got) and at or below `e_high`: at the
    coarse low levels (level 2 passes 1.8x level 1 with the DLP6500's 1000:1 leakage) rounding
    down can leave a highlight's peak anywhere down to e_aim / 1.8, and its body below the band.
    Float64 levels."""
    e = np.asarray(e_white, dtype=np.float64)
    rel = np.asarray(level_exposure, dtype=np.float64) / float(level_exposure[-1])
    v_aim = target_levels(e, e_aim, 1.0, level_exposure, min_level)
    v_high = target_levels(e, e_high, 1.0, level_exposure, min_level)
    got = e * rel[v_aim.astype(np.int64)]
    if not nearest:
        return np.where(got >= e_low, v_aim, v_high)
    order = min_level + np.argsort(rel[min_level:], kind="stable")
    pos = np.searchsorted(rel[order], rel[v_aim.astype(np.int64)], side="right") - 1
    up = order[np.minimum(pos + 1, len(order) - 1)]
    got_up = e * rel[up]
    closer_up = (got_up <= e_high) & (got_up * got < e_aim * e_aim)
    return np.where(closer_up, up.astype(np.float64), np.where(got >= e_low, v_aim, v_high))


def predicted_electrons(pred_8bit: np.ndarray, params, clipped_gain: float) -> np.ndarray:
    """Photo-electrons implied by a predicted frame on the 8-bit scale (values above 255 allowed,
    as in the demodulated loop): the sensor transfer inverted, e = (x max_dn / 255 - offset_dn)
    / gain_dn_per_e, >= 0 (so the black level reads 0 e-); clipped values (254.5 ... 255.5) are
    taken as clipped_gain x the saturation capacity. `params`: sensor.SensorParams."""
    x = np.asarray(pred_8bit, dtype=np.float64)
    dn = x * (params.max_dn / 255.0)
    e = np.maximum(dn - params.offset_dn, 0.0) / params.gain_dn_per_e
    clipped = (x >= 254.5) & (x <= 255.5)
    return np.where(clipped, clipped_gain * params.saturation_capacity_e, e)


@dataclass(frozen=True)
class MaskInput:
    """What a law may look at: the predicted frame on the 8-bit scale (mirror grid; above 255 in
    the demodulated loop, the paper's laws clip it), the electrons
    it implies with the all-white mask, the full well, and the exposure of every DMD level; for
    the exposure controller also the sensor (SensorParams), the controller's state (past masks
    and captures) and whether the prediction is of masked captures (the `raw` loop mode); the
    global attenuator's transmission for the frame (the `target` and `exposure_controller` laws
    take it into the exposure; the paper's laws act on the 8-bit prediction as is)."""

    pred_8bit: np.ndarray | None = None
    pred_electrons: np.ndarray | None = None
    full_well_e: float | None = None
    level_exposure: np.ndarray | None = None
    sensor: object | None = None
    controller: object | None = None
    pred_masked: bool = False
    transmission: float = 1.0       # the global attenuator's setting (camera/attenuator.py)

    @property
    def shape(self):
        return (self.pred_8bit if self.pred_8bit is not None else self.pred_electrons).shape


def _white_law(spec, top: int, x: MaskInput) -> np.ndarray:
    return np.full(x.shape, float(top))


def _target_law(spec, top: int, x: MaskInput) -> np.ndarray:
    if x.pred_electrons is None or x.level_exposure is None or x.full_well_e is None:
        raise ValueError("mask law 'target' needs predicted electrons and the level table")
    e = np.nan_to_num(np.asarray(x.pred_electrons, dtype=np.float64), nan=1e30, posinf=1e30)
    env = smooth_envelope(e * x.transmission, spec.smooth_px)
    return target_levels(env, x.full_well_e, spec.target, x.level_exposure, min(spec.min_level, top))


def controller_demand_e(spec, x: "MaskInput") -> np.ndarray:
    """The all-white electrons the exposure controller assumes per mirror (before the smooth
    envelope): bright where the prediction clips (the clip marker 254.5-255.5: "at least
    saturated"), as bright as the controller's demand there (first_guess x saturation where the
    controller has no clipped history: the prediction moved the highlight beyond the carried
    region), the prediction's own value elsewhere, above the clip included (the demodulated
    loop's estimates: their brightness moves with the prediction, issue 20)."""
    if x.pred_electrons is None or x.level_exposure is None or x.sensor is None:
        raise ValueError("mask law 'exposure_controller' needs predicted electrons, the level table "
                         "and the sensor")
    p = x.sensor
    e = np.nan_to_num(np.asarray(x.pred_electrons, dtype=np.float64), nan=1e30, posinf=1e30)
    c = x.controller
    if c is not None and c.demand_e is not None:
        x8 = None if x.pred_8bit is None else np.nan_to_num(np.asarray(x.pred_8bit, dtype=np.float64), nan=255.0)
        bright = x8 >= 254.5 if x8 is not None else e >= p.saturation_capacity_e
        if x.pred_masked:                       # a prediction of masked captures: demodulate it
            e = np.where(bright, e, e / np.maximum(c.rel.astype(np.float64), 1e-9))
        # a predicted value above the clip (the demodulated loop's estimates) carries its own
        # brightness, moved by the predictor; only the clip marker takes the controller's demand
        marker = bright & (x8 <= 255.5) if x8 is not None else bright
        held = c.held_e()
        known = held >= p.saturation_capacity_e
        e = np.where(marker, np.where(known, held, spec.first_guess * p.saturation_capacity_e), e)
        moved = c.moved_e() if spec.carry == "extrapolate" else None
        if moved is not None:                   # regions moving faster than the carry radius
            e = np.maximum(e, moved)
    return e


def reach_electrons(spec, top: int, level_exposure: np.ndarray, sensor) -> float:
    """The most all-white electrons the darkest usable level (>= min_level) still brings to the
    aim (`target` x full scale): the exposure controller's reach without a global attenuator."""
    from poevp_optics.control.exposure_control import full_scale_electrons

    rel = np.asarray(level_exposure, dtype=np.float64) / float(level_exposure[-1])
    floor = float(np.min(rel[min(spec.min_level, top):]))
    aim = float(full_scale_electrons(sensor, spec.target))
    return aim / floor if floor > 0 else float("inf")


def _controller_law(spec, top: int, x: MaskInput) -> np.ndarray:
    """exposure_control.py: the demand (`controller_demand_e`) through the attenuator's
    transmission, smooth envelope (under `mask.envelope = "region_body"` each bright region's
    body and its brighter parts apart: control/envelope.py), then the level putting the signal
    in the band [band_low, band_high] x full scale, aiming at `target`."""
    from poevp_optics.control.exposure_control import full_scale_electrons

    demand = controller_demand_e(spec, x)
    if spec.envelope == "region_body":
        sigma = None if x.controller is None else x.controller.region_sigma
        env = body_envelope(demand * x.transmission, demand >= x.sensor.saturation_capacity_e, sigma,
                            spec.smooth_px)
    else:
        env = smooth_envelope(demand * x.transmission, spec.smooth_px)
    e_low, e_aim, e_high = full_scale_electrons(x.sensor, [spec.band_low, spec.target, spec.band_high])
    return band_levels(env, x.level_exposure, e_low, e_aim, e_high, min(spec.min_level, top),
                       nearest=spec.aim_rounding == "nearest")


def _paper_law(formula):
    def law(spec, top: int, x: MaskInput) -> np.ndarray:
        if x.pred_8bit is None:
            raise ValueError(f"mask law {spec.law!r} needs a predicted 8-bit frame")
        env = smooth_envelope(_as_8bit(x.pred_8bit), spec.smooth_px)
        m255 = formula(env, spec.vs, spec.a, spec.b)
        return np.clip(np.rint(m255 * top / 255.0), min(spec.min_level, top), top)
    return law


#: The laws that take a global attenuator's transmission into the exposure (camera/attenuator.py).
ATTENUATED_LAWS = ("target", "exposure_controller")

#: How the exposure controller carries a region's demand to the next frame (exposure_control.py):
#: dilated by 3 smooth_px where the prediction clips, or also moved on at its box's velocity.
CARRY_MODES = ("dilate", "extrapolate")
#: How the exposure controller rounds to a level at its aim (`band_levels`): "down", the
#: largest level at or below the aim; "nearest", the level nearer the aim in ratio, never above
#: the band.
AIM_ROUNDING = ("down", "nearest")

MASK_LAWS = Registry("mask law")
MASK_LAWS.register("threshold_exp", _paper_law(threshold_exp),
                   source="paper Eq. 2, exponential reading (module docstring)")
MASK_LAWS.register("threshold_ratio", _paper_law(threshold_ratio),
                   source="paper Eq. 2, ratio reading (module docstring)")
MASK_LAWS.register("threshold_linear", _paper_law(threshold_linear),
                   source="paper Eq. 2, third reading: every printed symbol in order (module docstring)")
MASK_LAWS.register("target", _target_law, source="ours: the largest level bringing the predicted "
                   "signal to `target` x full well")
MASK_LAWS.register("exposure_controller", _controller_law,
                   source="ours: per-region exposure controller from past masks and captures "
                   "(control/exposure_control.py), target band of full scale")
MASK_LAWS.register("white", _white_law, source="all mirrors on: the LDR twin")


@dataclass(frozen=True)
class MaskSpec:
    """[mask]: mask law and its coefficients (paper Eq. 2: vs, a, b)."""

    law: str = param("target", choices=MASK_LAWS)
    vs: float = param(200.0, gt=0, lt=255)
    a: float = param(0.9, min=0, max=1)
    b: float = param(0.0, min=0, max=1)
    target: float = param(0.5, gt=0, max=1)
    smooth_px: float = param(4.0, min=0, max=1000)
    envelope: str = param("fixed", choices=ENVELOPE_MODES)
    clipped_gain: float = param(32.0, min=1, max=1e9)   # assumed x saturation (x lower bound) where clipped
    first_guess: float = param(40.0, min=1, max=1e9)    # exposure_controller: never-measured clipped region, x saturation
    prior_beam_cd: float = param(0.0, min=0, max=1e12)  # exposure_controller on a road scene: our beams' intensity_cd
    # that first_guess is for; the prior scales with [road].highbeam's intensity_cd / this (0: fixed)
    clip_step: float = param(2.0, min=1, max=1e9)       # exposure_controller: guess after a repeated clip, x lower bound
    band_low: float = param(0.4, gt=0, lt=1)            # exposure_controller: band, fraction of full scale
    band_high: float = param(0.9, gt=0, max=1)
    min_level: int = param(0, min=0, max=65535)         # lowest DMD level a law may use
    carry: str = param("dilate", choices=CARRY_MODES)    # exposure_controller: history carried to the next frame
    aim_rounding: str = param("down", choices=AIM_ROUNDING)  # exposure_controller: the level at the aim: "down" the
    # largest at or below it, "nearest" the one nearer it in ratio, never above band_high

    # exposure_controller's exposure time and DMD bit depth per frame (control/exposure_time.py):
    exposure_time_auto: bool = param(False)                 # choose T_e per frame (off: the scene's exposure)
    exposure_time_s: float = param(0.0, min=0, max=100.0)   # fixed sensor exposure T_e, s (0: not fixed)
    fine_steps: int = param(20, min=1, max=65535)           # levels above zero the reference demand is put at
    time_clip_step: float = param(100.0, min=1, max=1e9)    # T_e after a clip: for this x the lower bound


def mask_levels(spec: MaskSpec, bits: int, *, pred_8bit: np.ndarray | None = None,
                pred_electrons: np.ndarray | None = None, full_well_e: float | None = None,
                level_exposure: np.ndarray | None = None, sensor=None, controller=None,
                pred_masked: bool = False, transmission: float = 1.0) -> np.ndarray:
    """Apply the scene's mask law (MASK_LAWS); integer-valued float64 levels in [0, 2^bits - 1]."""
    x = MaskInput(pred_8bit, pred_electrons, full_well_e, level_exposure, sensor, controller, pred_masked,
                  transmission)
    return MASK_LAWS[spec.law](spec, (1 << bits) - 1, x)
