"""Mitsuba 3 rendering of a scene to absolute sensor-weighted photon radiance.

One render gives, per pixel, the integral over wavelength of the sensor's photon response
S(lambda) = QE(lambda) lambda / (h c) times the scene's spectral radiance: photo-electrons
s-1 m-2 sr-1 (`units.PHOTON_RADIANCE_UNIT`). Two paths (the report says which ran and why):

* spectral: `specfilm` with S(lambda) as its one channel; emitters and reflectances carry
  their tabulated spectra; Mitsuba samples wavelengths (FACTS.md: unnormalised integral).
* mono (pre-integrated): each emitter becomes the scalar integral of S times its SPD and each
  reflectance its S-and-SPD-weighted mean. Exact, with no wavelength noise, when every
  reflectance is spectrally flat, or when all emitters share one SPD shape and light bounces
  once (max_depth <= 2): then the per-path integral factorises.

The XML is loaded once; moving shapes and emitters are displaced per time sample through
`mi.traverse` + `params.update()`. A pixel is the box-filtered area average of radiance.
Monte Carlo error: the samples of each sub-frame are split into `mc_splits` renders with
independent seeds; their spread gives the per-pixel standard error (the `moment` integrator
fails with specfilm, FACTS.md).
"""

from __future__ import annotations

import math
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from poevp_optics.core import runtime
from poevp_optics.core.exceptions import SceneError
from poevp_optics.core.params import param
from poevp_optics.render.lights import LIGHT_SELECTIONS
from poevp_optics.render.opaque import opaque_pose
from poevp_optics.render.roi import ALL_PLATES, roi_targets
from poevp_optics.render.samplers import SAMPLERS, sample_count
from poevp_optics.sources import spectra

#: Default `render.sampler`, chosen from benchmarks/results/render_error_vs_time.md (time to 1 %
#: plate error): see README.
DEFAULT_SAMPLER = "multijitter"

_EMISSIVE_KINDS = ("intensity", "radiance", "irradiance")


@dataclass(frozen=True)
class RenderSpec:
    """[render]: the Mitsuba scene and its sampling; spp, subframes, pwm_nodes, temporal_spp,
    mc_splits, sampler, light_selection, target_rel_error and max_spp are accuracy settings
    (core/accuracy.py). roi_spp: samples per pixel added over each ROI's image box (`roi_shape`),
    pooled with `spp` there (exposures.add_roi_samples; ignored when target_rel_error > 0, which
    aims the frame's renders at the ROI error already)."""

    xml: str = param("scene.xml")
    spp: int = param(16, min=1, max=1 << 20)
    resolution: tuple[int, int] = param((368, 640), length=2, min=1, max=16384)
    subframes: int = param(4, min=1, max=4096)          # uniform radiance nodes in time per exposure
    pwm_nodes: bool = param(True)                       # also sample at the DMD's switching times
    temporal_spp: int = param(0, min=0, max=1 << 20)    # spp of the temporal-error check; 0: render.spp
    seed: int = param(0, min=0, max=2**31 - 1)
    variant: str = param("auto")                        # "auto" or a Mitsuba variant name
    spectral_mode: str = param("auto", choices=("auto", "spectral", "mono"))
    mc_splits: int = param(2, min=2, max=64)            # independent-seed renders for MC error
    roi_shape: str = param("")                          # shape id whose image box is the ROI, or "plates" (render/roi.py)
    sampler: str = param(DEFAULT_SAMPLER, choices=SAMPLERS)             # render/samplers.py
    light_selection: str = param("power", choices=LIGHT_SELECTIONS)    # render/lights.py
    target_rel_error: float = param(0.0, min=0.0, max=1.0,              # 0: off; else render/progressive.py
                                    why="a relative MC error (ROI, or frame) between 0 and 1")
    max_spp: int = param(4096, min=1, max=1 << 20)      # cap of the error-targeted render per radiance sample
    roi_spp: int = param(0, min=0, max=1 << 20)         # 0: off; else spp added over the ROI shape's box
    #                                                     (exposures.add_roi_samples; untargeted renders)


@dataclass(frozen=True)
class SpectralPlan:
    """How the scene's spectra enter Mitsuba: mode, why, and the XML parameter values."""

    mode: str                        # "spectral" | "mono"
    reason: str
    xml_params: dict[str, str]
    response_e_per_J: np.ndarray     # S(lambda) on spectra.WAVELENGTHS_NM
    notes: tuple[str, ...] = ()      # e.g. emission tables that end inside the sensor's response


@dataclass(frozen=True)
class XmlFacts:
    """What the planner needs to know from the Mitsuba XML."""

    defaults: frozenset[str]
    max_depth: int                   # -1: unbounded
    emitter_params: frozenset[str]   # $params used inside <emitter> spectra
    problems: tuple[str, ...]        # literal spectra on emitters, <rgb> elements


def read_xml_facts(xml_path: Path) -> XmlFacts:
    """Scan the Mitsuba XML for declared parameters, integrator depth and spectra usage."""
    try:
        root = ET.parse(xml_path).getroot()
    except ET.ParseError as e:
        raise SceneError(f"{xml_path}: malformed XML: {e}") from None
    defaults = frozenset(d.get("name") for d in root.iter("default"))
    max_depth = -1
    for integ in root.iter("integrator"):
        for node in integ.iter("integer"):
            if node.get("name") == "max_depth":
                max_depth = int(node.get("value"))
    emitter_params, problems = set(), []
    for em in root.iter("emitter"):
        for sp in em.iter("spectrum"):
            v = (sp.get("value") or "").strip()
            if v.startswith("$"):
                emitter_params.add(v[1:])
            else:
                problems.append(f"emitter {em.get('id') or em.get('type')!r} has a literal spectrum "
                                f"{v[:30]!r}: bind it to a [spectra] parameter so it has absolute units")
    for rgb in root.iter("rgb"):
        problems.append(f"<rgb name={rgb.get('name')!r}> found: use a [spectra] parameter "
                        "(RGB upsampling is not a measured spectrum)")
    return XmlFacts(defaults, max_depth, frozenset(emitter_params), tuple(problems))


def absolute_spectrum(spec_entry) -> np.ndarray:
    """A [spectra] entry as absolute values on the grid (W sr-1 nm-1 etc., or reflectance)."""
    if spec_entry.kind == "reflectance":
        return spectra.load_spectrum(spec_entry.source, emissive=False) * spec_entry.scale
    shape = spectra.load_spectrum(spec_entry.source, emissive=True)
    value = {"intensity": spec_entry.intensity_cd, "radiance": spec_entry.luminance_cd_per_m2,
             "irradiance": spec_entry.illuminance_lux}[spec_entry.kind]
    return spectra.scale_to_photometric(shape, value)


def check_bindings(scene, facts: XmlFacts) -> None:
    """Every [spectra] entry binds a declared XML parameter, every emitter spectrum is bound."""
    file = scene.toml_path
    if facts.problems:
        raise SceneError(f"{scene.xml_path}: {facts.problems[0]}")
    for name, entry in scene.spectra.items():
        if name not in facts.defaults:
            raise SceneError(f"{file}: spectra.{name}: the XML {scene.xml_path.name} declares no "
                             f"<default name=\"{name}\"> parameter to bind")
        if name in facts.emitter_params and entry.kind not in _EMISSIVE_KINDS:
            raise SceneError(f"{file}: spectra.{name}.kind: used by an emitter, must be one of "
                             f"{_EMISSIVE_KINDS}")
    for name in facts.emitter_params:
        if name not in scene.spectra:
            raise SceneError(f"{file}: spectra.{name}: emitter parameter ${name} of "
                             f"{scene.xml_path.name} has no [spectra.{name}] entry (absolute units)")


def _choose_path(scene, facts: XmlFacts, eligible: bool, why: str, force_mode: str | None) -> tuple[str, str]:
    """The render path (spectral or mono) and why."""
    mode = force_mode or scene.render.spectral_mode
    if mode == "mono" and not eligible:
        raise SceneError(f"{scene.toml_path}: render.spectral_mode: 'mono' would not be exact here ({why})")
    if mode == "auto":
        mode = "mono" if eligible else "spectral"
        return mode, (f"auto: pre-integrated mono render is exact ({why})" if eligible
                      else f"auto: spectral render needed ({why})")
    if force_mode:
        return mode, f"spectral: no mono Mitsuba variant on this machine ({why})"
    return mode, f"requested in the scene file ({why})"


def _mono_values(response, values, emissive, reflect, shapes) -> dict[str, str]:
    """Pre-integrated XML values: emitters as integral(S x SPD), reflectances as their S- and
    SPD-weighted mean."""
    params = {}
    weight = shapes[0] if shapes else np.ones_like(response)
    norm = spectra.integrate(response * weight)
    for n in emissive:
        params[n] = f"{spectra.integrate(response * values[n]):.9g}"
    for n in reflect:
        r = values[n]
        eff = (float(np.mean(r)) if spectra.is_neutral(r) or not norm > 0
               else spectra.integrate(response * weight * r) / norm)
        params[n] = f"{eff:.9g}"
    return params


def plan_spectra(scene, force_mode: str | None = None) -> SpectralPlan:
    """Check the [spectra] bindings against the XML and choose the spectral or mono path.

    force_mode: "spectral" overrides the scene's choice (used when no mono variant exists).
    """
    facts = read_xml_facts(scene.xml_path)
    check_bindings(scene, facts)
    response = spectra.sensor_response_e_per_J(spectra.load_spectrum(scene.sensor_qe, emissive=True))
    values = {n: absolute_spectrum(e) for n, e in scene.spectra.items()}
    emissive = [n for n, e in scene.spectra.items() if e.kind in _EMISSIVE_KINDS]
    reflect = [n for n, e in scene.spectra.items() if e.kind == "reflectance"]
    # a lamp switched off (0 cd) adds no light: its SPD shape does not matter to the plan
    shapes = [spectra.normalised_shape(values[n]) for n in emissive
              if spectra.integrate(response * values[n]) > 0]
    one_shape = all(np.allclose(s, shapes[0], rtol=1e-6, atol=1e-12) for s in shapes[1:]) if shapes else True
    flat = all(spectra.is_neutral(values[n]) for n in reflect)
    if flat:
        eligible, why = True, "every reflectance is spectrally flat: the wavelength integral factorises"
    elif one_shape and facts.max_depth in (1, 2):
        eligible, why = True, ("all emitters share one SPD shape and light bounces once "
                               f"(max_depth={facts.max_depth}): the wavelength integral factorises")
    else:
        eligible = False
        why = ("emitters have different SPD shapes" if not one_shape else
               f"multiple bounces (max_depth={facts.max_depth}) over non-flat reflectances")
    mode, reason = _choose_path(scene, facts, eligible, why, force_mode)
    params = ({n: spectra.to_mitsuba(v) for n, v in values.items()} if mode == "spectral"
              else _mono_values(response, values, emissive, reflect, shapes))
    from poevp_optics.render.materials.bindings import plugin_xml_params  # photometric lamps, retroreflective sheeting

    params.update(plugin_xml_params(scene, facts.defaults))
    if scene.plate.text:
        if scene.plate.param not in facts.defaults:
            raise SceneError(f"{scene.toml_path}: plate.param: the XML {scene.xml_path.name} declares no "
                             f"<default name=\"{scene.plate.param}\"> for the plate texture")
        from poevp_optics.sources.plates import cached_plate_path

        params[scene.plate.param] = str(cached_plate_path(scene.plate.text, scene.plate.width_px,
                                                         scene.plate.height_px, plate_format=scene.plate.format,
                                                         band=scene.plate.band))
    if scene.has_road:
        from poevp_optics.sources.road import xml_params as road_xml_params

        road = road_xml_params(scene.road)
        missing = sorted(set(road) - set(facts.defaults))
        if missing:
            raise SceneError(f"{scene.toml_path}: road: the XML {scene.xml_path.name} declares no "
                             f"<default name=\"{missing[0]}\"> ({len(missing)} of the [road] parameters missing)")
        params.update(road)
    from poevp_optics.sources.world import world_xml_params   # [weather], [vehicle.<id>]

    params.update(world_xml_params(scene, facts.defaults))
    notes = tuple(n for n in (spectra.coverage_note(name, scene.spectra[name].source, response)
                              for name in emissive) if n)
    return SpectralPlan(mode, reason, params, response, notes)


@dataclass
class RenderStats:
    """Counters for the report: number of mi.render calls and their wall time (s)."""

    calls: int = 0
    seconds: float = 0.0
    samples_per_pixel: int = 0
    variant: str = ""
    extra: dict = field(default_factory=dict)


def mitsuba_load_error(text: str, scene, printed=()) -> str:
    """Mitsuba's loader error as one line: the innermost file + line, and for a parameter the
    TOML key that binds it (`Found unused parameters: - $ink=0.0336` names no file)."""
    import re

    text = re.sub(r"\[[\w.]+:\d+\]\s*", "", text)
    unused = re.findall(r"\$([A-Za-z_]\w*)=", text) if "unused parameter" in text else []
    if unused:
        keys = [f"spectra.{n}" if n in scene.spectra else "plate.text" if n == scene.plate.param else n
                for n in unused]
        return (f"{scene.xml_path}: no element uses the parameter(s) {', '.join('$' + n for n in unused)}, "
                f"but {scene.toml_path}: {', '.join(keys)} binds them; write value=\"$name\" where it belongs "
                "in the XML, or remove the key")
    places = re.findall(r"(?:Error while loading|At) (.+?) \(line (\d+), col \d+\):\s*", text)
    tail = re.split(r"(?:Error while loading|At) .+? \(line \d+, col \d+\):\s*", text)[-1]
    tail = " ".join(tail.split())
    bitmap = re.search(r'plugin of type "bitmap".*?"([^"]+)"', tail)
    if bitmap:
        tail = f"texture file {bitmap.group(1)} is not an image Mitsuba reads ({tail})"
    where = f"{places[-1][0]}: line {places[-1][1]}" if places else str(scene.xml_path)
    extra = " ".join(" ".join(printed).split())
    return f"{where}: Mitsuba could not load the scene: {tail}" + (f" (Mitsuba printed: {extra[:200]})" if extra else "")


class Renderer:
    """A loaded Mitsuba scene that can be posed at a time and rendered (stateful: the scene)."""

    def __init__(self, scene, zero_params: frozenset[str] = frozenset(), guard_px: int = 0):
        """scene: the render's own inputs (render/render_scene.py RenderScene, resolved by
        scene/resolve.py: the XML, [render], spectra, motion, the sensor's QE curve, accuracy).
        zero_params: emitter parameters set to zero in this instance (one emitter group's
        image for flickering lamps, loop.render_exposures). guard_px: pixels rendered beyond
        each edge of `render.resolution` at the same focal length (the camera's guard band for
        its PSFs, camera.Camera.guard_px); images are (H + 2 guard, W + 2 guard)."""
        import mitsuba as mi

        self.scene = scene
        self.guard_px = int(guard_px)
        self.plan = plan_spectra(scene)
        variant, why = runtime.choose_variant(self.plan.mode, scene.render.variant)
        if self.plan.mode == "mono" and "mono" not in variant:
            # no scalar mono variant: fall back to the spectral path, which is always exact
            self.plan = plan_spectra(scene, force_mode="spectral")
            variant, why = runtime.choose_variant("spectral", scene.render.variant)
        if zero_params:
            zero = "0" if self.plan.mode == "mono" else spectra.to_mitsuba(np.zeros_like(self.plan.response_e_per_J))
            self.plan = SpectralPlan(self.plan.mode, self.plan.reason,
                                     {**self.plan.xml_params, **{n: zero for n in zero_params}},
                                     self.plan.response_e_per_J, self.plan.notes)
        runtime.set_variant(variant)
        runtime.register_asset_dir(spectra.ASSETS_DIR)
        self.variant, self.variant_reason = variant, why
        self.mi = mi
        from poevp_optics.core.failures import quiet_native_stderr

        try:
            with quiet_native_stderr() as printed:
                # optimize=False: Mitsuba's load-time merging of shapes that share a BSDF puts
                # the merged shapes' area emitters in the scene's emitter list in an order that
                # changes from one load to the next (4 of 30 loads of night_road in one process),
                # and the emitter sampler draws by that order, so the same seed rendered other
                # samples (~3 % of pixels, up to 8x apart) and the pilot summed its moments in
                # another order (light weights 1e-10 apart). Unmerged, the list is the XML's
                # order on every load.
                self.mi_scene = mi.load_file(str(scene.xml_path), optimize=False, **self.plan.xml_params)
        except Exception as e:  # noqa: BLE001 - Mitsuba raises RuntimeError with a long trace
            raise SceneError(mitsuba_load_error(str(e) or type(e).__name__, scene, printed)) from None
        if "".join(printed).strip():   # Mitsuba's log of a scene that loads: a warning, not loose text
            import warnings

            warnings.warn(f"Mitsuba loading {scene.xml_path.name}: {''.join(printed)[:500]}", stacklevel=2)
        self.params = mi.traverse(self.mi_scene)
        # Moving objects: analytic shapes and emitters expose `to_world`; meshes bake their
        # transform into `vertex_positions`, which we translate directly (motion is a translation).
        self._base, self._base_vertices = {}, {}
        for ident, motion in scene.motion.items():
            for target in (ident, *motion.attached):
                if f"{target}.to_world" in self.params:
                    self._base[target] = mi.Transform4f(self.params[f"{target}.to_world"])
                elif f"{target}.vertex_positions" in self.params:
                    self._base_vertices[target] = np.array(self.params[f"{target}.vertex_positions"]).copy()
                else:
                    hint = ""
                    if any(k.startswith("object_") for k in self.params.keys()):
                        hint = (" (Mitsuba 3.7+ merges meshes whose BSDFs are identical into one "
                                "anonymous shape: give a moving mesh a material of its own)")
                    raise SceneError(f"{scene.toml_path}: motion.{ident}: no shape or emitter with "
                                     f"id {target!r} in {scene.xml_path.name}{hint}")
        self.sensor = self._make_sensor()
        self._roi_shape = None
        self._roi_shapes = []           # [(RoiTarget, shape)]: render/roi.py
        self.multi_roi = scene.render.roi_shape == ALL_PLATES
        self._views, self._views_time = None, None
        if scene.render.roi_shape:
            by_id = {s.id(): s for s in self.mi_scene.shapes()}
            for target in roi_targets(scene):
                if target.shape_id not in by_id:
                    raise SceneError(f"{scene.toml_path}: render.roi_shape: no shape with id "
                                     f"{target.shape_id!r} in {scene.xml_path.name}")
                self._roi_shapes.append((target, by_id[target.shape_id]))
            self._roi_shape = self._roi_shapes[0][1]
        self.stats = RenderStats(variant=variant)
        self._time = None
        self.light_weights: dict[str, float] | None = None   # set before the first render
        self._pilot_area = 0                                  # ROI box area (px) at the last pilot

    def _make_sensor(self):
        mi = self.mi
        cams = self.mi_scene.sensors()
        if not cams:
            raise SceneError(f"{self.scene.xml_path}: the XML has no <sensor> (camera pose and fov)")
        cam_id = cams[0].id()
        p = self.params

        def get(name, default=None):
            key = f"{cam_id}.{name}"
            if key not in p:
                return default
            v = p[key]
            return float(v[0]) if hasattr(v, "__len__") else float(v)

        if get("x_fov") is None:
            raise SceneError(f"{self.scene.xml_path}: sensor {cam_id!r} must be a perspective camera")
        to_world = mi.ScalarTransform4f(np.array(p[f"{cam_id}.to_world"].matrix).reshape(4, 4))
        medium = cams[0].get_medium()     # a camera inside fog (sources/weather.py) keeps its medium
        h0, w0 = self.scene.render.resolution
        g = self.guard_px
        h, w = h0 + 2 * g, w0 + 2 * g
        # same focal length over a wider film: tan(fov / 2) grows with the film width
        fov_deg = math.degrees(2 * math.atan(math.tan(math.radians(get("x_fov")) / 2) * w / w0))
        if self.plan.mode == "spectral":
            film = {"type": "specfilm", "width": w, "height": h, "component_format": "float32",
                    "rfilter": {"type": "box"},
                    "S": {"type": "irregular",
                          "wavelengths": ", ".join(f"{x:g}" for x in spectra.WAVELENGTHS_NM),
                          "values": ", ".join(f"{x:.7g}" for x in self.plan.response_e_per_J)}}
        else:
            film = {"type": "hdrfilm", "width": w, "height": h, "pixel_format": "luminance",
                    "component_format": "float32", "rfilter": {"type": "box"}}
        return mi.load_dict({
            "type": "perspective", "fov": fov_deg, "fov_axis": "x", "to_world": to_world,
            "near_clip": get("near_clip", 0.01), "far_clip": get("far_clip", 1e4),
            # offsets are in units of the film size: keep them fixed in pixels
            "principal_point_offset_x": get("principal_point_offset_x", 0.0) * w0 / w,
            "principal_point_offset_y": get("principal_point_offset_y", 0.0) * h0 / h,
            "film": film, "sampler": SAMPLERS[self.scene.render.sampler].mitsuba_dict(1),
            **({"medium": medium} if medium is not None else {})})

    # ------------------------------------------------------------------ posing
    def set_time(self, t_s: float) -> None:
        """Displace every moving object to its pose at time `t_s` (s)."""
        if not (self._base or self._base_vertices) or self._time == t_s:
            return
        mi = self.mi
        for ident, motion in self.scene.motion.items():
            off = motion.offset_m(t_s)
            tr = mi.Transform4f().translate(mi.Vector3f(*map(float, off)))
            for target in (ident, *motion.attached):
                if target in self._base:      # opaque: one kernel for every pose (render/opaque.py)
                    self.params[f"{target}.to_world"] = opaque_pose(tr @ self._base[target])
                else:
                    verts = self._base_vertices[target].reshape(-1, 3) + off[None, :]
                    self.params[f"{target}.vertex_positions"] = mi.Float(verts.astype(np.float32).ravel())
        self.params.update()
        self._time = t_s
        if self._roi_shape is not None and LIGHT_SELECTIONS[self.scene.render.light_selection].from_pilot:
            box = self.roi_box()           # the ROI grew/shrank > 25 % since the pilot: re-select
            area = (box[2] - box[0]) * (box[3] - box[1]) if box else 0
            if self._pilot_area and area and not 0.8 <= area / self._pilot_area <= 1.25:
                self.light_weights = None  # (a pilot costs ~ a render: JIT; not at every pose)

    def roi_box(self) -> tuple[int, int, int, int] | None:
        """Image box (y0, x0, y1, x1), end-exclusive, of the ROI shape at the current pose, in
        the rendered grid (guard band included); with `render.roi_shape = "plates"`, the box of
        the nearest plate in view (render/roi.py)."""
        if self._roi_shape is None:
            return None
        if self.multi_roi:
            views = [v for v in self.plate_views().values() if v.in_view]
            return min(views, key=lambda v: v.distance_m).box if views else None
        from poevp_optics.render.roi import project_box

        return project_box(self, self._roi_shape)

    def plate_views(self) -> dict:
        """{ROI label: render/roi.py PlateView} of every ROI shape at the current pose (once per pose)."""
        from poevp_optics.render.roi import plate_view, project_box

        if self._views is None or self._views_time != self._time:
            self._views = {t.label: plate_view(self, shape, project_box(self, shape)) for t, shape in self._roi_shapes}
            self._views_time = self._time
        return self._views

    def roi_boxes(self) -> dict:
        """{ROI label: box} of the ROIs that get their own samples at the current pose: with
        "plates" every plate in view (render/roi.py), else the one ROI shape's box."""
        if not self.multi_roi:
            box = self.roi_box()
            return {self._roi_shapes[0][0].label: box} if box is not None else {}
        return {k: v.box for k, v in self.plate_views().items() if v.in_view}

    @property
    def roi_labels(self) -> tuple:
        """The ROI targets (render/roi.py RoiTarget) in the scene's order."""
        return tuple(t for t, _ in self._roi_shapes)

    # ------------------------------------------------------------------ rendering
    def select_lights(self) -> dict[str, float]:
        """Set the emitters' sampling weights by `render.light_selection` (render/lights.py) at
        the current pose; returns {emitter id: weight} (the report's `light_weights`)."""
        from poevp_optics.render.lights import set_sampling_weights, weights_from_moments

        choice = LIGHT_SELECTIONS[self.scene.render.light_selection]
        keys = {em.id(): f"{em.id()}.sampling_weight" for em in self.mi_scene.emitters()}
        keys = {k: v for k, v in keys.items() if v in self.params}
        if choice.keep_xml:
            weights = {k: float(self.params[v]) for k, v in keys.items()}
        else:
            weights = (weights_from_moments(self._pilot_moments())
                       if choice.from_pilot else {k: 1.0 for k in keys})
            set_sampling_weights(self.params, {k: weights.get(k, 1.0) for k in keys})
        self.light_weights = {k: weights[k] for k in keys if k in weights}
        self.stats.extra["light_weights"] = self.light_weights
        return self.light_weights

    def _pilot_moments(self) -> dict[str, float]:
        """The pilot's per-emitter second moments over the frame, combined with those over the
        ROI box at the current pose when there is one (render/lights.py roi_weighted_moments)."""
        from poevp_optics.render.lights import pilot_moments, roi_weighted_moments

        frame = pilot_moments(self.mi, self.mi_scene, self.sensor, self.scene.render.seed)
        if self.multi_roi:               # every plate in view a region of its own (render/roi.py)
            from poevp_optics.render.roi import plates_pilot_moments

            moments, self._pilot_area = plates_pilot_moments(self, frame)
            return moments
        box = self.roi_box() if self._roi_shape is not None else None
        if box is None:
            return frame[0]
        h, w = (n + 2 * self.guard_px for n in self.scene.render.resolution)
        y0, x0, y1, x1 = box
        self._pilot_area = (y1 - y0) * (x1 - x0)
        roi = pilot_moments(self.mi, self.mi_scene, self.sensor, self.scene.render.seed,
                            (x0 / w, y0 / h, x1 / w, y1 / h))
        return roi_weighted_moments([frame, roi])

    def sample_count(self, spp: int) -> int:
        """The spp Mitsuba renders for a request of `spp` with this run's sampler."""
        return sample_count(self.scene.render.sampler, spp)

    def render_once(self, seed: int, spp: int) -> np.ndarray:
        """One mi.render call: (H, W) float32 photon radiance. `self.last_spp` is the spp the
        sampler used (some round the count: render/samplers.py)."""
        if self.light_weights is None:
            self.select_lights()
        t0 = time.perf_counter()
        img = self.mi.render(self.mi_scene, sensor=self.sensor, seed=int(seed) & 0x7FFFFFFF, spp=int(spp))
        arr = np.array(img, dtype=np.float32)
        self.stats.seconds += time.perf_counter() - t0
        self.stats.calls += 1
        self.last_spp = int(self.sensor.sampler().sample_count())
        arr = arr[..., 0] if arr.ndim == 3 else arr
        if not np.all(np.isfinite(arr)):
            bad = int(np.count_nonzero(~np.isfinite(arr)))
            raise FloatingPointError(f"{self.scene.xml_path}: render produced {bad} NaN/Inf pixels")
        return arr

    def render_box(self, seed: int, spp: int, box) -> np.ndarray:
        """`spp` samples per pixel of the pixels in `box` (y0, x0, y1, x1, end-exclusive, on the
        rendered grid) only: (y1 - y0, x1 - x0) float64 photon radiance, the same estimator as
        one mi.render call restricted to those pixels. The lanes are pixel-major with `spp`
        consecutive samples per pixel, as Mitsuba's wavefront render orders them (so a
        stratified sampler stratifies each pixel's samples), and each lane draws its dimensions
        in the order of Mitsuba's SamplingIntegrator::render_sample (film position, then the
        integrator's own); the camera's box filter keeps a sample in its pixel. Mono path only
        (the spectral path's `specfilm` weights wavelengths in the film). `self.last_spp`: the
        sampler's count."""
        mi = self.mi
        if self.plan.mode != "mono":
            raise SceneError(f"{self.scene.toml_path}: render.roi_spp: the ROI box render needs the mono "
                             f"path (this scene renders {self.plan.mode}: {self.plan.reason})")
        if self.light_weights is None:
            self.select_lights()
        t0 = time.perf_counter()
        y0, x0, y1, x1 = box
        h, w = y1 - y0, x1 - x0
        sampler = mi.load_dict(SAMPLERS[self.scene.render.sampler].mitsuba_dict(int(spp)))
        n = int(sampler.sample_count())
        hh, ww = (k + 2 * self.guard_px for k in self.scene.render.resolution)
        lanes = h * w * n
        sampler.set_samples_per_wavefront(n)                 # lane % n: the sample index in its pixel
        sampler.seed(int(seed) & 0x7FFFFFFF, lanes)
        pix = np.arange(h * w, dtype=np.int64)
        py = (y0 + pix // w).astype(np.float32)
        px = (x0 + pix % w).astype(np.float32)
        idx = mi.UInt32(np.repeat(np.arange(h * w, dtype=np.uint32), n))
        import drjit as dr

        pos = sampler.next_2d()
        fx = (dr.gather(mi.Float, mi.Float(px), idx) + pos.x) / ww
        fy = (dr.gather(mi.Float, mi.Float(py), idx) + pos.y) / hh
        ray, ray_w = self.sensor.sample_ray(mi.Float(self.sensor.shutter_open()), mi.Float(0.5),
                                            mi.Point2f(fx, fy), mi.Point2f(0.5, 0.5))
        # the camera's medium (fog around it: sources/weather.py), as Mitsuba's own render passes it
        L, _, _ = self.mi_scene.integrator().sample(self.mi_scene, sampler, ray, self.sensor.get_medium(), True)
        val = np.array(ray_w * L, dtype=np.float64)
        val = val.reshape(-1, lanes).mean(axis=0) if val.size != lanes else val.ravel()
        out = val.reshape(h * w, n).mean(axis=1).reshape(h, w)
        self.stats.seconds += time.perf_counter() - t0
        self.stats.calls += 1
        self.last_spp = n
        if not np.all(np.isfinite(out)):
            raise FloatingPointError(f"{self.scene.xml_path}: ROI render produced NaN/Inf pixels")
        return out

    def render_box_with_error(self, seeds: list[int], spp: int, box) -> tuple[np.ndarray, np.ndarray, int]:
        """`render_box` in len(seeds) equal independent-seed parts: (mean, variance of the mean,
        spp used), as `render_with_error`."""
        n = len(seeds)
        parts = [self.render_box(s, max(1, spp // n), box) for s in seeds]
        used = self.last_spp * n
        mean = sum(parts) / n
        var = sum((m - mean) ** 2 for m in parts) / (n * (n - 1))
        return mean, var, used

    def render_with_error(self, seeds: list[int], spp: int) -> tuple[np.ndarray, np.ndarray]:
        """Render `spp` samples split over len(seeds) independent renders.

        Returns (mean radiance, variance of that mean) per pixel. With split sizes n_i and split
        means m_i: sigma^2 = sum n_i (m_i - m)^2 / (n - 1) estimates the per-sample variance,
        and var(m) = sigma^2 / N. With equal sizes this is sum (m_i - m)^2 / (n (n - 1)), the
        variance of the mean of n independent replicates, which also holds for a randomised
        QMC sampler (render/samplers.py). Sizes are the spp each render actually used
        (`last_used_spp`: the total).
        """
        n = len(seeds)
        if spp < n:
            raise ValueError(f"spp={spp} must be >= mc_splits={n}")
        sizes = [spp // n + (1 if i < spp % n else 0) for i in range(n)]
        means = []
        for i, (s, k) in enumerate(zip(seeds, sizes)):
            means.append(self.render_once(s, k).astype(np.float64))
            sizes[i] = self.last_spp
        spp = sum(sizes)
        self.last_used_spp = spp
        w = np.asarray(sizes, dtype=np.float64) / spp
        mean = sum(wi * m for wi, m in zip(w, means))
        sigma2 = sum(k * (m - mean) ** 2 for k, m in zip(sizes, means)) / (n - 1)
        return mean.astype(np.float32), sigma2 / spp
