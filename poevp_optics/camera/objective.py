"""The objective lens: it images the scene onto the DMD (layout.py holds its f-number's role).

| key       | type  | unit | default | meaning |
|-----------|-------|------|---------|---------|
| f_number  | float | -    | NaN     | working f-number at the DMD image plane; NaN: from sensor.f_number / M |
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from poevp_optics.core.params import param


@dataclass(frozen=True)
class ObjectiveSpec:
    """[objective]: the lens that images the scene onto the DMD (layout.py)."""

    f_number: float = param(math.nan, gt=0, max=1000.0)  # at the DMD; NaN: from sensor.f_number
