"""The camera at another scale than its scene file: `--scale S`, `--resolution HxW`, `--dmd-mirrors`
and the environment variable POEVP_SCALE (cli.py) all end here, as `section.key=value` overrides.

A camera at scale k renders the same field with k times the mirrors across it: k = W' / W, the
render's new width over the scene's (the field is set across the width, Mitsuba's default
`fov_axis = "x"`; `--scale` rounds the height to whole pixels too, so the aspect is kept to within
a pixel, and `--resolution` takes the height it is given, the vertical field following the
aspect). Mirrors and sensor pixels keep their pitch; the objective is the same design scaled by
k, so every size the scene states in mirrors or pixels of the image follows:

| key                           | at scale k              | why |
|-------------------------------|-------------------------|-----|
| render.resolution             | [round(H k), round(W k)] | the mirror count (>= 1 each) |
| objective.focal_length_m      | x k                     | the same field on k x the mirrors (tan(theta) = r / f); only where the objective acts (not a delta PSF without vignetting or glare) |
| objective.sigma_px            | x k                     | the `gaussian` objective's blur: a lens scaled by k scales its aberrations by k |
| objective.guard_max_px        | x k, rounded            | the same guard in field angle |
| mask.smooth_px                | x k                     | the mask's envelope follows the image of the highlight (where > 0) |
| attenuator.serve_min_mirrors  | x k^2, rounded, >= 1    | an area in mirrors (where an attenuator is in the path) |
| chart.roi_inset_px            | x k, rounded, >= 1      | the patches' border (on a [chart] scene) |
| predictor.resolution          | = the new render.resolution | only where the scene sets its predictor on the sensor's own grid (predictor.resolution stated and = render.resolution); otherwise the predictor keeps its grid, which sees the same field |

Each value is held within its key's bounds (core/params.py): a camera so small or so large that
a size would leave its range keeps the bound (the headline lists the values).

Not scaled: the relay's keys (`relay.sigma_px`, `support_px`, `glare_sigma_px`, `guard_max_px`:
the relay images mirrors onto sensor pixels of unchanged pitch), `dmd.registration.offset_px`
(sensor pixels), the `[source]` keys in the input frames' own pixels (`guard_px`, `box`,
`reference_pixel`, `r_px` at 720x1280), the plate texture's size (`plate.width_px`, `height_px`),
and every key in metres, seconds or candela.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from fractions import Fraction


#: The keys a scale changes (module table), in the order their overrides are written.
SCALED_KEYS = ("render.resolution", "objective.focal_length_m", "objective.sigma_px", "objective.guard_max_px",
               "mask.smooth_px", "attenuator.serve_min_mirrors", "chart.roi_inset_px", "predictor.resolution")
#: Largest and smallest scale accepted (a 16384-pixel render is the scene's own bound).
MAX_SCALE, MIN_SCALE = 64.0, 1e-4


def parse_scale(text: str) -> float:
    """'1/6', '0.5', '2' -> the scale (a float in [MIN_SCALE, MAX_SCALE]); ValueError with the
    reason otherwise."""
    try:
        value = float(Fraction(str(text).strip()))
    except (ValueError, ZeroDivisionError):
        raise ValueError(f"expected a number or a fraction like 1/6 or 0.5, got {text!r}") from None
    if not math.isfinite(value) or not MIN_SCALE <= value <= MAX_SCALE:
        raise ValueError(f"{text!r} is outside [{MIN_SCALE:g}, {MAX_SCALE:g}]")
    return value


def scale_text(k: float) -> str:
    """1/6 -> '1/6', 2 -> '2x', 0.37 -> '0.37', 1 -> 'full'."""
    if abs(k - 1.0) < 1e-9:
        return "full"
    if k < 1 and abs(1 / k - round(1 / k)) < 1e-6:
        return f"1/{round(1 / k)}"
    if k > 1 and abs(k - round(k)) < 1e-9:
        return f"{round(k)}x"
    return f"{k:.4g}"


@dataclass(frozen=True)
class Scaling:
    """A camera scaled against the scene as given: the scale k = new width / old width, how it
    was asked for (`given`: '--scale 1/6', 'POEVP_SCALE=1/6', '--resolution 180x320',
    '--dmd-mirrors'), the overrides written (`sets`), each changed key's (before, after) and the
    scaled keys left as the user's --set wrote them (`kept`)."""

    scale: float
    given: str
    base_resolution: tuple[int, int]
    sets: tuple[str, ...]
    changes: dict = field(default_factory=dict)
    kept: tuple[str, ...] = ()

    @property
    def resolution(self) -> tuple[int, int]:
        return tuple(self.changes["render.resolution"][1]) if "render.resolution" in self.changes \
            else self.base_resolution


def _bounded(key: str, value):
    """`value` held within the bounds of the params field `key` names (section.key); an open
    bound (gt, lt) is approached to 0.1 %, so the value still prints inside it."""
    import dataclasses

    from poevp_optics.scene.spec import SECTIONS

    section, name = key.split(".")
    meta = next((f.metadata for f in dataclasses.fields(SECTIONS[section]) if f.name == name), {})
    whole = isinstance(value, int)
    if "min" in meta:
        value = max(value, meta["min"])
    if "max" in meta:
        value = min(value, meta["max"])
    if "gt" in meta and value <= meta["gt"]:
        value = meta["gt"] + 1 if whole else meta["gt"] * 1.001
    if "lt" in meta and value >= meta["lt"]:
        value = meta["lt"] - 1 if whole else meta["lt"] * 0.999
    return int(value) if whole else float(value)


def _fmt(key: str, value) -> str:
    """The override text of a scaled value (TOML value syntax)."""
    if isinstance(value, (tuple, list)):
        return f"{key}=[{','.join(str(int(v)) for v in value)}]"
    if key == "objective.focal_length_m":
        return f"{key}={value:.6g}"
    if isinstance(value, int):
        return f"{key}={value}"
    return f"{key}={value:.4g}"


def scaled_values(spec, resolution: tuple[int, int]) -> tuple[float, dict]:
    """(k, {key: (value in `spec`, value at the new `resolution`)}) for every key of the module
    table that applies to `spec` and changes; k = new width / old width."""
    h0, w0 = (int(v) for v in spec.render.resolution)
    h, w = (int(v) for v in resolution)
    k = w / w0
    out: dict = {}
    if (h, w) != (h0, w0):
        out["render.resolution"] = ((h0, w0), (h, w))

    def size(key, value, digits=".4g", area=False, least=None):
        new = value * (k * k if area else k)
        new = round(new) if isinstance(value, int) else float(f"{new:{digits}}")
        out[key] = (value, _bounded(key, new if least is None else max(least, new)))

    obj = spec.objective
    if not obj.is_identity:
        size("objective.focal_length_m", obj.focal_length_m, ".6g")
        if obj.psf == "gaussian":
            size("objective.sigma_px", obj.sigma_px)
        size("objective.guard_max_px", obj.guard_max_px)
    if spec.mask.smooth_px > 0:
        size("mask.smooth_px", spec.mask.smooth_px)
    if spec.attenuator.enabled:
        size("attenuator.serve_min_mirrors", spec.attenuator.serve_min_mirrors, area=True, least=1)
    if spec.chart.patches:
        size("chart.roi_inset_px", spec.chart.roi_inset_px, least=1)
    stated = isinstance(spec.raw.get("predictor"), dict) and "resolution" in spec.raw["predictor"]
    if stated and tuple(spec.predictor.resolution) == (h0, w0):
        out["predictor.resolution"] = ((h0, w0), (h, w))
    return k, {key: v for key, v in out.items() if v[0] != v[1]}


def scaled_resolution(resolution, k: float) -> tuple[int, int]:
    """The render's [H, W] at scale k: each rounded to whole pixels, at least 1."""
    return tuple(max(1, round(int(v) * k)) for v in resolution)


def scaling_for(spec, resolution: tuple[int, int], given: str, explicit=frozenset()) -> Scaling:
    """The Scaling that renders `spec` (the scene with the user's --set applied) at `resolution`:
    overrides for every key of the module table that changes, except those in `explicit` (keys
    the user's --set gave: taken as written, so the caller applies them after these)."""
    k, changes = scaled_values(spec, resolution)
    kept = tuple(key for key in changes if key in explicit)
    changes = {key: v for key, v in changes.items() if key not in explicit}
    sets = tuple(_fmt(key, new) for key, (_, new) in changes.items())
    return Scaling(k, given, tuple(int(v) for v in spec.render.resolution), sets, changes, kept)
