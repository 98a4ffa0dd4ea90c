"""A validated scene: every section frozen, each the params dataclass of the stage it feeds.

| section              | params class     | owned by |
|----------------------|------------------|----------|
| [render]             | RenderSpec       | render/renderer.py |
| [timing]             | TimingSpec       | core/timing.py |
| [motion.<id>]        | MotionSpec       | sources/motion.py |
| [spectra.<param>]    | SpectrumSpec     | core/spectra.py |
| [flicker.<param>]    | FlickerSpec      | core/flicker.py |
| [plate]              | PlateSpec        | sources/plates.py |
| [source]             | SourceSpec       | sources/kinds.py (kinds: mitsuba_source.py, exr_sequence.py, ldr_highlight.py) |
| [road]               | RoadSpec         | sources/road.py (night-road geometry; only road scenes) |
| [sheeting.<param>]   | SheetingSpec     | render/materials/retroreflective.py |
| [marking.<param>]    | MarkingSpec      | render/materials/road_marking.py (EN 1436 lane markings) |
| [weather]            | WeatherSpec      | sources/weather.py (fog, wet road) |
| [traffic]            | TrafficSpec      | sources/traffic.py (Intelligent Driver Model traffic moving [vehicle] entries) |
| [vehicle.<id>]       | VehicleSpec      | sources/vehicles.py (parametric vehicle meshes and plates) |
| [furniture.<id>]     | FurnitureSpec    | sources/furniture.py (guard rails, delineators, studs, signs, kerbs, trees, buildings) |
| [objective]          | ObjectiveSpec    | camera/objective/   |
| [attenuator]         | AttenuatorSpec   | camera/attenuator.py (global variable ND before the DMD) |
| [dmd]                | DMDSpec          | camera/dmd.py (registration: camera/registration.py) |
| [relay]              | RelaySpec        | camera/relay.py |
| [sensor]             | SensorSpec       | camera/sensor.py |
| [mask]               | MaskSpec         | control/masks.py |
| [predictor]          | PredictorSpec    | control/predictors |
| [loop]               | LoopSpec         | control/loop_step.py |
| [budget]             | BudgetSpec       | control/timing_budget.py |
| [chart]              | ChartSpec        | analysis/charts.py |
| [outputs]            | OutputsSpec      | scene/outputs.py (the writer: apps/run/outputs.py) |

The spec is what the TOML says (after validation and the best-loop defaults); `resolve`
(scene/resolve.py, `SceneSpec.resolved`) turns it into each stage's own inputs, with the
accuracy settings as one core.accuracy.Accuracy and the values derived from other keys.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from types import MappingProxyType
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from poevp_optics.analysis.charts import ChartSpec
from poevp_optics.camera.attenuator import AttenuatorSpec
from poevp_optics.camera.dmd import DMDSpec
from poevp_optics.camera.objective import ObjectiveSpec
from poevp_optics.camera.relay import RelaySpec
from poevp_optics.camera.sensor import SensorSpec
from poevp_optics.control.loop_step import LoopSpec
from poevp_optics.control.masks import MaskSpec
from poevp_optics.control.predictors import PredictorSpec
from poevp_optics.control.timing_budget import BudgetSpec
from poevp_optics.core.accuracy import Accuracy
from poevp_optics.core.timing import TimingSpec
from poevp_optics.render.materials.retroreflective import SheetingSpec
from poevp_optics.render.materials.road_marking import MarkingSpec
from poevp_optics.render.renderer import RenderSpec
from poevp_optics.scene.outputs import OutputsSpec
from poevp_optics.sources.flicker import FlickerSpec
from poevp_optics.sources.furniture import FurnitureSpec
from poevp_optics.sources.kinds import SourceSpec
from poevp_optics.sources.motion import MotionSpec
from poevp_optics.sources.plates import PlateSpec
from poevp_optics.sources.road import RoadSpec
from poevp_optics.sources.traffic import TrafficSpec
from poevp_optics.sources.spectra import SpectrumSpec
from poevp_optics.sources.vehicles import VehicleSpec
from poevp_optics.sources.weather import WeatherSpec

if TYPE_CHECKING:
    from poevp_optics.scene.resolve import ResolvedScene


@dataclass(frozen=True)
class SceneSpec:
    """A validated scene: paths resolved, every section frozen."""

    name: str
    toml_path: Path
    xml_path: Path | None          # None: the radiance comes from a frame source ([source])
    description: str
    render: RenderSpec
    timing: TimingSpec
    motion: Mapping[str, MotionSpec]
    spectra: Mapping[str, SpectrumSpec]
    flicker: Mapping[str, FlickerSpec]
    sheeting: Mapping[str, SheetingSpec]
    dmd: DMDSpec
    objective: ObjectiveSpec
    relay: RelaySpec
    sensor: SensorSpec
    mask: MaskSpec
    predictor: PredictorSpec
    loop: LoopSpec
    budget: BudgetSpec
    outputs: OutputsSpec
    plate: PlateSpec
    chart: ChartSpec
    road: RoadSpec
    source: SourceSpec
    attenuator: AttenuatorSpec
    raw: Mapping[str, Any]
    weather: WeatherSpec = WeatherSpec()
    traffic: TrafficSpec = TrafficSpec()
    marking: Mapping[str, MarkingSpec] = field(default_factory=lambda: MappingProxyType({}))
    vehicle: Mapping[str, VehicleSpec] = field(default_factory=lambda: MappingProxyType({}))
    furniture: Mapping[str, FurnitureSpec] = field(default_factory=lambda: MappingProxyType({}))
    origin: str = ""               # the file and the --set overrides it was read with (messages)
    defaults_applied: tuple[str, ...] = ()  # "section.key=value" of the best loop the scene did not choose (defaults.py)

    @cached_property
    def resolved(self) -> "ResolvedScene":
        """The stages' inputs (scene/resolve.py), resolved once per spec."""
        from poevp_optics.scene.resolve import resolve

        return resolve(self)

    @property
    def accuracy(self) -> Accuracy:
        """The run's numerical settings (`resolved.accuracy`)."""
        return self.resolved.accuracy

    @property
    def sensor_qe(self) -> str:
        """The QE curve (core/spectra.py name) of the scene's sensor (`resolved.render.sensor_qe`)."""
        return self.resolved.render.sensor_qe

    @property
    def has_road(self) -> bool:
        """True for a night-road scene (a [road] section: sources/road.py)."""
        return "road" in self.raw

    @property
    def geometry_static(self) -> bool:
        """True when no shape or emitter moves (`resolved.render.geometry_static`)."""
        return self.resolved.render.geometry_static

    @property
    def is_static(self) -> bool:
        """True when nothing changes in time (no motion, no flicker): rendered once, K = 1."""
        return self.resolved.render.is_static

    def frame_start_s(self, index: int) -> float:
        return self.timing.frame_start_s(index)

    def exposure_window_s(self, index: int) -> tuple[float, float]:
        return self.timing.exposure_window_s(index)

    def subframe_times_s(self, index: int) -> np.ndarray:
        """Times (s) of frame `index`'s radiance samples (core/timing.py `ExposureClock`)."""
        return self.resolved.render.clock.subframe_times_s(index)

    def subframe_weights(self, index: int) -> np.ndarray:
        """Weight of each radiance sample in the exposure's time average (sums to 1)."""
        return self.resolved.render.clock.subframe_weights(index)


SECTIONS = {
    "render": RenderSpec, "timing": TimingSpec, "dmd": DMDSpec, "objective": ObjectiveSpec,
    "relay": RelaySpec, "sensor": SensorSpec, "mask": MaskSpec, "predictor": PredictorSpec,
    "loop": LoopSpec, "budget": BudgetSpec, "outputs": OutputsSpec, "plate": PlateSpec, "chart": ChartSpec,
    "source": SourceSpec, "road": RoadSpec, "attenuator": AttenuatorSpec, "weather": WeatherSpec,
    "traffic": TrafficSpec,
}
TABLE_SECTIONS = {"motion": MotionSpec, "spectra": SpectrumSpec, "flicker": FlickerSpec,
                  "sheeting": SheetingSpec, "marking": MarkingSpec, "vehicle": VehicleSpec,
                  "furniture": FurnitureSpec}
TOP_KEYS = {"description"}
