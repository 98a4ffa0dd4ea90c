"""Retroreflective road markings: a Mitsuba BSDF `road_marking` whose coefficient of retroreflected
luminance R_L is an EN 1436 class's at the standard 30 m geometry.

XML (`type="road_marking"`):

| property      | type             | unit | default | meaning |
|---------------|------------------|------|---------|---------|
| `marking`     | string           | -    | -       | `en1436:R2` ... `:R5` (dry), `en1436:RW1` ... `:RW4` (wet), or `rl:<mcd m-2 lx-1>` |
| `reflectance` | spectrum/texture | 1    | 0       | diffuse base (the marking's daytime whiteness, Lambertian) |
| `retro_tint`  | spectrum/texture | 1    | 1       | spectral factor (<= 1) on the retroreflection (yellow markings) |

[marking.<param>] keys (`MarkingSpec`, bound to `$<param>` as the `marking` string):

| key    | type | unit | default | meaning |
|--------|------|------|---------|---------|
| source | str  | -    | -       | `en1436:<class>` or `rl:<value in mcd m-2 lx-1>` |

Coefficient of retroreflected luminance (EN 1436:2018 section 4.3; CIE 54.2-2001): R_L = L / E_perp
in mcd m-2 lx-1, L the marking's luminance seen by the driver, E_perp the illuminance at the marking
on a plane perpendicular to the incident light. The standard ("30 m") geometry: a driver's eye
1.2 m and a headlamp 0.65 m above the road, 30 m from the marking, so the observation angle to the
road plane is 2.29 deg and the illumination angle 1.24 deg (EN 1436:2018 Annex B), coplanar.
Classes are the minimum R_L of new or maintained white markings: dry R2 >= 100, R3 >= 150,
R4 >= 200, R5 >= 300 (EN 1436:2018 Table 4); wet (measured 1 min after a bucket of water, EN 1436
Annex B.5) RW1 >= 25, RW2 >= 35, RW3 >= 50, RW4 >= 75 (EN 1436:2018 Table 5). A class stands for
its minimum: `en1436:R3` gives R_L = 150 exactly at the standard geometry.

The model reuses the retroreflective sheeting (retroreflective.py): R_L = R_A / cos(theta_v)
(CIE 54.2), so a marking is a sheeting whose R_A(alpha, beta) table is built from R_L, with alpha
the angle between the illumination and observation directions (1.05 deg at the standard geometry)
and beta the angle of their bisector from the road's normal (88.235 deg there). Angular falloff
away from the standard geometry (a documented modelling choice; EN 1436 fixes one geometry only):

  * in alpha, the glass beads' divergence profile of beaded sheeting: R_A ~ alpha^-p with
    p = ln(70 / 30) / ln(0.5 / 0.2) = 0.925, the ASTM D4956 Type I (enclosed glass beads) white
    minimums at 0.2 and 0.5 deg (retroreflective.py's `astm_d4956:I`), normalised to the class at
    1.05 deg; held below 0.2 deg and continued beyond the table as the sheeting's tail;
  * in entrance angle, R_L held at its value for that alpha (R_A = R_L cos(theta_v), theta_v =
    beta - alpha / 2 in the coplanar geometry), from 60 deg to 89.5 deg; held below 60 deg.

So a marking seen from 60 m (alpha ~ 0.5 deg) returns 2x its 30 m R_L and from 15 m (alpha ~ 2.1
deg) about half, as the bead profile says; measured markings differ with bead size and embedment.
The nodes hold (1.05 deg, 88.235 deg) exactly, so the class value is reproduced there to float
precision. The retroreflective efficiency bound is the beaded sheeting's (10 %, retroreflective.py).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

from poevp_optics.core.params import param
from poevp_optics.render.materials import retroreflective as _retro
from poevp_optics.render.materials.retroreflective import BEADED_EFFICIENCY, SheetingError, SheetingTable

#: EN 1436:2018 Annex B standard geometry: angles to the road plane (deg), and the distance (m).
ILLUMINATION_DEG = 1.24
OBSERVATION_DEG = 2.29
STANDARD_DISTANCE_M = 30.0

_EN1436 = "EN 1436:2018 Road marking materials - Road marking performance for road users"
#: Minimum R_L (mcd m-2 lx-1) of each class: dry (Table 4) and wet (Table 5).
MARKING_CLASSES: dict[str, float] = {
    "R2": 100.0, "R3": 150.0, "R4": 200.0, "R5": 300.0,
    "RW1": 25.0, "RW2": 35.0, "RW3": 50.0, "RW4": 75.0,
}
#: The bead divergence exponent: ASTM D4956 Type I white, R_A 70 -> 30 from 0.2 -> 0.5 deg.
BEAD_EXPONENT = math.log(70.0 / 30.0) / math.log(0.5 / 0.2)
#: Table nodes: observation angles (deg, the standard's 1.05 among them) and entrance angles.
ALPHA_NODES_DEG = (0.2, 0.5, OBSERVATION_DEG - ILLUMINATION_DEG, 2.0)
BETA_NODES_DEG = (60.0, 80.0, 85.0, 90.0 - (OBSERVATION_DEG + ILLUMINATION_DEG) / 2, 89.5)


def standard_geometry_deg() -> tuple[float, float, float]:
    """(alpha, beta of the bisector, theta_v) in deg of EN 1436's 30 m geometry, coplanar."""
    alpha = OBSERVATION_DEG - ILLUMINATION_DEG
    return alpha, 90.0 - (OBSERVATION_DEG + ILLUMINATION_DEG) / 2, 90.0 - OBSERVATION_DEG


def parse_marking(text: str) -> float:
    """`en1436:<class>` or `rl:<value>` -> R_L at the standard geometry (mcd m-2 lx-1)."""
    if not isinstance(text, str) or ":" not in text:
        raise SheetingError(f"marking {text!r}: expected 'en1436:<class>' ({', '.join(MARKING_CLASSES)}) "
                            "or 'rl:<mcd m-2 lx-1>'")
    kind, _, value = (p.strip() for p in text.partition(":"))
    if kind == "en1436":
        if value not in MARKING_CLASSES:
            raise SheetingError(f"marking {text!r}: unknown EN 1436 class (known: {', '.join(MARKING_CLASSES)})")
        return MARKING_CLASSES[value]
    if kind == "rl":
        try:
            r_l = float(value)
        except ValueError:
            raise SheetingError(f"marking {text!r}: R_L must be a number in mcd m-2 lx-1") from None
        if not 0 < r_l <= 5000:
            raise SheetingError(f"marking {text!r}: R_L must be in (0, 5000] mcd m-2 lx-1")
        return r_l
    raise SheetingError(f"marking {text!r}: unknown kind {kind!r} (known: en1436, rl)")


@functools.lru_cache(maxsize=32)
def marking_table(r_l_mcd: float) -> SheetingTable:
    """The R_A table (cd lx-1 m-2) of a marking with R_L = r_l_mcd at the standard geometry
    (module docstring: bead profile in alpha, R_L held in beta)."""
    a0 = ALPHA_NODES_DEG[2]
    r_l = r_l_mcd * 1e-3
    rows = tuple(tuple(r_l * (a / a0) ** -BEAD_EXPONENT * math.cos(math.radians(b - a / 2))
                       for a in ALPHA_NODES_DEG) for b in BETA_NODES_DEG)
    return SheetingTable(f"marking R_L {r_l_mcd:g} mcd m-2 lx-1", ALPHA_NODES_DEG, BETA_NODES_DEG, rows,
                         BEADED_EFFICIENCY, f"{_EN1436}; bead profile of ASTM D4956 Type I")


@dataclass(frozen=True)
class MarkingSpec:
    """[marking.<param>]: a road marking's retroreflection bound to `$<param>` of a `road_marking`
    BSDF: an EN 1436 class or an R_L value (module docstring)."""

    source: str = param()


class _RoadMarkingBSDFMethods:
    """Mitsuba BSDF `road_marking`: the sheeting lobe of `marking_table` (module docstring)."""

    def __init__(self, props):
        _retro.mi.BSDF.__init__(self, props)
        if "marking" not in props.keys():
            raise SheetingError("road_marking BSDF: the 'marking' property is required")
        self.r_l_mcd = parse_marking(str(props["marking"]))
        self._init_law(marking_table(self.r_l_mcd), props)

    def to_string(self):
        return f"RoadMarkingBSDF[R_L={self.r_l_mcd:g} mcd m-2 lx-1, tail_sigma_deg={self.law.tail_sigma_deg:.3f}]"


def register() -> None:
    """Register `road_marking` with the active Mitsuba variant (materials.register_plugins)."""
    import mitsuba as mi

    _retro._make_bsdf_class()           # binds the sheeting methods' Mitsuba module
    methods = {k: v for k, v in vars(_retro._RetroreflectiveBSDFMethods).items()
               if k not in ("__dict__", "__weakref__", "__module__", "__doc__")}
    methods.update({k: v for k, v in vars(_RoadMarkingBSDFMethods).items()
                    if k not in ("__dict__", "__weakref__", "__module__")})
    cls = type("RoadMarkingBSDF", (mi.BSDF,), methods)
    mi.register_bsdf("road_marking", lambda props: cls(props))
