"""Report extensions: what a scene's own section adds to a run's report (a per-frame record, a
summary, a figure), registered by name and chosen by the scene, so the generic frame loop
(apps/run/render_run.py) imports none of them. Modelled on GalSim's extra outputs
(galsim.config.RegisterExtraOutput: a builder per output, called per object and at the end).

| name                | applies when                          | per frame key         | summary                         |
|---------------------|---------------------------------------|-----------------------|---------------------------------|
| night_road          | the scene has a [road] section        | `plate` (night_road.py) | `night_road` + night_road.png |
| exposure_controller | mask.law = "exposure_controller", causal loop | `exposure_controller` (the controller's state) | - |
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from poevp_optics.core.registry import Registry


@dataclass(frozen=True)
class ReportExtension:
    """applies(spec, causal) -> bool; start(spec) -> per-run state; frame(spec, camera, fc, step,
    state) -> the frame's record entry under `key`, taken before the loop observes the frame or,
    with after_observe, after it; finish(spec, camera, report, out_dir, write_images) adds the
    summary (and writes its figure)."""

    key: str
    applies: Callable[..., bool]
    start: Callable[[Any], Any] = lambda spec: None
    frame: Callable[..., Any] | None = None
    finish: Callable[..., None] | None = None
    after_observe: bool = False


REPORT_EXTENSIONS = Registry("report extension")


def _road_frame(spec, camera, fc, step, laws):
    from poevp_optics.apps.run import night_road

    return night_road.frame_record(spec, camera, fc, laws)


def _road_start(spec):
    from poevp_optics.apps.run import night_road

    return night_road.scene_laws(spec)


def _road_finish(spec, camera, report: dict, out_dir: Path, write_images: bool) -> None:
    from poevp_optics.apps.run import night_road

    report["night_road"] = night_road.summary(spec, camera, report["per_frame"])
    report["notes"].append(f"night road: {report['night_road']['statement']}")
    if write_images:
        night_road.plot(out_dir / "night_road.png", report["night_road"],
                        f"{spec.name}: plate peak over saturation vs distance")


REPORT_EXTENSIONS.register(
    "night_road", ReportExtension("plate", lambda spec, causal: spec.has_road, _road_start, _road_frame, _road_finish),
    source="apps/run/night_road.py: plate distance, angles, R_A, luminance and DR demand per frame")
REPORT_EXTENSIONS.register(
    "exposure_controller",
    ReportExtension("exposure_controller", lambda spec, causal: causal and spec.mask.law == "exposure_controller",
                    frame=lambda spec, camera, fc, step, state: step.controller.summary(), after_observe=True),
    source="control/exposure_control.py: the controller's state after each frame")


def active(spec, causal: bool) -> list[tuple[ReportExtension, Any]]:
    """The scene's extensions with their per-run state, in registration order."""
    return [(ext, ext.start(spec)) for name in REPORT_EXTENSIONS
            if (ext := REPORT_EXTENSIONS[name]).applies(spec, causal)]
