"""One step of the closed loop: past captures -> predictor input -> prediction -> mask.

Per frame t the step gives the DMD mask for t (`next_mask`) from what the camera saw up to t - 1,
then takes what the camera saw at t (`observe`). The first `loop.init_frames` frames are white
for every predictor, the oracle included (paper Sec. 3; DESIGN.md), and a causal predictor also
waits until it has `needs_frames` past frames. With `loop.meter_init` (exposure controller, causal
predictor) every one of those frames after the first is metered instead (`metered_choice`): the
controller's mask from the last capture, held in place, dims by its prior where that capture
clipped, so the first loop frame's mask comes from a measurement of every region up to
prior / target (67x saturation at the default 40) and from one bracket beyond it, not from the
prior (a white frame says of a clipped region only "at least saturated"). The same step drives
the render run, the chart's mask settling, `compare`, `evaluate` and the benchmarks.

Loop modes (`LOOP_MODES`, what the predictor sees; DESIGN.md "Loop modes"):

| mode        | predictor input                                                     | reference |
|-------------|---------------------------------------------------------------------|-----------|
| open        | the LDR twin (DMD white), 8-bit                                     | paper Fig. 3 (its simulation) |
| raw         | the encoded capture, 8-bit                                          | paper Fig. 7 (its hardware) |
| demodulated | the reconstruction re-expressed as the all-white signal, 8-bit scale, unclipped | ours |

Grids (core/grids.py): the predictor's history and prediction are on the predictor grid
(`[predictor].resolution`, `resize_onto` from and back to the sensor grid, the clip marker kept);
captures are on the sensor grid; a prediction is placed on the mirror grid through the inverse
registration (camera.to_mirror) before the mask law, and the DMD command's levels are on the
mirror grid. Each crossing carries the grid (`OnGrid`) and refuses an array on another one.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from poevp_optics.camera.attenuator import AttenuatorSpec, AttenuatorState, choose_transmission
from poevp_optics.camera.dmd import displayed_levels
from poevp_optics.control import exposure_time
from poevp_optics.control.envelope import region_radii, region_sigma
from poevp_optics.control.exposure_control import ExposureController
from poevp_optics.control.masks import (ATTENUATED_LAWS, ENVELOPE_FLOOR_SIGMA, MaskSpec, envelope_sigma,
                                        highlight_miss_px, mask_levels, predicted_electrons, reach_electrons)
from poevp_optics.control.timing_budget import BudgetSpec, MaskClock
from poevp_optics.control.predictors import PREDICTORS, PredictorSpec, checked_prediction, make_predictor
from poevp_optics.core.grids import Grid, GridError, OnGrid
from poevp_optics.core.params import param
from poevp_optics.core.registry import Registry
from poevp_optics.core.units import to_8bit


def resize_to(img: np.ndarray, shape) -> np.ndarray:
    """float32 image resized to (H, W): area average when shrinking, bilinear when growing."""
    import cv2

    h, w = shape
    if img.shape == (h, w):
        return img.astype(np.float32)
    interp = cv2.INTER_AREA if img.shape[0] > h else cv2.INTER_LINEAR
    return cv2.resize(img.astype(np.float32), (w, h), interpolation=interp)


#: 8-bit value from which a pixel is clipped (the mask laws' clip marker; flow.py's SATURATED).
CLIP_MARKER = 254.5


def resize_keeping_clip(img: np.ndarray, shape) -> np.ndarray:
    """`resize_to`, with the clip marker kept: a pixel whose footprint is at least half clipped
    (>= CLIP_MARKER) in `img` is clipped after the resize (>= 255, or its own value where that
    is higher), so area averaging or bilinear growth never turns a clipped edge into a value the
    mask law reads as unclipped."""
    out = resize_to(img, shape)
    if tuple(np.shape(img)) == tuple(shape):
        return out
    frac = resize_to((np.asarray(img) >= CLIP_MARKER).astype(np.float32), shape)
    return np.where(frac >= 0.5, np.maximum(out, 255.0), out).astype(np.float32)


#: The resampling `resize_onto` does: (from grid, onto grid). The mirror grid is reached only
#: through the registration (Camera.to_mirror), never by a resize.
_RESIZES = {("sensor", "predictor"), ("predictor", "sensor")}


def resize_onto(x: OnGrid, target: Grid) -> OnGrid:
    """`resize_keeping_clip` between the sensor grid and the predictor grid, tagged: a sensor-grid
    picture onto the predictor grid (the predictor's input) or a prediction back onto the sensor
    grid. Any other pair (a mirror-grid array, or a resize onto the mirror grid, which needs the
    registration) is refused with a GridError naming both grids."""
    if not isinstance(x, OnGrid):
        raise TypeError(f"resize_onto takes an OnGrid (an array and its grid), not {type(x).__name__}")
    if (x.grid.name, target.name) not in _RESIZES:
        raise GridError(f"resize_onto cannot take an array on the {x.grid} onto the {target}: only the "
                        "sensor and predictor grids are resized (the mirror grid goes through the "
                        "registration, Camera.to_mirror / to_sensor)")
    return OnGrid(resize_keeping_clip(x.array, target.shape), target)


def _open_input(camera, ldr, enc, est, flags, index, clipped_gain):
    return to_8bit(ldr.dn, camera.params.max_dn).astype(np.float32)


def _raw_input(camera, ldr, enc, est, flags, index, clipped_gain):
    return to_8bit(enc.dn, camera.params.max_dn).astype(np.float32)


def _demodulated_input(camera, ldr, enc, est, flags, index, clipped_gain):
    """Reconstruction re-expressed as the signal an all-white mask would give, on the 8-bit
    scale, unclipped. A saturated pixel's estimate is only a lower bound x_lb: behind a white
    mirror (x_lb ~ 255) it is marked clipped (255), which the target law reads as clipped_gain x
    saturation; behind a dimmed mirror (x_lb > 255) it becomes clipped_gain x x_lb, the same
    assumption one step further, so a highlight brighter than the first guess is dimmed
    geometrically, frame after frame (static scenes converge)."""
    e_white = est.astype(np.float64) * camera.electrons_per_radiance() * camera.white_exposure_s(index)
    x = 255.0 * e_white / camera.params.saturation_capacity_e
    sat = (flags.astype(np.int64) & 1) > 0
    lifted = np.where(x > 255.5, x * clipped_gain, 255.0)
    x = np.where(sat, lifted, np.where(np.abs(x - 255.0) <= 0.5, 254.4, x))
    return x.astype(np.float32)


#: Loop modes whose predictor sees masked captures (the exposure controller demodulates them).
MASKED_MODES = frozenset({"raw"})

LOOP_MODES = Registry("loop mode")
LOOP_MODES.register("open", _open_input, source="paper Fig. 3: the predictor sees unmasked LDR frames")
LOOP_MODES.register("raw", _raw_input, source="paper Fig. 7: the predictor sees the masked captures")
LOOP_MODES.register("demodulated", _demodulated_input,
                    source="ours: the predictor sees reconstructions, so the mask does not fight itself")


@dataclass(frozen=True)
class LoopSpec:
    """[loop]: what the predictor sees and how many all-white frames start the loop."""

    mode: str = param("open", choices=LOOP_MODES)
    init_frames: int = param(2, min=0, max=1000)
    meter_init: bool = param(False)   # after the first white frame, initialisation frames dim where the last capture clipped


def predictor_input(mode: str, camera, ldr, enc, est, flags, index: int, clipped_gain: float) -> np.ndarray:
    """What the predictor sees of frame `index` (8-bit scale, float32, sensor grid), per mode
    (`LoopStep.observe` tags it with the sensor grid and resizes it onto the predictor grid)."""
    return LOOP_MODES[mode](camera, ldr, enc, est, flags, index, clipped_gain)


def levels_and_exposure(camera, mask: MaskSpec, index: int, g: float, demand_e: np.ndarray, controller=None,
                        attenuator: AttenuatorSpec = AttenuatorSpec(), **kw):
    """(levels, exposure choice) of the mask law for frame `index` with the ND at `g`; demand_e:
    the all-white electrons per mirror the exposure choice reads (as the attenuator's); kw: the
    law's inputs (mask_levels' pred_8bit, pred_electrons, full_well_e, sensor, pred_masked). Under
    the exposure controller's law the frame's sensor exposure and DMD bit depth are chosen first
    (control/exposure_time.py) and the law then reads that frame's level table, the shortening
    taken as a transmission; other laws: (levels, None)."""
    level_exposure = camera.level_exposure_s(index)
    fx, t = None, g
    if exposure_time.is_active(mask, camera):
        fx = exposure_time.choose(camera, mask, demand_e, index, g, attenuator.serve_min_mirrors, attenuator.enabled)
        if not fx.nominal:
            white_nom = float(level_exposure[-1])
            level_exposure = camera.level_exposure_s(index, fx)
            t = g * float(level_exposure[-1]) / white_nom
    bits = camera.dmd.spec.bits
    levels = mask_levels(mask, bits, level_exposure=level_exposure, controller=controller, transmission=t, **kw)
    if fx is not None and fx.bits < bits:     # each B-bit level by its nearest mask level (same light)
        q = displayed_levels(levels, bits, fx.bits)
        levels = np.rint(q * ((1 << bits) - 1) / ((1 << fx.bits) - 1)).astype(np.float64)
    return levels, fx


def oracle_choice(camera, mask: MaskSpec, radiance_mean: np.ndarray, index: int,
                  attenuator: AttenuatorSpec = AttenuatorSpec()) -> tuple[np.ndarray, float, object]:
    """(levels, attenuator transmission, exposure choice or None) of the mask law applied to the
    true frame (mirror grid): the upper bound of any predictor; the transmission from the true
    all-white electrons; the exposure time from the true frame (`levels_and_exposure`)."""
    white_e = radiance_mean.astype(np.float64) * camera.electrons_per_radiance() * camera.white_exposure_s(index)
    g = attenuator_transmission(camera, mask, attenuator, white_e, index)
    ldr8 = to_8bit(camera.noise_free_dn(white_e), camera.params.max_dn)
    levels, fx = levels_and_exposure(camera, mask, index, g, white_e, attenuator=attenuator, pred_8bit=ldr8,
                                     pred_electrons=white_e, full_well_e=camera.params.full_well_e, sensor=camera.params)
    return levels, g, fx


def oracle_decision(camera, mask: MaskSpec, radiance_mean: np.ndarray, index: int,
                    attenuator: AttenuatorSpec = AttenuatorSpec()) -> tuple[np.ndarray, float]:
    """(levels, attenuator transmission) of the mask law applied to the true frame at the
    scene's exposure (no exposure-time choice: `oracle_choice` has it)."""
    white_e = radiance_mean.astype(np.float64) * camera.electrons_per_radiance() * camera.white_exposure_s(index)
    g = attenuator_transmission(camera, mask, attenuator, white_e, index)
    ldr8 = to_8bit(camera.noise_free_dn(white_e), camera.params.max_dn)
    return mask_levels(mask, camera.dmd.spec.bits, pred_8bit=ldr8, pred_electrons=white_e,
                       full_well_e=camera.params.full_well_e, level_exposure=camera.level_exposure_s(index),
                       sensor=camera.params, transmission=g), g


def oracle_mask(camera, mask: MaskSpec, radiance_mean: np.ndarray, index: int) -> np.ndarray:
    """The mask law applied to the true frame (mirror grid), no attenuator (`oracle_decision`)."""
    return oracle_decision(camera, mask, radiance_mean, index)[0]


def attenuator_transmission(camera, mask: MaskSpec, attenuator: AttenuatorSpec, demand_e: np.ndarray,
                            index: int) -> float:
    """The attenuator's setting for frame `index` given the all-white electrons per mirror the
    mask law assumes (camera/attenuator.py); 1 for a disabled attenuator or a paper law."""
    if not attenuator.enabled or mask.law not in ATTENUATED_LAWS:
        return 1.0
    reach = reach_electrons(mask, camera.top_level, camera.level_exposure_s(index), camera.params)
    return choose_transmission(demand_e, reach, attenuator)


def predicted_mask(camera, mask: MaskSpec, pred_8bit: np.ndarray | OnGrid, index: int, controller=None,
                   pred_masked: bool = False) -> np.ndarray:
    """The mask law applied to a predicted frame on the 8-bit scale (sensor grid), placed on the
    mirror grid through the inverse registration first (camera.to_mirror). controller: the
    loop's ExposureController (past masks and captures); pred_masked: the prediction is of
    masked captures (MASKED_MODES). No attenuator (`predicted_decision` has one)."""
    return predicted_decision(camera, mask, pred_8bit, index, controller, pred_masked)[0]


def predicted_decision(camera, mask: MaskSpec, pred_8bit: np.ndarray | OnGrid, index: int, controller=None,
                       pred_masked: bool = False,
                       attenuator: AttenuatorSpec = AttenuatorSpec()) -> tuple[np.ndarray, float]:
    """(levels, attenuator transmission) from a predicted frame (`predicted_mask`). The
    transmission is global, so it needs no prediction of where: it comes from the exposure
    controller's demand of the last capture, per mirror and not dilated (so a highlight counts
    with its measured size: camera/attenuator.py serves only highlights of serve_min_mirrors or
    more), or from the prediction without a controller; then the levels through it.
    pred_8bit: on the sensor grid (an `OnGrid` on another grid is refused by camera.to_mirror)."""
    levels, g, _ = predicted_choice(camera, mask, pred_8bit, index, controller, pred_masked, attenuator,
                                    exposure_control=False)
    return levels, g


def predicted_choice(camera, mask: MaskSpec, pred_8bit: np.ndarray | OnGrid, index: int, controller=None,
                     pred_masked: bool = False, attenuator: AttenuatorSpec = AttenuatorSpec(),
                     exposure_control: bool = True) -> tuple[np.ndarray, float, object]:
    """(levels, attenuator transmission, exposure choice or None) from a predicted frame:
    `predicted_decision` with the frame's exposure time and DMD bit depth chosen under the
    exposure controller's law (`levels_and_exposure`; exposure_control=False: the scene's)."""
    pred = camera.mirror_grid.take(camera.to_mirror(pred_8bit), "the placed prediction").astype(np.float64)
    e = predicted_electrons(pred, camera.params, mask.clipped_gain)
    kw = dict(pred_8bit=pred, pred_electrons=e, full_well_e=camera.params.full_well_e, sensor=camera.params,
              pred_masked=pred_masked)
    g = 1.0
    measured = controller is not None and controller.demand_e is not None
    demand = controller.demand_e if measured else e     # global: where does not matter, only how bright and how large
    if attenuator.enabled:
        g = attenuator_transmission(camera, mask, attenuator, demand, index)
    if not exposure_control:
        return mask_levels(mask, camera.dmd.spec.bits, transmission=g, level_exposure=camera.level_exposure_s(index),
                           controller=controller, **kw), g, None
    levels, fx = levels_and_exposure(camera, mask, index, g, demand, controller, attenuator, **kw)
    return levels, g, fx


def metered_choice(camera, mask: MaskSpec, controller: ExposureController, index: int,
                   attenuator: AttenuatorSpec = AttenuatorSpec()) -> tuple[np.ndarray, float, object]:
    """(levels, attenuator transmission, exposure choice or None) of a metering frame: the mask
    law with the last capture held as the prediction (mirror grid, no motion: the predictor is
    still waiting for its history). Its all-white electrons are the controller's demand: the
    measurement where the capture was not clipped, the prior or bracket where it was, marked
    clipped (255) so the law takes the controller's carried demand there, as on a loop frame."""
    e = controller.demand_e.astype(np.float64)
    sat = camera.params.saturation_capacity_e
    x8 = np.where(controller.clip_frames > 0, 255.0, np.minimum(255.0 * e / sat, 254.0))
    kw = dict(pred_8bit=x8, pred_electrons=e, full_well_e=camera.params.full_well_e, sensor=camera.params)
    g = attenuator_transmission(camera, mask, attenuator, e, index)
    levels, fx = levels_and_exposure(camera, mask, index, g, e, controller, attenuator, **kw)
    return levels, g, fx


def controller_view(camera, enc, est, flags, index: int):
    """What the exposure controller takes from a capture, on the mirror grid: the all-white
    electrons the reconstruction implies (a lower bound where clipped), the clipped pixels and
    the exposure each pixel had relative to white (its displayed mask, through the relay)."""
    white_s = camera.white_exposure_s(index)
    e_white = est.astype(np.float64) * camera.electrons_per_radiance() * white_s
    clipped = ((flags.astype(np.int64) & 1) > 0).astype(np.float32)
    rel = np.asarray(enc.exposure_s, dtype=np.float64) / white_s
    sensor, mirror = camera.sensor_grid, camera.mirror_grid

    def placed(x: np.ndarray) -> np.ndarray:
        return camera.to_mirror(OnGrid(x, sensor)).on(mirror).array

    return placed(e_white.astype(np.float32)), placed(clipped) > 0.5, placed(rel.astype(np.float32))


@dataclass(frozen=True)
class MaskDecision:
    """The mask for one frame and how it came about."""

    levels: np.ndarray
    init: bool                       # an all-white initialisation frame
    predict_seconds: float | None    # predictor + mask law (causal predictors)
    fallback_px: int = 0             # prediction pixels that were NaN/Inf and fell back to hold
    transmission: float = 1.0        # the global attenuator's commanded setting (camera/attenuator.py)
    exposure: object | None = None   # the frame's exposure time and DMD bit depth (control/exposure_time.py)
    metered: bool = False            # an initialisation frame dimmed where the last capture clipped (loop.meter_init)


@dataclass(frozen=True)
class DMDCommand:
    """What the DMD and the attenuator do in one frame's exposure window: the levels shown from
    the window's start (`levels`, an OnGrid on the mirror grid; `.array` for the numbers); a late
    mask (`late_levels`, mirror grid too) replaces them at `switch_s` after
    the start (timing_budget.MaskClock); the attenuator's transmission once its command settled
    (camera/attenuator.py); `record` holds the frame's loop entries for report.json (init,
    prediction_fallback_pixels, predict_seconds, timing_budget, attenuator)."""

    levels: OnGrid
    late_levels: OnGrid | None
    switch_s: float | None
    transmission: float
    record: dict
    decision: MaskDecision
    exposure: object | None = None   # the frame's T_e and B (control/exposure_time.py); None: the scene's

    def __post_init__(self):
        for name in ("levels", "late_levels"):
            x = getattr(self, name)
            if x is not None:
                if not isinstance(x, OnGrid):
                    raise TypeError(f"DMDCommand.{name} must be an OnGrid on the mirror grid, "
                                    f"not {type(x).__name__}")
                x.expect("mirror", f"DMDCommand.{name}")

    @property
    def switch(self) -> tuple | None:
        """Camera.capture's `switch` argument: (late levels on the mirror grid, switch time s), or None."""
        return (self.late_levels, self.switch_s) if self.late_levels is not None else None


@dataclass(frozen=True)
class LoopParams:
    """What the loop is built from (scene/resolve.py): the mask law (with any value the scene
    derived, e.g. the controller prior scaled to our beams), the loop mode, the predictor, the
    real-time budget and the attenuator."""

    mask: MaskSpec
    loop: LoopSpec
    predictor: PredictorSpec
    budget: BudgetSpec = BudgetSpec()
    attenuator: AttenuatorSpec = AttenuatorSpec()


class LoopStep:
    """The closed loop's state and its per-frame step (module docstring). State is real here:
    the history of what the predictor has seen (on the predictor grid), the mask clock and the
    attenuator's setting."""

    HISTORY = 4

    def __init__(self, camera, mask: MaskSpec, loop: LoopSpec, predictor: PredictorSpec,
                 model=None, budget: BudgetSpec = BudgetSpec(), attenuator: AttenuatorSpec = AttenuatorSpec()):
        """model: an already built predictor (else built from `predictor`); none for the oracle.
        budget: the real-time budget; `clock` (timing_budget.MaskClock) says when each mask
        reaches the DMD and what each window shows. attenuator: the global variable ND whose
        setting each decision carries (camera/attenuator.py)."""
        self.camera, self.mask, self.loop, self.predictor_spec = camera, mask, loop, predictor
        self.budget = budget
        self.attenuator = attenuator
        self.attenuator_state = AttenuatorState(attenuator)
        self.needs_truth = PREDICTORS[predictor.name].needs_truth
        self.model = None if self.needs_truth else (model or make_predictor(
            predictor.name, predictor.weights, predictor.resolution))
        self.predictor_grid = Grid("predictor", tuple(predictor.resolution))
        self.history: list[OnGrid] = []
        p = camera.params
        self.clock = MaskClock(budget, camera.timing, camera.shape, p.bits, camera.mirror_shape,
                               camera.dmd.spec.bits) if camera.dmd else None
        self.controller = ExposureController(mask.first_guess, exposure_time.clip_step(mask, camera, attenuator),
                                             int(np.ceil(3 * mask.smooth_px)),
                                             p.saturation_capacity_e, mask.carry == "extrapolate",
                                             white_step=mask.clip_step) if camera.dmd else None
        self.miss_px: float | None = None            # the last measured miss (masks.highlight_miss_px)
        self._aimed: np.ndarray | None = None         # the bright mirrors the last mask was computed for

    @property
    def lift(self) -> float:
        """The demodulated loop's assumption for a pixel clipped behind a dimmed mirror (x its
        lower bound): mask.clipped_gain, or where the exposure time does the search after a clip
        the same bracket as the controller's (exposure_time.searches, mask.time_clip_step)."""
        if exposure_time.searches(self.mask, self.camera, self.attenuator):
            return self.mask.time_clip_step
        return self.mask.clipped_gain

    @classmethod
    def from_params(cls, camera, p: LoopParams, model=None) -> "LoopStep":
        """The loop `p` describes, for `camera` (model: an already built predictor)."""
        return cls(camera, p.mask, p.loop, p.predictor, model=model, budget=p.budget, attenuator=p.attenuator)

    def next_mask(self, index: int, truth: np.ndarray | None = None) -> MaskDecision:
        """The mask for frame `index`; `truth` (mirror grid, time-averaged radiance; an OnGrid on
        another grid is refused) for the oracle."""
        truth = self.camera.mirror_grid.take(truth, "the oracle's truth")
        needs = 0 if self.model is None else self.model.needs_frames
        self._aimed = None
        measure = self.mask.envelope != "fixed"
        if index < self.loop.init_frames or len(self.history) < needs:
            if measure and self.needs_truth:        # where a mask would have aimed: the miss is
                self._aimed = self._true_bright(truth, index)   # known on the first loop frame
            elif measure and self.model is not None and len(self.history) >= needs:
                pred, _ = checked_prediction(self.model, [h.on(self.predictor_grid).array for h in self.history])
                self._aimed = self._predicted_bright(resize_onto(OnGrid(pred, self.predictor_grid),
                                                                 self.camera.sensor_grid))
            if self._meters():
                mask = self.frame_mask()
                levels, g, fx = metered_choice(self.camera, mask, self.controller, index, self.attenuator)
                if measure:                         # aimed where the last capture was bright
                    self._aimed = self.controller.demand_e >= self.controller.saturation_e
                return MaskDecision(levels, True, None, transmission=g, exposure=fx, metered=True)
            return MaskDecision(self.camera.white_mask(), True, None)
        mask = self.frame_mask()
        if self.needs_truth:
            levels, g, fx = oracle_choice(self.camera, mask, truth, index, self.attenuator)
            if measure:
                self._aimed = self._true_bright(truth, index)
            return MaskDecision(levels, False, None, transmission=g, exposure=fx)
        t0 = time.perf_counter()
        pred, n_bad = checked_prediction(self.model, [h.on(self.predictor_grid).array for h in self.history])
        pred_s = resize_onto(OnGrid(pred, self.predictor_grid), self.camera.sensor_grid)
        levels, g, fx = predicted_choice(self.camera, mask, pred_s, index,
                                         self.controller, self.loop.mode in MASKED_MODES, self.attenuator)
        if mask.envelope != "fixed":
            self._aimed = self._predicted_bright(pred_s)
        return MaskDecision(levels, False, time.perf_counter() - t0, n_bad, transmission=g, exposure=fx)

    def _meters(self) -> bool:
        """Whether this initialisation frame is metered (`loop.meter_init`): a causal predictor
        under the exposure controller's law, after at least one capture. A white frame says of
        a clipped region only "at least saturated" (plates under our beams are 5-300x over), so
        without it the first loop frame's guess of such a region is the prior; metered, the
        region was measured through a mask dimmed by the prior (or bracketed again where it
        clipped once more), and the first loop frame's mask comes from a measurement."""
        return (self.loop.meter_init and not self.needs_truth and self.mask.law == "exposure_controller"
                and self.controller is not None and self.controller.demand_e is not None)

    def _true_bright(self, truth: np.ndarray, index: int) -> np.ndarray:
        """The mirrors the true frame (the oracle's input) puts at or above saturation, all white."""
        white_e = truth.astype(np.float64) * self.camera.electrons_per_radiance() * self.camera.white_exposure_s(index)
        return white_e >= self.camera.params.saturation_capacity_e

    def _predicted_bright(self, pred_s: OnGrid) -> np.ndarray:
        """The mirrors the prediction puts at or above saturation with the all-white mask (a
        prediction of masked captures demodulated by the last mask, as the controller does)."""
        pred = self.camera.mirror_grid.take(self.camera.to_mirror(pred_s), "the placed prediction")
        x8 = np.nan_to_num(np.asarray(pred, dtype=np.float64), nan=255.0)
        e = predicted_electrons(x8, self.camera.params, self.mask.clipped_gain)
        rel = None if self.controller is None else self.controller.rel
        if self.loop.mode in MASKED_MODES and rel is not None:
            e = np.where(x8 >= 254.5, e, e / np.maximum(rel.astype(np.float64), 1e-9))
        return e >= self.camera.params.saturation_capacity_e

    def envelope_px(self) -> int:
        """The mask envelope's radius for the next frame, mirrors: ceil(3 sigma), sigma from
        `mask.envelope` and the last measured miss (masks.envelope_sigma)."""
        return int(np.ceil(3 * envelope_sigma(self.mask, self.miss_px)))

    def frame_mask(self) -> MaskSpec:
        """The mask settings of the next decision: under `mask.envelope = "predictor_error"` the
        envelope's sigma from the last miss, and the exposure controller's carry radius with it."""
        if self.mask.envelope != "predictor_error":
            return self.mask
        if self.controller is not None:
            self.controller.radius_px = self.envelope_px()
        return dataclasses.replace(self.mask, smooth_px=envelope_sigma(self.mask, self.miss_px))

    def command(self, index: int, truth: np.ndarray | None = None) -> DMDCommand:
        """The DMD command of frame `index`: the mask decision (`next_mask`), what the DMD shows
        of it in the frame's window given when its compute ends (the mask clock), and the
        attenuator's transmission then."""
        decision = self.next_mask(index, truth)
        rec: dict = {}
        if decision.init:
            rec["init"] = True
        if decision.metered:
            rec["metered"] = True
        if decision.fallback_px:
            rec["prediction_fallback_pixels"] = decision.fallback_px     # held the last frame there
        if decision.predict_seconds is not None:
            rec["predict_seconds"] = decision.predict_seconds
        fx = decision.exposure
        preloaded = decision.init and not decision.metered     # a white mask: loaded before the run
        shown = self.clock.show(index, decision.levels, preloaded, decision.predict_seconds, fx)
        if shown.record and not shown.record.get("init"):
            rec["timing_budget"] = {k: v for k, v in shown.record.items() if k != "frame"}
        g = self._attenuator_setting(decision, index, rec)
        if fx is not None:
            rec["exposure_time"] = {**fx.record(), "nd_transmission": g}
        if self.mask.envelope != "fixed" and (not decision.init or decision.metered):
            rec["envelope_px"] = self.envelope_px()
            if self.mask.envelope == "region_body":
                rec["region_envelope_px"] = region_radii(self.controller.region_sigma)
        late = shown.late is not None
        mirror = self.camera.mirror_grid
        return DMDCommand(OnGrid(shown.levels, mirror), OnGrid(shown.late, mirror) if late else None,
                          shown.switch_s if late else None, g, rec, decision, fx)

    def _attenuator_setting(self, decision: MaskDecision, index: int, rec: dict) -> float:
        """The attenuator's transmission in frame `index`: the decision's, unless its command
        (sent when the mask's compute ends) settles after the exposure starts; budget.late_mask
        = 'ideal' takes it as on time, like the mask."""
        if not self.attenuator.enabled:
            return 1.0
        budget = rec.get("timing_budget")
        command_s = None
        if budget and self.budget.late_mask != "ideal":
            command_s = budget["compute_start_s"] + budget["compute_s"]
        rec["attenuator"] = self.attenuator_state.apply(decision.transmission, command_s,
                                                        self.camera.timing.exposure_window_s(index)[0])
        return rec["attenuator"]["transmission"]

    def observe(self, index: int, ldr, enc, est, flags) -> None:
        """Take what the camera saw of frame `index` into the predictor's history and the
        exposure controller's state."""
        if self.controller is not None:
            self.controller.observe(*controller_view(self.camera, enc, est, flags, index))
            if self._aimed is not None:              # where the highlight was against where the mask aimed
                captured = self.controller.demand_e >= self.controller.saturation_e
                if self.mask.envelope == "region_body":        # each region's own miss, no global one
                    self.controller.region_sigma = region_sigma(self._aimed, captured, self.mask.smooth_px,
                                                                ENVELOPE_FLOOR_SIGMA)
                else:
                    miss = highlight_miss_px(self._aimed, captured)
                    self.miss_px = self.miss_px if miss is None else miss
        if self.model is None:
            return
        x = predictor_input(self.loop.mode, self.camera, ldr, enc, est, flags, index, self.lift)
        self.history.append(resize_onto(OnGrid(x, self.camera.sensor_grid), self.predictor_grid))
        self.history = self.history[-self.HISTORY:]
