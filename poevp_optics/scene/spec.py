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

Accuracy settings (spp, nodes, MC splits, PSF support, ...) are gathered into one
core.accuracy.Accuracy by `SceneSpec.accuracy`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

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
from poevp_optics.render.renderer import RenderSpec
from poevp_optics.scene.outputs import OutputsSpec
from poevp_optics.sources.flicker import FlickerSpec
from poevp_optics.sources.kinds import SourceSpec
from poevp_optics.sources.motion import MotionSpec
from poevp_optics.sources.plates import PlateSpec
from poevp_optics.sources.road import RoadSpec
from poevp_optics.sources.spectra import SpectrumSpec


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
    origin: str = ""               # the file and the --set overrides it was read with (messages)
    defaults_applied: tuple[str, ...] = ()  # "section.key=value" of the best loop the scene did not choose (defaults.py)

    @property
    def accuracy(self) -> Accuracy:
        """The run's numerical settings, from the stable [render] and [relay] keys."""
        r, rel = self.render, self.relay
        return Accuracy(spp=r.spp, subframes=r.subframes, pwm_nodes=r.pwm_nodes, mc_splits=r.mc_splits,
                        temporal_spp=r.temporal_spp, sampler=r.sampler, light_selection=r.light_selection,
                        target_rel_error=r.target_rel_error, max_spp=r.max_spp, psf_support_energy=rel.support_energy,
                        psf_support_px=rel.support_px, guard_max_px=rel.guard_max_px,
                        poisson_sampler=self.sensor.poisson_sampler)

    @property
    def sensor_qe(self) -> str:
        """The QE curve (core/spectra.py name) of the scene's sensor, its preset's unless
        overridden: the response the render weights wavelengths by (render/ reads it here, so
        it needs nothing of camera/)."""
        from poevp_optics.camera.sensor import resolve_sensor

        return resolve_sensor(self.sensor).qe

    @property
    def has_road(self) -> bool:
        """True for a night-road scene (a [road] section: sources/road.py)."""
        return "road" in self.raw

    @property
    def geometry_static(self) -> bool:
        """True when no shape or emitter moves (a frame source is taken to change in time)."""
        return self.source.renders and all(m.is_static for m in self.motion.values())

    @property
    def is_static(self) -> bool:
        """True when nothing changes in time (no motion, no flicker): rendered once, K = 1."""
        return self.geometry_static and not self.flicker

    def frame_start_s(self, index: int) -> float:
        return self.timing.frame_start_s(index)

    def exposure_window_s(self, index: int) -> tuple[float, float]:
        return self.timing.exposure_window_s(index)

    def subframe_times_s(self, index: int) -> np.ndarray:
        """Times (s) of the radiance samples of frame `index`'s exposure: K = render.subframes
        uniform nodes including both ends (the midpoint for K = 1), joined, when
        render.pwm_nodes is on and a DMD is in the path, by the DMD's switching times inside the
        exposure (window edges, bit-plane boundaries: dmd.switch_times_s). Moving scenes only;
        a static scene needs one sample."""
        from poevp_optics.camera.dmd import Schedule, node_times_s, switch_times_s

        t0, t1 = self.exposure_window_s(index)
        k = self.render.subframes
        extra = ()
        if k > 1 and self.render.pwm_nodes and self.dmd.enabled:
            extra = switch_times_s(Schedule.for_frame(self.dmd, self.timing, self.frame_start_s(index)))
        return node_times_s(t0, t1, k, extra)

    def subframe_weights(self, index: int) -> np.ndarray:
        """Weight of each radiance sample in the exposure's time average (sums to 1)."""
        from poevp_optics.camera.dmd import node_time_weights_s

        t = self.subframe_times_s(index)
        t0, t1 = self.exposure_window_s(index)
        w = node_time_weights_s(t1 - t0, t - t0)
        return w / w.sum()


SECTIONS = {
    "render": RenderSpec, "timing": TimingSpec, "dmd": DMDSpec, "objective": ObjectiveSpec,
    "relay": RelaySpec, "sensor": SensorSpec, "mask": MaskSpec, "predictor": PredictorSpec,
    "loop": LoopSpec, "budget": BudgetSpec, "outputs": OutputsSpec, "plate": PlateSpec, "chart": ChartSpec,
    "source": SourceSpec, "road": RoadSpec, "attenuator": AttenuatorSpec,
}
TABLE_SECTIONS = {"motion": MotionSpec, "spectra": SpectrumSpec, "flicker": FlickerSpec,
                  "sheeting": SheetingSpec}
TOP_KEYS = {"description"}
