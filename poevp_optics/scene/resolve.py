"""Resolve a validated scene once into the typed inputs of its stages (issue 30).

`resolve(spec) -> ResolvedScene`: pure (reads only the spec; nothing is loaded or rendered).

| field    | type                           | read by |
|----------|--------------------------------|---------|
| render   | render/render_scene.RenderScene | `Renderer`, `render_exposures`, the frame sources |
| camera   | camera/camera.CameraParams     | `Camera.from_params` |
| loop     | control/loop_step.LoopParams   | `LoopStep.from_params` |
| accuracy | core/accuracy.Accuracy         | every stage's numerics (one object, a real field) |
| derived  | {"section.key": value}         | values computed from other keys, reported as derived |

Below apps/ no function takes the scene object (`SceneSpec`): each stage receives its own part,
as GalSim hands each stage its GSParams rather than the config. Values one stage needs from
another are resolved here, in one place: the sensor's QE curve that weights the render, the
DMD's switching times that join the radiance nodes (`ExposureClock`), the controller prior
scaled to our own beams (`derived`, so that `spec.mask` stays what the TOML says).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Mapping

from poevp_optics.camera.camera import CameraParams
from poevp_optics.camera.sensor import resolve_sensor
from poevp_optics.control.loop_step import LoopParams
from poevp_optics.core.accuracy import OBJECTIVE_KEYS, Accuracy
from poevp_optics.core.timing import ExposureClock, PlaneDisplay
from poevp_optics.render.render_scene import RenderScene


@dataclass(frozen=True)
class ResolvedScene:
    """A scene resolved into its stages' inputs (module table)."""

    render: RenderScene
    camera: CameraParams
    loop: LoopParams
    accuracy: Accuracy
    derived: Mapping[str, Any]


def accuracy_of(spec) -> Accuracy:
    """The run's numerical settings, from the stable [render], [relay], [sensor] and [objective]
    keys (core/accuracy.py's table)."""
    r, rel = spec.render, spec.relay
    return Accuracy(spp=r.spp, subframes=r.subframes, pwm_nodes=r.pwm_nodes, mc_splits=r.mc_splits,
                    temporal_spp=r.temporal_spp, sampler=r.sampler, light_selection=r.light_selection,
                    target_rel_error=r.target_rel_error, max_spp=r.max_spp, psf_support_energy=rel.support_energy,
                    psf_support_px=rel.support_px, guard_max_px=rel.guard_max_px,
                    poisson_sampler=spec.sensor.poisson_sampler,
                    **{f"objective_{k}": getattr(spec.objective, k) for k in OBJECTIVE_KEYS})


def prior_first_guess(mask, road, spectra, has_road: bool) -> float | None:
    """The exposure controller's prior scaled to our high beams, first_guess x intensity_cd /
    prior_beam_cd (control/exposure_control.py: the signal of light returned from our beams is
    proportional to their intensity), or None where the scene sets no such scaling."""
    if mask.prior_beam_cd == 0 or mask.law != "exposure_controller" or not has_road:
        return None
    return mask.first_guess * spectra[road.highbeam].intensity_cd / mask.prior_beam_cd


def exposure_clock(spec) -> ExposureClock:
    """Frame i's exposure window and radiance-node times: the DMD's switching times join the
    nodes when render.pwm_nodes is on and a DMD is in the path."""
    planes = None
    if spec.render.pwm_nodes and spec.dmd.enabled:
        planes = PlaneDisplay(spec.dmd.bits, spec.dmd.bit_order, spec.dmd.settle_s)
    return ExposureClock(spec.timing, spec.render.subframes, planes)


def resolve(spec) -> ResolvedScene:
    """`spec` (scene/spec.py SceneSpec) -> its stages' inputs."""
    accuracy = accuracy_of(spec)
    has_road = "road" in spec.raw
    derived: dict[str, Any] = {}
    mask = spec.mask
    guess = prior_first_guess(mask, spec.road, spec.spectra, has_road)
    if guess is not None:
        derived["mask.first_guess"] = guess
        mask = dataclasses.replace(mask, first_guess=guess)
    render = RenderScene(
        name=spec.name, toml_path=spec.toml_path, xml_path=spec.xml_path, origin=spec.origin,
        render=spec.render, timing=spec.timing, clock=exposure_clock(spec), motion=spec.motion,
        spectra=spec.spectra, flicker=spec.flicker, sheeting=spec.sheeting, plate=spec.plate, road=spec.road,
        has_road=has_road, source=spec.source, sensor_qe=resolve_sensor(spec.sensor).qe, accuracy=accuracy,
        weather=spec.weather if "weather" in spec.raw else None, marking=spec.marking, vehicle=spec.vehicle,
        furniture=spec.furniture)
    camera = CameraParams(spec.sensor, spec.dmd, spec.relay, spec.objective, spec.timing,
                          tuple(spec.render.resolution), accuracy, base_dir=spec.toml_path.parent,
                          flicker=spec.flicker)
    loop = LoopParams(mask, spec.loop, spec.predictor, spec.budget, spec.attenuator)
    return ResolvedScene(render, camera, loop, accuracy, MappingProxyType(derived))
