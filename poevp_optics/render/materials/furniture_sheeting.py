"""Retroreflection of road furniture: sign sheeting classes (EN 12899-1), delineator reflectors
(EN 12899-3) and road studs (EN 1463-1), as R_A tables of the sheeting model (retroreflective.py).

Sheeting sources (the `source` of a `[sheeting.<param>]` entry, or a `retroreflective` BSDF's
`sheeting` string), beside retroreflective.py's `astm_d4956:*`:

| source           | what | R_A at 12' (0.2 deg) / +5 deg (cd lx-1 m-2) |
|------------------|------|---------------------------------------------|
| `en12899_1:RA1`  | sign sheeting class RA1 (engineering grade, enclosed glass beads) | 50 |
| `en12899_1:RA2`  | sign sheeting class RA2 (high intensity, encapsulated beads or prisms) | 180 |
| `en1463_1:PRP1`  | road stud reflector, per m2 of the stud's lens (STUD_LENS_M) | R / A = 0.22 / A |

EN 12899-1:2007 (Fixed, vertical road traffic signs - Part 1: Fixed signs), Table 3 (class RA1)
and Table 4 (class RA2): minimum R_A of white sheeting at observation angles alpha = 12', 20', 2
deg and entrance angles beta1 = +5, +30, +40 deg (beta2 = 0):

    RA1 white   beta 5    30    40        RA2 white   beta 5    30    40
    alpha 12'        50    24    9.0      alpha 12'        180   100   95
    alpha 20'        35    16    6.0      alpha 20'        140   75    65
    alpha 2 deg      5.0   2.5   1.5      alpha 2 deg      5.0   2.5   1.5

(as we read the standard's tables; the class names and ASTM equivalents are in FACTS.md; the
numbers were not checked against a copy of the standard in this project). EN 12899-1's RA3
(prismatic, long and short distance) is specified by national documents (e.g. DIN 67520's RA3A
and RA3B, 300 cd lx-1 m-2 at 12'/5 deg) and is not tabulated here: use `file:<csv>`. EN 12899-3
(delineator posts and retroreflectors) lets a delineator carry sheeting of these classes; a
delineator reflector is such a sheeting patch (sources/furniture.py places it).

Road studs, EN 1463-1:2009 (Road marking materials - Retroreflecting road studs), class PRP1:
coefficient of luminous intensity R (mcd lx-1) of a white reflector, horizontal entrance angle
beta2 = 0 and +-5 deg: R >= 220 mcd lx-1 at alpha = 0.3 deg and >= 20 at 1.0 deg; at beta2 = +-20
deg 55 and 5 (Table 4 as we read it; not checked against a copy here). A stud's reflector is
modelled as a flat lens of area A = STUD_LENS_M[0] x STUD_LENS_M[1] facing the traffic, the
reference axis horizontal (EN 1463-1 measures with the stud's base horizontal), so R_A = R / A
(CIE 54.2: R_A = R / A) and the stud sends I = R E_perp toward a driver.

Efficiency bounds (retroreflective.py: the light returned into the lobe, which sets the tail's
roll-off): RA1 beaded 10 % (BEADED_EFFICIENCY), RA2 and studs prismatic: truncated-cube prismatic
sheeting returns ~32 % (3M / FHWA, FACTS.md).
"""

from __future__ import annotations

from poevp_optics.render.materials.sheeting_table import BEADED_EFFICIENCY, SheetingTable
from poevp_optics.sources.furniture import STUD_LENS_M   # the stud lens the R is spread over

#: Prismatic (truncated-cube) retroreflective efficiency, ~32 % (3M / FHWA figures in FACTS.md).
PRISMATIC_EFFICIENCY = 0.32
#: EN 1463-1 class PRP1, white: R (mcd lx-1) at alpha (deg) and beta2 (deg), module docstring.
STUD_R_MCD = {"PRP1": {"alpha_deg": (0.3, 1.0), "beta_deg": (5.0, 20.0),
                       "r_mcd_per_lx": ((220.0, 20.0), (55.0, 5.0))}}

_EN12899 = "EN 12899-1:2007 Fixed, vertical road traffic signs - Part 1: Fixed signs"
#: 12' and 20' in degrees, and 2 deg: the EN 12899-1 observation angles.
_ALPHA_DEG = (12.0 / 60.0, 20.0 / 60.0, 2.0)
_BETA_DEG = (5.0, 30.0, 40.0)


def _transpose(by_alpha):
    """Rows per alpha (as the standard prints them) -> rows per beta (SheetingTable's layout)."""
    return tuple(tuple(row[j] for row in by_alpha) for j in range(len(by_alpha[0])))


def stud_table(cls: str = "PRP1") -> SheetingTable:
    """The R_A table of a road stud's lens: R (EN 1463-1 class) / lens area (module docstring)."""
    c = STUD_R_MCD[cls]
    area = STUD_LENS_M[0] * STUD_LENS_M[1]
    rows = tuple(tuple(r * 1e-3 / area for r in row) for row in c["r_mcd_per_lx"])
    return SheetingTable(f"en1463_1:{cls}", c["alpha_deg"], c["beta_deg"], rows, PRISMATIC_EFFICIENCY,
                         f"EN 1463-1:2009 road studs, class {cls} white, over a {STUD_LENS_M[0] * 1e3:g} x "
                         f"{STUD_LENS_M[1] * 1e3:g} mm lens")


#: The furniture presets, looked up by retroreflective.parse_sheeting beside its own.
FURNITURE_SHEETINGS: dict[str, SheetingTable] = {
    "en12899_1:RA1": SheetingTable(
        "en12899_1:RA1", _ALPHA_DEG, _BETA_DEG,
        _transpose(((50.0, 24.0, 9.0), (35.0, 16.0, 6.0), (5.0, 2.5, 1.5))), BEADED_EFFICIENCY,
        _EN12899 + ", Table 3 (class RA1, white)"),
    "en12899_1:RA2": SheetingTable(
        "en12899_1:RA2", _ALPHA_DEG, _BETA_DEG,
        _transpose(((180.0, 100.0, 95.0), (140.0, 75.0, 65.0), (5.0, 2.5, 1.5))), PRISMATIC_EFFICIENCY,
        _EN12899 + ", Table 4 (class RA2, white)"),
    "en1463_1:PRP1": stud_table("PRP1"),
}
