"""Checks that combine keys or reach outside the TOML: timing fits the frame, spectra resolve
and have visible power, photometric and sheeting files load, the optical layout agrees,
weights exist, the DMD can act on the exposure, the [source] kind's keys go together (a frame
source needs no XML). Each failure is one line naming file and key.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from poevp_optics.analysis.charts import ChartSpec
from poevp_optics.camera.dmd import DMDSpec
from poevp_optics.camera.relay import RelaySpec
from poevp_optics.camera.sensor import SensorSpec
from poevp_optics.control.masks import ATTENUATED_LAWS, MaskSpec
from poevp_optics.control.predictors import PREDICTORS, PredictorSpec, takes_weights
from poevp_optics.core.paths import ASSETS_DIR
from poevp_optics.core.timing import TimingSpec
from poevp_optics.render.renderer import RenderSpec
from poevp_optics.sources.frames import SourceKeyError
from poevp_optics.sources.kinds import SOURCES, SourceSpec
from poevp_optics.sources.motion import MotionSpec
from poevp_optics.sources.plates import PlateSpec
from poevp_optics.sources.spectra import SpectrumSpec


def chart_spectra(ctx, path: Path, chart: ChartSpec, given) -> dict:
    """The patch spectra a [chart] section implies: light box x 10^-D per patch."""
    dens = chart.density_list()
    if len(dens) != chart.patches:
        raise ctx.fail("chart.densities", f"{len(dens)} densities for {chart.patches} patches")
    if not chart.densities and chart.d_max <= chart.d_min:
        raise ctx.fail("chart.d_max", f"must exceed d_min = {chart.d_min}")
    if chart.reference_camera:
        ref = path.parent / chart.reference_camera
        if not (ref.is_file() or (ref / "scene.toml").is_file()):
            raise ctx.fail("chart.reference_camera", f"scene not found: {ref}")
    out = {}
    for i, d in enumerate(dens):
        name = chart.param(i)
        if name in given:
            raise ctx.fail(f"spectra.{name}", "set by [chart] (light box x 10^-D); remove it here")
        entry = SpectrumSpec(kind="radiance", source=chart.source,
                             luminance_cd_per_m2=chart.luminance_cd_per_m2 * 10.0 ** (-d))
        check_spectrum(ctx, "chart.source", entry)
        out[name] = entry
    return out


def check_timing(ctx, t: TimingSpec):
    period = 1.0 / t.fps
    if t.exposure_offset_s + t.exposure_s > period * (1 + 1e-9):
        raise ctx.fail("timing.exposure_s",
                       f"impossible timing: exposure_offset_s + exposure_s = "
                       f"{t.exposure_offset_s + t.exposure_s:.6g} s exceeds the frame period "
                       f"1/fps = {period:.6g} s")
    if t.dmd_window_offset_s + t.dmd_window_s > period * (1 + 1e-9):
        raise ctx.fail("timing.dmd_window_s",
                       f"impossible timing: dmd_window_offset_s + dmd_window_s = "
                       f"{t.dmd_window_offset_s + t.dmd_window_s:.6g} s exceeds the frame period "
                       f"1/fps = {period:.6g} s")


def check_accuracy(ctx, r: RenderSpec):
    if r.spp < r.mc_splits:
        raise ctx.fail("render.spp", f"must be >= render.mc_splits = {r.mc_splits} (the Monte Carlo "
                       f"error comes from {r.mc_splits} independent-seed renders, each needs a "
                       f"sample), got {r.spp}")
    if r.target_rel_error > 0 and r.max_spp < r.spp:
        raise ctx.fail("render.max_spp", f"must be >= render.spp = {r.spp} (the first pass of the "
                       f"error-targeted render), got {r.max_spp}")


def check_dmd_use(ctx, dmd: DMDSpec, t: TimingSpec, mask: MaskSpec):
    """A DMD that can act on the capture: its window overlaps the exposure, and the mask law
    has levels below white to use."""
    e0, e1 = t.exposure_offset_s, t.exposure_offset_s + t.exposure_s
    d0, d1 = t.dmd_window_offset_s, t.dmd_window_offset_s + t.dmd_window_s
    if min(e1, d1) - max(e0, d0) <= 0:
        raise ctx.fail("timing.dmd_window_offset_s",
                       f"the DMD window [{d0:.6g}, {d1:.6g}] s misses the exposure [{e0:.6g}, "
                       f"{e1:.6g}] s (from the frame start): no mask could act on the capture")
    from poevp_optics.camera.dmd import timing_problem

    from poevp_optics.control.exposure_time import exposure_time_problem

    problem = timing_problem(dmd, t) or exposure_time_problem(mask, dmd, t)
    if problem:
        raise ctx.fail(*problem)
    if mask.law == "exposure_controller" and not mask.band_low < mask.target < mask.band_high:
        raise ctx.fail("mask.target", f"the exposure controller aims inside its band: need band_low < "
                       f"target < band_high, got {mask.band_low:g} < {mask.target:g} < {mask.band_high:g}")
    if mask.envelope == "region_body" and mask.law != "exposure_controller":
        raise ctx.fail("mask.envelope", f"\"region_body\" splits the regions the exposure controller "
                       f"measured: it needs mask.law = \"exposure_controller\", got \"{mask.law}\"")
    top = (1 << dmd.bits) - 1
    if mask.law != "white" and mask.min_level >= top:
        raise ctx.fail("mask.min_level", f"must be < {top}, the white level of a {dmd.bits}-bit DMD "
                       f"(dmd.bits), so the mask law has a level that dims; got {mask.min_level}")


def check_sensor_levels(ctx, sensor: SensorSpec):
    """The preset with the scene's overrides leaves codes between black level and top code."""
    from poevp_optics.camera.sensor import SENSOR_PRESETS

    bits = sensor.bits if sensor.bits != -1 else SENSOR_PRESETS[sensor.preset].bits
    top = (1 << bits) - 1
    if not math.isnan(sensor.offset_dn) and sensor.offset_dn >= top:
        raise ctx.fail("sensor.offset_dn", f"must be below the top code {top} of the {bits}-bit ADC "
                       f"(sensor.bits), or no signal could be read; got {sensor.offset_dn:g}")


def check_plate(ctx, plate: PlateSpec):
    if plate.text and not plate.text.strip():
        raise ctx.fail("plate.text", f"blank text {plate.text!r}: give the plate's characters, "
                       "or leave it out ('') for the XML's own texture")
    if plate.band and plate.format != "eu":
        raise ctx.fail("plate.band", f"a {plate.format!r} plate has no blue band (only format 'eu' has)")


def check_predictor(ctx, path: Path, pred: PredictorSpec, cross_checks: bool) -> PredictorSpec:
    """Resolve `weights` against the scene's folder (as render.xml is) and check it is used."""
    if not pred.weights:
        return pred
    if cross_checks and not PREDICTORS[pred.name].takes_weights:
        raise ctx.fail("predictor.weights", f"predictor {pred.name!r} takes no weights (only "
                       f"{', '.join(takes_weights())} do); remove the key or change predictor.name")
    w = Path(pred.weights).expanduser()
    w = w if w.is_absolute() else (path.parent / w)
    w = w.resolve()
    if not w.is_file():
        raise ctx.fail("predictor.weights", f"weights file not found: {w}"
                       + (" (relative paths are read from the scene's folder)" if not Path(pred.weights).is_absolute() else ""))
    return dataclasses.replace(pred, weights=str(w))


#: Speed of light in vacuum, m/s (SI definition, exact).
SPEED_OF_LIGHT_M_PER_S = 299_792_458.0
#: Largest displacement a trajectory may reach during a run, m: 100 km is beyond any camera
#: scene here, and float32 vertex positions there are no finer than ~8 mm.
MAX_OFFSET_M = 1.0e5


def check_trajectory(ctx, key, m: MotionSpec, t: TimingSpec):
    """Physically possible and in the scene: finite, slower than light, within MAX_OFFSET_M over
    the run (frame starts 0 ... frames / fps, plus one frame)."""
    with np.errstate(all="ignore"):
        if m.kind == "linear":
            v = np.asarray(m.velocity_m_per_s, float)
            speed = float(np.sqrt(np.sum(v * v))) if np.all(np.isfinite(v)) else math.inf
            if speed >= SPEED_OF_LIGHT_M_PER_S:
                raise ctx.fail(f"{key}.velocity_m_per_s", f"{list(m.velocity_m_per_s)} m/s is not slower than "
                               f"light ({SPEED_OF_LIGHT_M_PER_S:.6g} m/s): check the value and its unit")
            end_s = (t.frames + 1) / t.fps
            far = [m.offset_m(0.0), m.offset_m(end_s)]
            what, name = f"at t = 0 and {end_s:.4g} s", f"{key}.start_offset_m"
        elif m.kind == "keyframes" and len(m.times_s) >= 2:
            offs = np.asarray(m.offsets_m, float)
            steps = np.linalg.norm(np.diff(offs, axis=0), axis=1) / np.diff(np.asarray(m.times_s, float))
            if not np.all(steps < SPEED_OF_LIGHT_M_PER_S):
                raise ctx.fail(f"{key}.offsets_m", "keyframes move faster than light between two times "
                               f"(up to {float(np.nanmax(steps)):.3g} m/s): check offsets_m and times_s")
            far, what, name = list(offs), "at a keyframe", f"{key}.offsets_m"
        else:
            return
        reach = max(float(np.linalg.norm(o)) if np.all(np.isfinite(o)) else math.inf for o in far)
    if reach > MAX_OFFSET_M:
        raise ctx.fail(name, f"the object is {reach:.3g} m from its XML pose {what}, beyond "
                       f"{MAX_OFFSET_M:g} m: it leaves the scene; check the values and their unit")


def check_motion(ctx, key, m: MotionSpec, t: TimingSpec | None = None):
    _check_keyframe_keys(ctx, key, m)
    if t is not None:
        check_trajectory(ctx, key, m, t)


def _check_keyframe_keys(ctx, key, m: MotionSpec):
    if m.kind == "keyframes":
        if len(m.times_s) < 1 or len(m.times_s) != len(m.offsets_m):
            raise ctx.fail(f"{key}.offsets_m",
                           f"keyframes need as many offsets_m as times_s "
                           f"({len(m.offsets_m)} vs {len(m.times_s)}), at least one")
        if any(b <= a for a, b in zip(m.times_s, m.times_s[1:])):
            raise ctx.fail(f"{key}.times_s", "keyframe times must increase strictly")
    elif m.times_s or m.offsets_m:
        raise ctx.fail(f"{key}.times_s", f"times_s/offsets_m only apply to kind = 'keyframes'")


_PHOTOMETRIC = {"intensity": "intensity_cd", "radiance": "luminance_cd_per_m2",
                "irradiance": "illuminance_lux"}


def check_spectrum(ctx, key, s: SpectrumSpec):
    from poevp_optics.sources.spectra import SpectrumError, load_spectrum

    given = [k for k in _PHOTOMETRIC.values() if not math.isnan(getattr(s, k))]
    if s.kind == "reflectance":
        if given:
            raise ctx.fail(f"{key}.{given[0]}", "a reflectance takes `scale`, not a photometric value")
    else:
        need = _PHOTOMETRIC[s.kind]
        wrong = [k for k in given if k != need]
        if wrong:
            raise ctx.fail(f"{key}.{wrong[0]}", f"kind = {s.kind!r} takes {need}")
        if need not in given:
            raise ctx.fail(f"{key}.{need}", f"required for kind = {s.kind!r} (absolute scale)")
        if s.scale != 1.0:
            raise ctx.fail(f"{key}.scale", "scale only applies to reflectances")
    try:
        values = load_spectrum(s.source, emissive=s.kind != "reflectance")
    except SpectrumError as e:
        raise ctx.fail(f"{key}.source", str(e)) from None
    if s.kind != "reflectance":
        from poevp_optics.sources.spectra import integrate, photopic_v

        if not integrate(photopic_v() * values) > 0:
            raise ctx.fail(f"{key}.source", f"{s.source}: the spectrum has no visible power (zero "
                           f"under V(lambda)), so it cannot be scaled to {_PHOTOMETRIC[s.kind]}")
    if s.kind == "reflectance" and float(np.max(values * s.scale)) > 1.0 + 1e-9:
        raise ctx.fail(f"{key}.scale", f"reflectance exceeds 1 (max {np.max(values * s.scale):.4g}): "
                       "energy would not be conserved")


def check_layout(ctx, sec: dict):
    from poevp_optics.camera.layout import LayoutError, layout_of

    try:
        layout_of(sec["sensor"], sec["dmd"], sec["relay"], sec["objective"])
    except LayoutError as e:
        raise ctx.fail(e.key, str(e)) from None
    check_objective(ctx, sec)


def check_objective(ctx, sec: dict):
    """[objective]: the glare radii in order, and a prescription's design field covering the
    rendered image's corner (sensor footprint on the DMD; the guard band is checked by the camera)."""
    from poevp_optics.camera.objective import PRESCRIPTIONS
    from poevp_optics.camera.layout import image_plane_pitch_m
    from poevp_optics.camera.sensor import resolve_sensor

    o = sec["objective"]
    if o.glare_outer_radius_deg < o.glare_core_radius_deg:
        raise ctx.fail("objective.glare_outer_radius_deg", f"{o.glare_outer_radius_deg:g} is below "
                       f"glare_core_radius_deg = {o.glare_core_radius_deg:g}")
    if o.psf != "prescription" and o.vignetting != "prescription":
        return
    h, w = sec["render"].resolution
    pitch = image_plane_pitch_m(sec["dmd"], resolve_sensor(sec["sensor"]))
    corner = math.degrees(math.atan(math.hypot(h / 2, w / 2) * pitch / o.focal_length_m))
    design = PRESCRIPTIONS[o.prescription].field_deg
    if corner > design:
        raise ctx.fail("objective.focal_length_m", f"{o.focal_length_m:g} m puts the image's corner "
                       f"{corner:.2f} deg off axis, beyond the {o.prescription!r} design field of "
                       f"{design:g} deg: use a longer focal length or a smaller render.resolution")


def check_plugin_tables(ctx, path: Path, spectra_, sheeting):
    """Photometric files of [spectra] lamps and [sheeting] tables (materials/): readable, in range."""
    from poevp_optics.render.materials.photometric_lamp import LampFileError, resolve_distribution
    from poevp_optics.render.materials.retroreflective import (SheetingError, parse_sheeting, retro_law,
                                                               sheeting_string)

    for ident, s in spectra_.items():
        if s.distribution:
            if s.kind != "intensity":
                raise ctx.fail(f"spectra.{ident}.distribution", "only a kind = 'intensity' lamp takes a distribution")
            try:
                resolve_distribution(s.distribution, path.parent)
            except LampFileError as e:
                raise ctx.fail(f"spectra.{ident}.distribution", str(e)) from None
    for ident, sh in sheeting.items():
        try:
            retro_law(parse_sheeting(sheeting_string(sh, path.parent)))
        except SheetingError as e:
            raise ctx.fail(f"sheeting.{ident}", str(e)) from None


def check_sensor_and_relay(ctx, path: Path, sensor: SensorSpec, relay: RelaySpec):
    from poevp_optics.sources.spectra import SpectrumError, load_spectrum

    if sensor.qe:
        try:
            load_spectrum(sensor.qe, emissive=True)
        except SpectrumError as e:
            raise ctx.fail("sensor.qe", str(e)) from None
    if relay.psf == "measured":
        if not relay.measured_file:
            raise ctx.fail("relay.measured_file", "required when psf = 'measured'")
        p = Path(relay.measured_file)
        cand = [p] if p.is_absolute() else [path.parent / p, ASSETS_DIR / p]
        if not any(c.is_file() for c in cand):
            raise ctx.fail("relay.measured_file", f"PSF image not found: {relay.measured_file}")


def check_source(ctx, path: Path, raw: dict, sec: dict, tables: dict) -> Path | None:
    """[source]: the kind's keys and their combinations (sources/kinds.py SOURCES), its files; a
    frame source refuses the sections only Mitsuba reads. Returns the XML path (None for frames)."""
    src: SourceSpec = sec["source"]
    kind = SOURCES[src.kind]
    given = frozenset(raw.get("source", {})) - {"kind"}
    for key in sorted(given - set(kind.keys)):
        raise ctx.fail(f"source.{key}", f"not a key of kind = {src.kind!r}"
                       + (f" (its keys: {', '.join(kind.keys)})" if kind.keys else " (it takes none)"))
    try:
        kind.check_keys(src, given, path.parent)
    except SourceKeyError as e:
        raise ctx.fail(f"source.{e.key}", str(e)) from None
    if src.renders:
        xml_path = (path.parent / sec["render"].xml).resolve()
        if not xml_path.is_file():
            raise ctx.fail("render.xml", f"Mitsuba scene file not found: {xml_path}")
        return xml_path
    why = f"source.kind = {src.kind!r} takes its radiance from frames"
    for name in ("motion", "spectra", "flicker", "sheeting"):
        if tables[name]:
            raise ctx.fail(f"{name}.{next(iter(tables[name]))}", f"{why}: [{name}] applies to kind = 'mitsuba' only")
    for key in ("xml", "roi_shape"):
        if key in raw.get("render", {}):
            raise ctx.fail(f"render.{key}", f"{why}: no Mitsuba scene to read (the ROI comes from source.boxes)")
    if sec["plate"].text:
        raise ctx.fail("plate.text", f"{why}: the plate text comes from source.boxes (or source.text)")
    if sec["chart"].patches:
        raise ctx.fail("chart.patches", f"{why}: a dynamic-range chart is rendered by Mitsuba (kind = 'mitsuba')")
    return None


def check_road(ctx, road, spectra_, sheeting, vehicle) -> None:
    """[road] (sources/road.py): its high beam names an intensity lamp with a photometric file,
    its sheeting a [sheeting] entry (the per-frame report reads both), and a plate-carrying
    `road.vehicle` names a [vehicle.<id>] whose plate is at plate_position_m, facing us."""
    from poevp_optics.sources.road import vehicle_plate_problem

    problem = vehicle_plate_problem(road, vehicle)
    if problem:
        raise ctx.fail(*problem)
    lamp = spectra_.get(road.highbeam)
    if lamp is None or lamp.kind != "intensity" or not lamp.distribution:
        raise ctx.fail("road.highbeam", f"{road.highbeam!r} must name a [spectra] entry of kind 'intensity' "
                       "with a photometric distribution (our high beams)")
    if road.sheeting not in sheeting:
        raise ctx.fail("road.sheeting", f"{road.sheeting!r} names no [sheeting] entry")


def check_controller_prior(ctx, mask: MaskSpec, road, spectra_, has_road: bool) -> None:
    """`mask.prior_beam_cd`: the prior it scales (scene/resolve.py `prior_first_guess`, reported as
    derived; the spec keeps the written first_guess) needs a [road] high beam and must land in
    first_guess's own range [1, 1e9] x saturation."""
    from poevp_optics.scene.resolve import prior_first_guess

    if mask.prior_beam_cd == 0 or mask.law != "exposure_controller":
        return                          # other laws have no prior (first_guess is inert there too)
    key = "mask.prior_beam_cd"
    if not has_road:
        raise ctx.fail(key, "needs a [road] section: the prior follows its high beam's intensity_cd")
    guess = prior_first_guess(mask, road, spectra_, has_road)
    if not 1.0 <= guess <= 1e9:
        beams_cd = spectra_[road.highbeam].intensity_cd
        raise ctx.fail(key, f"first_guess {mask.first_guess:g} x {beams_cd:g} cd / "
                       f"{mask.prior_beam_cd:g} cd = {guess:.4g} x saturation, outside [1, 1e9]")


def check_metering(ctx, sec: dict):
    """`loop.meter_init`: metered initialisation frames are the exposure controller's mask from
    the last capture, so they need its law and a causal predictor (the oracle reads the truth)."""
    if not sec["loop"].meter_init:
        return
    if sec["mask"].law != "exposure_controller":
        raise ctx.fail("loop.meter_init", f"meters with the 'exposure_controller' mask law, not {sec['mask'].law!r}")
    if PREDICTORS[sec["predictor"].name].needs_truth:
        raise ctx.fail("loop.meter_init", f"the {sec['predictor'].name!r} predictor reads the true frame: "
                       "it has nothing to meter")


def check_attenuator(ctx, sec: dict):
    """[attenuator]: an enabled one needs the DMD, a mask law that takes its transmission
    (`target`, `exposure_controller`) and time to settle between two exposures."""
    a = sec["attenuator"]
    if not a.enabled:
        return
    if not sec["dmd"].enabled:
        raise ctx.fail("attenuator.kind", f"{a.kind!r} is set with the mask's law: it needs [dmd] enabled")
    if sec["mask"].law not in ATTENUATED_LAWS:
        raise ctx.fail("attenuator.kind", f"{a.kind!r} is set by the {' or '.join(map(repr, ATTENUATED_LAWS))} "
                       f"mask law, not {sec['mask'].law!r}")
    t = sec["timing"]
    gap = 1.0 / t.fps - t.exposure_s
    if a.settle_s > gap:
        raise ctx.fail("attenuator.settle_s", f"impossible timing: {a.settle_s * 1e3:.3g} ms to settle, but "
                       f"only {gap * 1e3:.3g} ms between two exposures (1/fps - exposure_s): every "
                       f"setting would arrive late")


def check_world(ctx, marking, vehicle, furniture) -> None:
    """[marking.<param>] sources parse (render/materials/road_marking.py); each [vehicle.<id>]'s
    shape is buildable (sources/vehicles.py: parts fit the body, the plate its recess); each
    [furniture.<id>] fits together (sources/furniture.py)."""
    from poevp_optics.sources.furniture import FurnitureError, resolve as resolve_furniture

    from poevp_optics.render.materials.retroreflective import SheetingError
    from poevp_optics.render.materials.road_marking import parse_marking
    from poevp_optics.sources.vehicles import VehicleShapeError, shape_of

    for ident, m in marking.items():
        try:
            parse_marking(m.source)
        except SheetingError as e:
            raise ctx.fail(f"marking.{ident}.source", str(e)) from None
    for ident, v in vehicle.items():
        try:
            shape_of(v)
        except VehicleShapeError as e:
            raise ctx.fail(f"vehicle.{ident}.{e.key}", str(e)) from None
    for ident, fu in furniture.items():
        try:
            resolve_furniture(fu)
        except FurnitureError as e:
            raise ctx.fail(f"furniture.{ident}.{e.key}", str(e)) from None
