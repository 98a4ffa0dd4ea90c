"""The exposure controller's coarse stage: the sensor's exposure time T_e and the DMD's bit depth B per frame.

Why. The mask dims a mirror by PWM: with B bit-planes a level q passes q / (2^B - 1) of the
light (plus the off-state leakage 1 / contrast_ratio). A highlight 1e3-1e4x over saturation at
the scene's exposure needs a transmission of 1e-3 to 1e-4, i.e. levels 0-6 of 255, where one
step changes the transmission by 17-100 %: the mask can no longer shape the highlight (a plate's
ends fall to the lowest levels) and below 1 / contrast_ratio it cannot reach it at all. The
global variable ND (camera/attenuator.py) takes ~20 ms to settle, so at 30 fps with 30 ms
exposures it cannot follow a frame. The sensor's exposure time needs no settling: it is set per
frame, causally, like the mask.

What. Per frame, from the controller's demand (through the ND's setting), the controller picks

- T_e, the sensor's exposure, centred on the scene's exposure (the frame still shows the middle
  of its slot), within [`shortest_exposure_s`, timing.exposure_s]: the shortest is the sensor's
  minimum (SENSOR_MIN_EXPOSURE_S) or the shortest window holding the mask's dmd.bits planes,
  (2^bits - 1) t_p, t_p the controller's shortest plane (camera/dmd.py DMD_CONTROLLERS; 105 us
  on the DLPC900, whose shorter planes need an LED gated off, which a camera imaging the
  scene's own light has not): 26.8 ms for 8 bits there, so on the DLPC900 T_e moves only
  between 26.8 and 30 ms (below, "Shortest choice");
- B, the largest bit depth whose PWM fits T_e with every plane >= t_p, (2^B - 1) t_p <= T_e,
  B <= dmd.bits: dmd.bits for every chosen T_e; fewer only for a fixed T_e (`at_exposure`:
  below the shortest 2-bit window, 3 t_p, the mask is binary, its one pattern shown for
  max(T_e, t_p) around the exposure). The DMD shows its B planes in a window equal to the
  exposure, so the duty integral is the closed form q / (2^B - 1) over the exposure; a mirror
  shows the top B bits of its mask level (camera/dmd.py `displayed_levels`; the DLPC900 takes a
  B-bit pattern from a bit field of the stored image);

so that the reference demand D_ref lands at the aim (`mask.target` x full scale) at the fine
level: `mask.fine_steps` (20) steps above zero, a step of 5 %, or the top level when B has fewer
levels. The coarse attenuation is then in T_e (and in the ND where it can settle), and the mask
keeps the highlight's mirrors in their fine range instead of at levels 1-6. D_ref follows the
attenuator's rule (camera/attenuator.py): from the controller's demand of the last capture (the
frame's own for the oracle; not dilated), through the ND's setting, the highlights beyond the
fine level's reach at the scene's exposure (the demand the fine level brings to the aim: 7.6x
saturation at 8 bits) of at least `attenuator.serve_min_mirrors` mirrors are served, each at the
demand its brightest serve_min_mirrors mirrors share, and D_ref is the highest of these. A lamp
core smaller than that is left to the low levels rather than darken the frame; a frame with no
served highlight keeps the scene's exposure. With a variable ND in the path (it settles within
the scene's frame timing, or the scene is refused) the ND keeps the coarse part as before: T_e
serves only what the ND's setting leaves beyond the mask's reach (its darkest usable level, the
attenuator's own threshold), e.g. beyond the ND's darkest setting.

A frame that keeps the scene's exposure keeps its [timing] schedule and dmd.bits
(`FrameExposure.nominal`): its capture is the same as without this stage. A shorter T_e darkens
the whole frame by T_e / timing.exposure_s (the mask can only dim), the price of bringing a
highlight into range.

Search after a clip. A clipped capture says only "at least the lower bound L". The mask's demand
brackets by `mask.clip_step` (2) per frame because its 8-bit levels round coarsely; T_e is
continuous and a capture well below the band is still measured (a 12-bit capture at 1 % of full
scale holds ~100 e- of a ~10 ke- well: SNR ~10), so with this stage the controller brackets a
region clipped again by `mask.time_clip_step` (100) x L (control/loop_step.py builds the
ExposureController so): the next capture is unclipped for any X < time_clip_step x L / target,
and the one after is exact. A region clipped behind a white mirror at the scene's exposure
(the white initialisation frames: L is only ~1x) keeps `mask.clip_step` and so the controller's
prior (`mask.first_guess`). With a variable ND in the path the search stays the ND's
(`mask.clip_step`, which such a scene sets for its ND: night_road's 5 lands a plate 10x brighter
than its prior in the band on the frame after the clip). A plate 1e4x over saturation is then
in the band on the third loop frame (tests).

Shortest choice: the controller never shortens T_e below (2^dmd.bits - 1) t_p (26.8 ms for
8 bits on the DLPC900; the sensor's minimum with an ideal controller), `shortest_exposure_s`.
With planes at their shortest t_p, a mirror's smallest step passes t_p x the radiance whatever
T_e is: a highlight that needs an on-time tau of white-equivalent exposure sits at level
tau / t_p, so shortening T_e further only removes bits (the darker parts of the frame get
coarser) and never brings the highlight to a finer level. On the DLPC900 the fine range at the
aim therefore needs tau >= fine_steps x t_p = 2.1 ms, i.e. a highlight at most ~9x over
saturation at 30 ms: beyond, only the ND (which dims the light itself) or gated illumination
helps. Measured on the paper protocol with the DLPC900 and T_e allowed down to the 5-bit window
(3.26 ms), the plate sat at levels 0-6 of 31 and read less than at 30 ms. A fixed T_e may be
shorter: B then falls (binary below 315 us; the report's `binary_mask`).

Fixed T_e: `mask.exposure_time_s` > 0 sets T_e for every frame (B from it as above; the
scene's own timing.exposure_s gives the scene's schedule); 0 (default) lets the controller
choose. Bounds: SENSOR_MIN_EXPOSURE_S <= T_e <= timing.exposure_s (`exposure_time_problem`).

Sensor minimum. FACTS.md has no minimum exposure for the Pregius IMX250/253 family. Their
global shutter is set in steps of one line time (a few us) and camera makers list minimum
exposures from a few us to about 20 us; the conservative 20 us is taken here (to be checked
against the camera's own manual).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poevp_optics.camera.dmd import frame_schedule  # noqa: F401  (the schedule of a choice)

#: Shortest sensor exposure (s) the controller uses: conservative figure for Pregius
#: IMX250/253 cameras (module docstring).
SENSOR_MIN_EXPOSURE_S = 20e-6


@dataclass(frozen=True)
class FrameExposure:
    """One frame's exposure choice: the sensor's exposure T_e (s), the DMD's bit-planes B, its
    window (s; = T_e, or one plane's minimum display time around a shorter binary exposure), the
    ND transmission commanded with it, whether it is the scene's own schedule (`nominal`) and
    whether T_e was fixed by the scene."""

    exposure_s: float
    bits: int
    window_s: float
    nominal: bool
    nd_transmission: float = 1.0
    fixed: bool = False

    def record(self) -> dict:
        """The frame's entry in report.json."""
        return {"exposure_s": self.exposure_s, "dmd_bits": self.bits, "dmd_window_s": self.window_s,
                "nd_transmission": self.nd_transmission, "binary_mask": self.bits == 1,
                "scene_timing": self.nominal, "fixed": self.fixed}


def min_plane_s(dmd_spec) -> float:
    """The DMD controller's shortest bit-plane (s; camera/dmd.py DMD_CONTROLLERS)."""
    from poevp_optics.camera.dmd import DMD_CONTROLLERS

    return DMD_CONTROLLERS[dmd_spec.controller].min_plane_s


def max_bits(exposure_s: float, plane_s: float, mask_bits: int) -> int:
    """Largest B <= mask_bits whose PWM fits the exposure with every plane >= plane_s:
    (2^B - 1) plane_s <= exposure_s; 1 (a binary mask) when not even 2 bits fit."""
    b = mask_bits
    while b > 1 and ((1 << b) - 1) * plane_s > exposure_s * (1 + 1e-12):
        b -= 1
    return b


def fine_relative(bits: int, fine_steps: int, contrast_ratio: float) -> float:
    """Exposure of the fine level relative to white at B bits: d + (1 - d) / contrast_ratio,
    d = min(fine_steps, 2^B - 1) / (2^B - 1) (settle time neglected; the mask law uses the exact
    table)."""
    top = (1 << bits) - 1
    d = min(fine_steps, top) / top
    return d + (1.0 - d) / contrast_ratio


def nominal(camera) -> FrameExposure:
    """The scene's own schedule as a choice."""
    t = camera.timing
    return FrameExposure(t.exposure_s, camera.dmd_spec.bits, t.dmd_window_s, True)


def at_exposure(camera, exposure_s: float, nd: float = 1.0, fixed: bool = False) -> FrameExposure:
    """The choice for a given T_e (s): the scene's schedule at timing.exposure_s, else the
    largest B that fits (`max_bits`) in a window equal to the exposure (one plane's minimum
    for a binary mask under a shorter exposure)."""
    t, spec = camera.timing, camera.dmd_spec
    if exposure_s >= t.exposure_s * (1 - 1e-12):
        return FrameExposure(t.exposure_s, spec.bits, t.dmd_window_s, True, nd, fixed)
    plane = min_plane_s(spec)
    b = max_bits(exposure_s, plane, spec.bits)
    window = max(exposure_s, plane) if b == 1 else exposure_s
    return FrameExposure(float(exposure_s), b, float(window), False, nd, fixed)


def reference_demand(demand_e: np.ndarray, reach_e: float, min_mirrors: int) -> float:
    """D_ref (e-, all-white at the scene's exposure): over the highlights beyond `reach_e`
    (8-connected regions, demand > reach_e) of at least `min_mirrors` mirrors, the highest
    demand that `min_mirrors` mirrors of one highlight share (its min_mirrors-th brightest); 0
    when there is none. As the attenuator's rule (camera/attenuator.py): a lamp core smaller than
    that is left to the low levels rather than darken the frame, and a plate is served at its
    own brightness."""
    import cv2

    d = np.nan_to_num(np.asarray(demand_e, dtype=np.float64), nan=1e300, posinf=1e300)
    beyond = (d > reach_e).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(beyond, connectivity=8)
    best = 0.0
    for i in range(1, n):
        if stats[i, cv2.CC_STAT_AREA] >= min_mirrors:
            vals = d[labels == i]
            best = max(best, float(np.partition(vals, vals.size - min_mirrors)[vals.size - min_mirrors]))
    return best


def shortest_exposure_s(dmd_spec) -> float:
    """The shortest T_e the controller chooses (s): the sensor's minimum, or the shortest window
    that keeps the mask's full bit depth, (2^bits - 1) t_p (26.8 ms for 8 bits on the DLPC900),
    whichever is longer. Below it the planes stay at t_p, so the light a mirror's smallest step
    passes (t_p x radiance) does not shrink while the mask loses bits (module docstring)."""
    return max(SENSOR_MIN_EXPOSURE_S, ((1 << dmd_spec.bits) - 1) * min_plane_s(dmd_spec))


def choose(camera, mask, demand_e: np.ndarray, index: int, nd: float = 1.0, min_mirrors: int = 24,
           with_nd: bool = False) -> FrameExposure:
    """T_e and B for frame `index` (module docstring). demand_e: the all-white electrons per
    mirror at the scene's exposure, before the ND (the controller's demand of the last capture,
    or the frame's where no capture was measured; mirror grid); nd: the ND's transmission;
    min_mirrors: the smallest highlight served (attenuator.serve_min_mirrors); with_nd: a
    variable ND is in the path (it takes the coarse part: T_e only for what it leaves beyond
    the mask's reach)."""
    from poevp_optics.control.exposure_control import full_scale_electrons
    from poevp_optics.control.masks import reach_electrons

    if mask.exposure_time_s > 0:
        return at_exposure(camera, mask.exposure_time_s, nd, fixed=True)
    p, spec, t = camera.params, camera.dmd_spec, camera.timing
    table = camera.level_exposure_s(index)
    white_nom = float(table[-1])
    e_aim = float(full_scale_electrons(p, mask.target))
    if with_nd:     # the ND took the coarse part: only what it leaves beyond the darkest usable level
        threshold = reach_electrons(mask, len(table) - 1, table, p)
    else:           # what the fine level brings to the aim at the scene's exposure
        threshold = e_aim * white_nom / float(table[min(mask.fine_steps, len(table) - 1)])
    d_ref = reference_demand(np.asarray(demand_e, dtype=np.float64) * nd, threshold, min_mirrors)
    if d_ref <= 0:
        return nominal(camera) if nd == 1.0 else FrameExposure(t.exposure_s, spec.bits, t.dmd_window_s, True, nd)
    from poevp_optics.camera.dmd import throughput_on

    thr = throughput_on(spec)
    fine = fine_relative(spec.bits, mask.fine_steps, spec.contrast_ratio)
    te = e_aim / (d_ref * fine) * white_nom / thr       # D_ref at the fine level at the aim
    te = float(min(max(te, shortest_exposure_s(spec)), t.exposure_s))   # >= the full-depth window: B = dmd.bits
    return at_exposure(camera, te, nd)


def exposure_time_problem(mask, dmd_spec, timing) -> tuple[str, str] | None:
    """(key, message) when the scene's fixed T_e (`mask.exposure_time_s`) is impossible, else None."""
    te = mask.exposure_time_s
    if te <= 0:
        return None
    if te > timing.exposure_s * (1 + 1e-12):
        return ("mask.exposure_time_s", f"{te:g} s is longer than the scene's exposure timing.exposure_s = "
                f"{timing.exposure_s:g} s, the slot its radiance is rendered for: use <= {timing.exposure_s:g} s "
                "(0: the controller chooses per frame)")
    if te < SENSOR_MIN_EXPOSURE_S * (1 - 1e-12):
        return ("mask.exposure_time_s", f"{te:g} s is shorter than the sensor's minimum exposure "
                f"{SENSOR_MIN_EXPOSURE_S * 1e6:g} us: use >= {SENSOR_MIN_EXPOSURE_S:g} s (0: the controller "
                "chooses per frame)")
    return None


#: The least span timing.exposure_s / shortest_exposure_s for which T_e is chosen per frame: one
#: mask bracket (`mask.clip_step`'s default 2). On the DLPC900 at 28-30 ms frames T_e spans only
#: 1.04-1.12x (the full 8-bit window is 26.8 ms), so it stays at the scene's exposure there.
MIN_TIME_SPAN = 2.0


def is_active(mask, camera) -> bool:
    """True when the frame's exposure is chosen here: the exposure controller's law with a DMD,
    and T_e fixed by the scene (`mask.exposure_time_s`) or chosen per frame
    (`mask.exposure_time_auto`) where it spans at least MIN_TIME_SPAN.

    Per-frame choice is opt-in. Measured with the ideal controller (its T_e spans ~1400x) in the
    quick evaluation (highbeam_plate, 40 px/frame, E = 9), it brought the plate's mirrors to their
    fine levels but lowered whole-frame reads (flow 2/3 -> 0/3), as on the paper's protocol at
    E = 49 (oracle 5/6 -> 0/6): one exposure for the frame sets the highlight's centre at the fine
    level and the plate's far end below what the detector finds (docs/physics/exposure-time.md)."""
    if mask.law != "exposure_controller" or camera.dmd is None:
        return False
    if mask.exposure_time_s > 0:
        return True
    span = camera.timing.exposure_s / shortest_exposure_s(camera.dmd_spec)
    return bool(mask.exposure_time_auto) and span >= MIN_TIME_SPAN


def searches(mask, camera, attenuator=None) -> bool:
    """True when T_e does the search after a clip: chosen per frame, no variable ND in the path
    (with an ND the search is the ND's, bracketed as the scene set it for the ND), and T_e able
    to span the bracket, timing.exposure_s / shortest_exposure_s >= `mask.time_clip_step`. On the
    DLPC900 at a 28-30 ms exposure T_e spans only 28 / 26.8 = 1.04x: the mask does the search with
    its own `mask.clip_step`, since a 100x bracket the exposure time cannot follow would push the
    mask itself to its coarse lowest levels."""
    nd = attenuator is not None and attenuator.enabled
    if not is_active(mask, camera) or mask.exposure_time_s > 0 or nd:
        return False
    return camera.timing.exposure_s / shortest_exposure_s(camera.dmd_spec) >= mask.time_clip_step


def clip_step(mask, camera, attenuator=None) -> float:
    """The controller's bracket after a repeated clip: `mask.time_clip_step` where T_e searches
    (`searches`), else `mask.clip_step`."""
    return mask.time_clip_step if searches(mask, camera, attenuator) else mask.clip_step


__all__ = ["FrameExposure", "SENSOR_MIN_EXPOSURE_S", "at_exposure", "choose", "clip_step", "exposure_time_problem",
           "fine_relative", "frame_schedule", "is_active", "max_bits", "min_plane_s", "nominal", "reference_demand",
           "searches", "shortest_exposure_s"]
