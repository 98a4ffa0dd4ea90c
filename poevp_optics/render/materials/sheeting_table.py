"""A retroreflective sheeting's tabulated coefficient of retroreflection R_A and its efficiency
bound: the table type shared by the sheeting presets (render/materials/retroreflective.py for
ASTM D4956 plates, render/materials/furniture_sheeting.py for signs, delineators and studs)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Retroreflective efficiency used by the presets: mid-range of beaded sheeting's 7-14 % (3M
#: "Reflective sheeting efficiencies"; FHWA, quoted in FACTS.md). Override with `;efficiency=`.
BEADED_EFFICIENCY = 0.10


class SheetingError(ValueError):
    """A sheeting source or table that cannot be used (message names the source)."""


@dataclass(frozen=True)
class SheetingTable:
    """A tabulated coefficient of retroreflection and the sheeting's efficiency bound.

    alpha_deg: observation angles (deg, increasing, > 0, at least two);
    beta_deg: entrance angles |beta| (deg, increasing, in [0, 90));
    ra_cd_per_lx_m2[i_beta][i_alpha]: R_A (cd lx-1 m-2, > 0);
    efficiency: retroreflected fraction bound (0, 1);
    reference: where the numbers come from.
    """

    name: str
    alpha_deg: tuple[float, ...]
    beta_deg: tuple[float, ...]
    ra_cd_per_lx_m2: tuple[tuple[float, ...], ...]
    efficiency: float
    reference: str

    def __post_init__(self):
        a, b = np.asarray(self.alpha_deg, float), np.asarray(self.beta_deg, float)
        ra = np.asarray(self.ra_cd_per_lx_m2, float)
        where = f"sheeting {self.name!r}"
        if len(a) < 2 or np.any(np.diff(a) <= 0) or a[0] <= 0:
            raise SheetingError(f"{where}: needs >= 2 increasing observation angles > 0 deg, got {list(a)}")
        if len(b) < 1 or np.any(np.diff(b) <= 0) or b[0] < 0 or b[-1] >= 90:
            raise SheetingError(f"{where}: entrance angles must increase within [0, 90) deg, got {list(b)}")
        if ra.shape != (len(b), len(a)):
            raise SheetingError(f"{where}: R_A table must be a full grid of {len(b)} entrance x "
                                f"{len(a)} observation angles")
        if not np.all(np.isfinite(ra)) or np.any(ra <= 0):
            raise SheetingError(f"{where}: R_A values must be finite and > 0")
        if np.any(ra[:, -1] >= ra[:, -2]):
            raise SheetingError(f"{where}: R_A must fall at the largest observation angles "
                                "(the tail is extrapolated from the last segment)")
        if not 0 < self.efficiency < 1:
            raise SheetingError(f"{where}: efficiency must be in (0, 1), got {self.efficiency}")
