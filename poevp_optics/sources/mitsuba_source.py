"""[source] kind = "mitsuba" (the default): the scene's Mitsuba 3 XML rendered to absolute
sensor-weighted photon radiance (Jakob, Speierer, Roussel, Vicini, Mitsuba 3 renderer, 2022).

Its settings are the [render] section's (xml, spp, subframes, ...); [source] takes no key
besides `kind`. The renderer lives in render/ (render/renderer.py, render/exposures.py), which
may import sources/ but not the other way round: render/radiance.py opens this kind
(`MitsubaSource`, K sub-frames per exposure with Monte Carlo error).
"""

from __future__ import annotations

from pathlib import Path

KEYS: tuple[str, ...] = ()


def check_keys(src, given: frozenset[str], base_dir: Path) -> None:
    """kind = 'mitsuba' takes no [source] keys besides `kind` (scene/validate.py refuses any
    other before this is called)."""


def input_files(scene) -> list[Path]:
    """No files besides the XML and what it names (apps/run/preflight.py lists those)."""
    return []
