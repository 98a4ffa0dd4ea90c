"""[outputs]: which files a run writes (the writer is apps/run/outputs.py). Here in scene/ because the
scene spec is composed of it and scene/ may not import apps/ (DESIGN's package table, issue 30)."""

from __future__ import annotations

from dataclasses import dataclass

from poevp_optics.analysis.tonemap import TONEMAPPERS
from poevp_optics.core.params import param


@dataclass(frozen=True)
class OutputsSpec:
    """[outputs]: which files a run writes."""

    radiance_exr: bool = param(True)
    subframes_exr: bool = param(False)
    previews: bool = param(True)
    contact_sheet: bool = param(True)
    tonemap: str = param("reinhard2004", choices=TONEMAPPERS)
