"""The run's radiance source: the scene's `[source]` kind opened on the mirror grid.

kind = "mitsuba" renders the XML here in render/ (`MitsubaSource`: a `Renderer` that also yields
the run's exposures, render/exposures.py); every other kind reads frames (sources/kinds.py
`SOURCES`, sources/frames.py). Both give what the render run reads: `guard_px`, `plan`,
`stats`, `variant`, `variant_reason`, `exposures(progress)`, `temporal_skip`, and the radiance at
any time for the temporal-error estimate (`set_time`, `render_once`).
"""

from __future__ import annotations

from poevp_optics.render.exposures import render_exposures
from poevp_optics.render.renderer import Renderer
from poevp_optics.sources.kinds import check_source, open_frames


class MitsubaSource(Renderer):
    """A `Renderer` that yields the run's exposures (K sub-frames with Monte Carlo error)."""

    temporal_skip = None       # apps/run/temporal_check.py estimates it by step halving

    def exposures(self, progress: bool = True):
        return render_exposures(self.scene, self, progress)


def open_source(scene, guard_px: int):
    """The scene's radiance source (`[source] kind`) on a mirror grid with `guard_px` mirrors of
    guard band beyond each edge of render.resolution (camera.Camera.guard_px)."""
    if scene.source.renders:
        return MitsubaSource(scene, guard_px=guard_px)
    return open_frames(scene, guard_px, scene.sensor_qe)


def check_frame_source(scene, guard_px: int):
    """Read every frame a frame source's run uses (sources/kinds.py check_source): its plan."""
    return check_source(scene, guard_px, scene.sensor_qe)
