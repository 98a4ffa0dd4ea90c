"""A global variable attenuator before the DMD: the dynamic range the 8-bit mask cannot give.

An 8-bit PWM mask dims a mirror at most to 1/255 of the window (plus the off-state leakage
1/CR): with `mask.min_level` 1 and CR 1000:1, 1/(1/255 + 1/1000) = 203x, so a highlight aimed at
`mask.target` 0.6 of full scale can be at most 0.6 x 203 = 122x over saturation. A plate under
high beams at short range is more (night_road at 10x its beams: 200-640x). The camera's
exposure cannot shorten instead: the 8-bit window needs >= 255 x 105 us = 26.8 ms
(camera/dmd.py). What a camera does then is dim the whole image: an electronically variable
neutral-density filter (liquid crystal) in the objective's path, transmission g per frame, set
with the mask by the exposure controller. Every mirror's exposure is multiplied by g, so the
capture's per-pixel exposure (and the reconstruction, which divides by it) carries g exactly;
where a region needs less dimming than g gives, its mask level rises to compensate, up to white
(a dark region loses signal: g dims it too, the price of the global stage).

| key                 | type  | unit    | default | meaning |
|---------------------|-------|---------|---------|---------|
| kind                | str   | -       | none    | `none` (no attenuator) or `variable_nd` |
| min_transmission    | float | -       | 1/128   | darkest setting (7 stops: Sony's electronic variable ND spans 1/4-1/128) |
| settle_s            | float | s       | 0.02    | time from command (the mask's compute end) to the new transmission (LC: ms to tens of ms) |
| serve_min_mirrors   | int   | mirrors | 24      | the attenuator dims the frame only for a highlight this many mirrors large or larger |

Choice of g (`choose_transmission`): from the exposure controller's per-mirror demand D of the
last capture (the electrons each mirror would send with the all-white mask and the clear
attenuator; measured where not clipped, the bracket's guess where clipped; not dilated), the
over-reach O = D / D_reach, D_reach = the all-white electrons that the darkest usable level puts
at the aim; the highlights are the 8-connected regions where O > 1, and those of at least
N = serve_min_mirrors mirrors are served: g = 1 / (the highest O in them), clamped to
[min_transmission, 1] (1 when none). Smaller highlights are left to clip rather than darken the
whole frame for them: on night_road at 184x320 the oncoming lamps' 90 mm lenses at 60-80 m
clip over 4-6 mirrors each after the objective's PSF (9-15 with ten times their light), the
520 x 110 mm plate's region beyond reach covers 37-73 mirrors from 60 m on; N = 24 tells them
apart. (Measured on the dilated demand the mask law uses, the lamps spread over 34-55 mirrors
and would dim the whole frame 5x at the scene's own beams.) A command that would settle after the frame's
exposure starts is late: the previous transmission holds for that frame (`AttenuatorState`).

Sources: Sony electronic variable ND filter, 1/4-1/128 (2-7 stops), PXW-FS5 / FX9 product
specifications; liquid-crystal attenuators switch in milliseconds to tens of milliseconds
(e.g. Thorlabs LCC1620 liquid crystal variable attenuator, response times in its manual).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poevp_optics.core.params import param
from poevp_optics.core.registry import Registry

ATTENUATORS = Registry("attenuator")


@dataclass(frozen=True)
class AttenuatorSpec:
    """[attenuator]: a global variable ND before the DMD (module docstring)."""

    kind: str = param("none", choices=ATTENUATORS)
    min_transmission: float = param(1.0 / 128.0, gt=0, max=1.0)
    settle_s: float = param(0.02, min=0, max=10.0)
    serve_min_mirrors: int = param(24, min=1, max=1 << 26)

    @property
    def enabled(self) -> bool:
        return ATTENUATORS[self.kind] is not None


def choose_transmission(demand_e: np.ndarray, reach_e: float, spec: AttenuatorSpec) -> float:
    """Transmission g in [min_transmission, 1] for a frame whose mirrors would send `demand_e`
    electrons with the all-white mask and a clear attenuator; `reach_e`: the most electrons the
    darkest usable mask level still brings to the aim (module docstring). 1 when disabled."""
    rule = ATTENUATORS[spec.kind]
    return 1.0 if rule is None else rule(demand_e, reach_e, spec)


def _largest_regions_rule(demand_e: np.ndarray, reach_e: float, spec: AttenuatorSpec) -> float:
    """g = 1 / (the highest over-reach within any highlight of >= serve_min_mirrors mirrors),
    clamped to [min_transmission, 1] (module docstring)."""
    import cv2

    d = np.nan_to_num(np.asarray(demand_e, dtype=np.float64), nan=np.inf, posinf=np.inf)
    if d.ndim != 2 or not reach_e > 0:
        raise ValueError(f"attenuator: demand must be a 2-D mirror map and reach > 0 (got {d.shape}, {reach_e!r})")
    over = d / float(reach_e)
    beyond = (over > 1.0).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(beyond, connectivity=8)
    served = [i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= spec.serve_min_mirrors]
    if not served:
        return 1.0
    peak = max(float(over[labels == i].max()) for i in served)
    return float(max(spec.min_transmission, 1.0 / peak))


ATTENUATORS.register("none", None, source="no attenuator: the mask alone sets each mirror's exposure")
ATTENUATORS.register("variable_nd", _largest_regions_rule,
                     source="liquid-crystal variable ND (Sony electronic variable ND 1/4-1/128; "
                     "Thorlabs LCC1620 LC attenuator), g from the brightest highlight of >= N mirrors")


class AttenuatorState:
    """The transmission in force frame by frame. State is real: the filter's setting."""

    def __init__(self, spec: AttenuatorSpec):
        self.spec = spec
        self.transmission = 1.0

    def apply(self, commanded: float, command_s: float | None, exposure_start_s: float) -> dict:
        """Set the transmission for a frame whose exposure starts at `exposure_start_s` (s): the
        commanded value if it was sent (`command_s`, s; None: preset before the run, e.g. the
        white initialisation frames) at least settle_s before, else the previous one holds."""
        ready = None if command_s is None else command_s + self.spec.settle_s
        late = ready is not None and ready > exposure_start_s
        if not late:
            self.transmission = float(commanded)
        return {"commanded": float(commanded), "transmission": self.transmission, "late": bool(late),
                **({"ready_s": ready} if ready is not None else {})}
