"""What the light side reads of a scene: `RenderScene`, the narrow input of render/ and sources/.

Resolved once from the whole scene by `scene/resolve.py` (GalSim's GSParams is the model: the
stage gets its own typed inputs, never the scene object). Every field is a validated params
dataclass of render/ or sources/, plus what the scene resolved for them from other stages: the
sensor's QE curve that weights the render (`sensor_qe`), the exposure clock with the DMD's
switching times (`clock`, core/timing.py) and the run's `Accuracy`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Mapping

import numpy as np

from poevp_optics.core.accuracy import Accuracy
from poevp_optics.core.timing import ExposureClock, TimingSpec

if TYPE_CHECKING:
    from poevp_optics.core.flicker import FlickerSpec
    from poevp_optics.core.spectra import SpectrumSpec
    from poevp_optics.render.materials.retroreflective import SheetingSpec
    from poevp_optics.render.renderer import RenderSpec
    from poevp_optics.sources.kinds import SourceSpec
    from poevp_optics.sources.motion import MotionSpec
    from poevp_optics.sources.plates import PlateSpec
    from poevp_optics.render.materials.road_marking import MarkingSpec
    from poevp_optics.sources.road import RoadSpec
    from poevp_optics.sources.furniture import FurnitureSpec
    from poevp_optics.sources.vehicles import VehicleSpec
    from poevp_optics.sources.weather import WeatherSpec


@dataclass(frozen=True)
class RenderScene:
    """The scene as the renderer and the frame sources see it (paths resolved, frozen)."""

    name: str
    toml_path: Path
    xml_path: Path | None            # None: the radiance comes from a frame source ([source])
    origin: str                      # the file and the --set overrides it was read with (messages)
    render: "RenderSpec"
    timing: TimingSpec
    clock: ExposureClock
    motion: Mapping[str, "MotionSpec"]
    spectra: Mapping[str, "SpectrumSpec"]
    flicker: Mapping[str, "FlickerSpec"]
    sheeting: Mapping[str, "SheetingSpec"]
    plate: "PlateSpec"
    road: "RoadSpec"
    has_road: bool                   # a night-road scene ([road] given: sources/road.py)
    source: "SourceSpec"
    sensor_qe: str                   # the QE curve (core/spectra.py name) the render weights by
    accuracy: Accuracy
    weather: "WeatherSpec | None" = None     # [weather] (sources/weather.py); None: none given
    marking: Mapping[str, "MarkingSpec"] = field(default_factory=lambda: MappingProxyType({}))  # [marking.<param>]
    vehicle: Mapping[str, "VehicleSpec"] = field(default_factory=lambda: MappingProxyType({}))  # [vehicle.<id>]
    furniture: Mapping[str, "FurnitureSpec"] = field(default_factory=lambda: MappingProxyType({}))  # [furniture.<id>]

    @property
    def geometry_static(self) -> bool:
        """True when no shape or emitter moves (a frame source is taken to change in time)."""
        return self.source.renders and all(m.is_static for m in self.motion.values())

    @property
    def is_static(self) -> bool:
        """True when nothing changes in time (no motion, no flicker): rendered once, K = 1."""
        return self.geometry_static and not self.flicker

    def frame_start_s(self, index: int) -> float:
        return self.clock.frame_start_s(index)

    def exposure_window_s(self, index: int) -> tuple[float, float]:
        return self.clock.exposure_window_s(index)

    def subframe_times_s(self, index: int) -> np.ndarray:
        """Times (s) of frame `index`'s radiance samples (`ExposureClock.subframe_times_s`)."""
        return self.clock.subframe_times_s(index)

    def subframe_weights(self, index: int) -> np.ndarray:
        """Weight of each radiance sample in the exposure's time average (sums to 1)."""
        return self.clock.subframe_weights(index)
