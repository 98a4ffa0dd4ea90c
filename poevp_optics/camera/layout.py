"""The optical layout of the camera: one geometry gives both the etendue and the diffraction.

    scene -> objective (f-number N_obj at the DMD) -> DMD -> relay (magnification M = sensor image
    size / DMD size, optional aperture stop N_relay on its image side) -> sensor

The cone reaching a sensor pixel is the objective's cone magnified by the relay, f/(N_obj M),
unless the relay's own stop is narrower: N_sensor = max(N_obj M, N_relay). Without a DMD the
objective images straight onto the sensor: N_sensor = N_obj. N_sensor sets the pixel etendue
A pi / (4 N^2) (sensor.pixel_etendue_m2_sr) and the relay's diffraction PSF at the sensor
(relay.airy_psf; incoherent imaging of the DMD plane through the cone that reaches the sensor).
M follows from the mirror-to-sensor registration: M = scale x sensor pitch / mirror pitch.

Keys (`[objective] f_number`, `[relay] f_number, magnification`, `[sensor] f_number`; NaN: not
set): give the objective's f-number, or the sensor's working f-number (the stable key, default
from the sensor preset), or both when they agree. A scene whose values contradict each other
(a relay stop narrower than the sensor cone it claims, an f-number that does not follow from
the other two, a magnification that does not follow from the registration) is an error naming
the keys. Sources: Smith, Modern Optical Engineering, 4th ed., ch. 9 (working f-number, image
irradiance = pi L / (4 N^2)) and ch. 6 (stops: the smaller cone wins).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Relative tolerance when two ways of computing one f-number or magnification must agree.
AGREE_RTOL = 1e-6


class LayoutError(ValueError):
    """Contradictory optical keys; `key` names the offending scene key."""

    def __init__(self, key: str, message: str):
        super().__init__(message)
        self.key = key


@dataclass(frozen=True)
class OpticalLayout:
    """Resolved f-numbers and magnification of the optical path (dimensionless)."""

    objective_f_number: float        # image side of the objective, at the DMD (sensor without DMD)
    relay_magnification: float       # sensor image size / DMD size (1 without DMD)
    relay_f_number: float            # relay aperture stop, image side (inf: none)
    sensor_f_number: float           # working f-number of the cone at the sensor
    limited_by: str                  # "objective" or "relay": whose aperture sets the cone

    def as_dict(self) -> dict:
        d = dict(self.__dict__)
        if math.isinf(d["relay_f_number"]):
            d["relay_f_number"] = None
        return d


def _agree(a: float, b: float) -> bool:
    return abs(a - b) <= AGREE_RTOL * max(abs(a), abs(b))


def optical_layout(*, objective_f_number: float, sensor_f_number: float, preset_f_number: float,
                   relay_f_number: float, relay_magnification: float, dmd_enabled: bool,
                   registration_scale: float, sensor_pitch_m: float, mirror_pitch_m: float) -> OpticalLayout:
    """Resolve the layout from the scene's keys (NaN: not set); raises `LayoutError`."""
    n_obj, n_sen = objective_f_number, sensor_f_number
    if not dmd_enabled:
        if not math.isnan(n_obj) and not math.isnan(n_sen) and not _agree(n_obj, n_sen):
            raise LayoutError("objective.f_number",
                              f"{n_obj:g} contradicts sensor.f_number = {n_sen:g}: without a DMD the "
                              "objective images onto the sensor, so they are one cone")
        n = n_obj if not math.isnan(n_obj) else (n_sen if not math.isnan(n_sen) else preset_f_number)
        return OpticalLayout(n, 1.0, math.inf, n, "objective")
    m_geom = registration_scale * sensor_pitch_m / mirror_pitch_m
    if not math.isnan(relay_magnification) and not _agree(relay_magnification, m_geom):
        raise LayoutError("relay.magnification",
                          f"{relay_magnification:g} contradicts dmd.registration.scale x sensor.pixel_pitch_m"
                          f" / dmd.pitch_m = {registration_scale:g} x {sensor_pitch_m:g} / {mirror_pitch_m:g}"
                          f" = {m_geom:.6g}")
    n_rel = math.inf if math.isnan(relay_f_number) else relay_f_number
    if not math.isnan(n_obj):
        cone = n_obj * m_geom
        n_s = max(cone, n_rel) if math.isfinite(n_rel) else cone
        if not math.isnan(n_sen) and not _agree(n_s, n_sen):
            raise LayoutError("sensor.f_number",
                              f"{n_sen:g} contradicts the layout: objective.f_number {n_obj:g} x relay "
                              f"magnification {m_geom:.4g} = f/{cone:.4g}"
                              + (f", relay stop f/{n_rel:g}" if math.isfinite(n_rel) else "")
                              + f" gives f/{n_s:.4g} at the sensor")
        return OpticalLayout(n_obj, m_geom, n_rel, n_s, "relay" if math.isfinite(n_rel) and n_rel > cone
                             else "objective")
    n_s = n_sen if not math.isnan(n_sen) else preset_f_number
    if math.isfinite(n_rel) and n_rel > n_s * (1 + AGREE_RTOL):
        raise LayoutError("relay.f_number",
                          f"the relay stop f/{n_rel:g} is narrower than the sensor cone f/{n_s:g} "
                          "(sensor.f_number or its preset): the relay would set the cone; give "
                          "objective.f_number instead, or drop one of the two")
    limited = "relay" if math.isfinite(n_rel) and _agree(n_rel, n_s) else "objective"
    return OpticalLayout(n_s / m_geom, m_geom, n_rel, n_s, limited)


def image_plane_pitch_m(dmd, sensor_params) -> float:
    """Pitch (m) of the grid the objective images onto: the DMD's mirrors, else (no DMD) the
    sensor's pixels. The one place of this rule (camera, memory estimate and validation read it)."""
    return dmd.pitch_m if dmd.enabled else sensor_params.pixel_pitch_m


def objective_params_of(sensor, dmd, relay, objective):
    """The [objective] resolved as the camera resolves it (camera/objective ObjectiveParams: the
    layout's objective f-number, the image-plane pitch, the sensor's QE band); None when the
    stage is the identity (skipped)."""
    if objective.is_identity:
        return None
    from poevp_optics.camera.objective import ObjectiveParams
    from poevp_optics.camera.sensor import resolve_sensor

    p = resolve_sensor(sensor)
    n = layout_of(sensor, dmd, relay, objective).objective_f_number
    return ObjectiveParams.resolve(objective, f_number=n, pixel_pitch_m=image_plane_pitch_m(dmd, p), qe=p.qe)


def layout_of(sensor, dmd, relay, objective) -> OpticalLayout:
    """The layout of the [sensor], [dmd], [relay] and [objective] sections (their Spec classes):
    the preset's f-number and pitch fill unset keys."""
    from poevp_optics.camera.sensor import SENSOR_PRESETS

    preset = SENSOR_PRESETS[sensor.preset]
    pitch = sensor.pixel_pitch_m if not math.isnan(sensor.pixel_pitch_m) else preset.pixel_pitch_m
    return optical_layout(objective_f_number=objective.f_number, sensor_f_number=sensor.f_number,
                          preset_f_number=preset.f_number, relay_f_number=relay.f_number,
                          relay_magnification=relay.magnification, dmd_enabled=dmd.enabled,
                          registration_scale=dmd.registration.scale, sensor_pitch_m=pitch,
                          mirror_pitch_m=dmd.pitch_m)
