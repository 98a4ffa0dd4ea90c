"""Everything a run checks before it starts, short of rendering; `poevp validate` runs the same.

`load_scene` checks each key and the combinations of keys (scene.py). A run also depends on
things outside the TOML, checked here in one pass before any output folder is touched:

| check            | what                                                              |
|------------------|-------------------------------------------------------------------|
| memory           | the run's estimate fits in the available memory (memory.py)       |
| spectra          | [spectra] entries bind the XML's parameters; lamps switched off are legal |
| XML references   | motion ids (and `attached`), `render.roi_shape` name shapes or emitters of the XML; every file the XML names exists |
| emitters         | no emitter so bright that the render would overflow float32       |
| variant          | `render.variant` is a Mitsuba mono or spectral variant that can render the scene |
| relay            | `relay.measured_file` is an odd-sized square image with energy    |
| loop             | `compare` and `chart` get loop frames: `loop.init_frames` below the frames they run on (a render may be all initialisation frames) |
| predictor        | weights load and are finite; `predictor.resolution` is large enough for the network |
| chart            | `poevp chart` on a static scene with a [chart] section            |
| source           | a frame source ([source] kind other than mitsuba; replaces the spectra, XML, emitter and variant checks): every frame the run reads has one size, finite values >= 0 (EXR) and the channel; times and boxes CSVs parse; the frames cover every radiance sample's time; the field has render.resolution's aspect |

Each failure is a `SceneError` (a frame source's: `sources.frames.SourceError`): one line naming
the file and the key.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from poevp_optics.apps.run.memory import MemoryEstimate, check_memory
from poevp_optics.core.exceptions import SceneError
from poevp_optics.scene.spec import SceneSpec
#: Largest sensor-weighted photon quantity an emitter may have (e- s-1 sr-1, e- s-1 m-2 sr-1 or
#: e- s-1 m-2, per unit of its photometric key). The sun's disk is ~1e25 e- s-1 m-2 sr-1 here;
#: float32 ends at 3.4e38, and the film adds up spp samples and 1/d^2 factors on top.
MAX_EMITTER_PHOTONS = 1e30

JOBS = ("render", "compare", "chart", "train_sequence")   # train_sequence: apps/train/train_data.py


@dataclass(frozen=True)
class Preflight:
    """What the checks found out: the spectral plan and the memory estimate."""

    plan: object
    memory: MemoryEstimate | None


def check_run(spec: SceneSpec, job: str = "render", *, workers: int = 1, memory: bool = True,
              predictors: tuple[str, ...] | None = None, load: bool = False) -> Preflight:
    """Run every check of the module docstring for `job`; raise SceneError on the first failure.

    predictors: for `compare`, every predictor it will run (default: the scene's).
    load: also load the XML in Mitsuba (`validate --load`)."""
    from poevp_optics.render.renderer import plan_spectra

    if job not in JOBS:
        raise ValueError(f"unknown job {job!r}")
    if job == "chart":
        check_chart(spec)
    check_relay(spec)                # the memory estimate reads the PSF file's size
    est = check_memory(spec, job, workers=workers) if memory else None
    if spec.source.renders:
        plan = plan_spectra(spec.resolved.render)
        check_xml_references(spec, plan.xml_params)
        check_emitters(spec, plan.response_e_per_J)
        check_variant(spec, plan)
    else:
        plan = check_frame_source(spec)
    check_loop(spec, job)
    for name in (predictors or (spec.predictor.name,)):
        check_predictor(spec, job, name)
    if load and spec.source.renders:
        from poevp_optics.render.renderer import Renderer

        Renderer(spec.resolved.render)
    return Preflight(plan, est)


def check_frame_source(spec: SceneSpec):
    """A frame source opens on the camera's mirror grid and every frame its run reads is valid
    (sources/kinds.py check_source); returns its plan (mode, reason, notes)."""
    from poevp_optics.camera.camera import Camera
    from poevp_optics.render.radiance import check_frame_source as check

    return check(spec.resolved.render, Camera.from_params(spec.resolved.camera).guard_px)


def _fail(spec: SceneSpec, key: str, msg: str) -> SceneError:
    return SceneError(f"{spec.origin or spec.toml_path}: {key}: {msg}")


# ---------------------------------------------------------------------------- XML
#: Deepest chain of <include> files followed (Mitsuba has no limit; a loop would not end).
MAX_INCLUDE_DEPTH = 16
#: Leading bytes of the image formats Mitsuba's bitmap texture reads (Bitmap::detect_file_format).
_IMAGE_MAGIC = (b"\x89PNG", b"\xff\xd8", b"\x76\x2f\x31\x01", b"#?", b"PF", b"Pf", b"P6", b"P5", b"BM")


def _parse_xml(path: Path, via: str = ""):
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as e:
        raise SceneError(f"{path}: malformed XML{via}: {e}") from None
    except (OSError, RecursionError) as e:
        raise SceneError(f"{path}: cannot read the XML{via}: {getattr(e, 'strerror', None) or e}") from None


def _xml_root(spec: SceneSpec):
    """The scene's XML with every <include> replaced by the included file's elements (paths
    relative to the including file, as Mitsuba resolves them); a missing or looping include is
    a SceneError naming the file that includes it."""
    def expand(root, path: Path, chain: tuple):
        for parent in list(root.iter()):
            for i, child in enumerate(list(parent)):
                if child.tag != "include":
                    continue
                name = child.get("filename") or ""
                inc = (path.parent / name).resolve()
                if not name or not inc.is_file():
                    raise SceneError(f"{path}: <include filename={name!r}>: file not found: {inc}")
                if inc in chain or len(chain) >= MAX_INCLUDE_DEPTH:
                    raise SceneError(f"{path}: <include filename={name!r}>: includes itself or nests deeper "
                                     f"than {MAX_INCLUDE_DEPTH} files")
                sub = expand(_parse_xml(inc, f" (included by {path.name})"), inc, chain + (inc,))
                parent.remove(child)
                for j, el in enumerate(list(sub)):
                    parent.insert(i + j, el)
        return root

    return expand(_parse_xml(spec.xml_path), spec.xml_path, (spec.xml_path.resolve(),))


def _check_parameters_used(spec: SceneSpec, root, xml_params: dict[str, str]) -> None:
    """Every parameter the TOML binds is written `$name` somewhere in the XML (Mitsuba refuses
    a scene given parameters it does not use: 'Found unused parameters')."""
    import re

    used = set()
    for el in root.iter():
        if el.tag == "default":
            continue
        for v in el.attrib.values():
            used.update(re.findall(r"\$([A-Za-z_][A-Za-z0-9_]*)", v))
    for name in sorted(set(xml_params) - used):
        key = (f"spectra.{name}" if name in spec.spectra else
               "plate.text" if name == spec.plate.param else name)
        raise SceneError(f"{spec.xml_path}: no element uses the parameter ${name} (its <default> or the "
                         f"binding alone does not), but {spec.toml_path}: {key} binds it; write "
                         f'value="${name}" where it belongs in the XML, or remove {key}')


def _check_image(spec: SceneSpec, path: Path, what: str) -> None:
    """A bitmap texture's file starts like an image Mitsuba reads (PNG, JPEG, OpenEXR, RGBE,
    PFM, PPM/PGM, BMP; TGA has no signature and is taken by its suffix)."""
    if path.suffix.lower() == ".tga":
        return
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError as e:
        raise SceneError(f"{spec.xml_path}: {what}: texture file {path}: {e.strerror or e}") from None
    if not head.startswith(_IMAGE_MAGIC):
        raise SceneError(f"{spec.xml_path}: {what}: texture file {path} is not an image Mitsuba reads "
                         "(PNG, JPEG, OpenEXR, HDR, PFM, PPM, BMP, TGA)")


def check_xml_references(spec: SceneSpec, xml_params: dict[str, str]) -> None:
    """Moving ids and the ROI shape exist in the XML; every file it names exists (after
    binding `$parameters`), relative to the XML's folder or assets/ as Mitsuba resolves them."""
    from poevp_optics.sources.spectra import ASSETS_DIR

    root = _xml_root(spec)
    shapes = {e.get("id") for e in root.iter("shape") if e.get("id")}
    movable = shapes | {e.get("id") for e in root.iter("emitter") if e.get("id")}
    for ident, motion in spec.motion.items():
        for key, target in [(f"motion.{ident}", ident)] + [(f"motion.{ident}.attached", a) for a in motion.attached]:
            if target not in movable:
                raise _fail(spec, key, f"no shape or emitter with id {target!r} in {spec.xml_path.name} "
                            f"(ids there: {', '.join(sorted(movable)) or 'none'})")
    if spec.render.roi_shape == "plates":      # every vehicle plate (render/roi.py): one line when none
        from poevp_optics.render.roi import roi_targets

        roi_targets(spec)
    elif spec.render.roi_shape and spec.render.roi_shape not in shapes:
        raise _fail(spec, "render.roi_shape", f"no shape with id {spec.render.roi_shape!r} in "
                    f"{spec.xml_path.name} (shape ids there: {', '.join(sorted(shapes)) or 'none'})")
    defaults = {d.get("name"): d.get("value") for d in root.iter("default")}
    for parent in root.iter():
        for child in parent:
            if child.tag != "string" or child.get("name") != "filename":
                continue
            value = child.get("value") or ""
            via = ""
            if value.startswith("$"):
                param = value[1:]
                via = f" (${param})"
                value = xml_params.get(param, defaults.get(param, ""))
            p = Path(value)
            cands = [p] if p.is_absolute() else [spec.xml_path.parent / p, ASSETS_DIR / p]
            what = f"<{parent.tag} type={parent.get('type')!r}" + (f" id={parent.get('id')!r}" if parent.get("id") else "") + ">"
            found = [c for c in cands if c.is_file()] if value else []
            if not found:
                raise SceneError(f"{spec.xml_path}: {what} filename{via}: file not found: {value!r} "
                                 f"(looked in {spec.xml_path.parent} and {ASSETS_DIR})")
            if parent.tag == "texture" and parent.get("type") == "bitmap":
                _check_image(spec, found[0], f"{what} filename{via}")
    _check_parameters_used(spec, root, xml_params)


# ---------------------------------------------------------------------------- emitters, variant
_PHOTOMETRIC = {"intensity": "intensity_cd", "radiance": "luminance_cd_per_m2", "irradiance": "illuminance_lux"}


def check_emitters(spec: SceneSpec, response_e_per_J: np.ndarray) -> None:
    """No emitter beyond MAX_EMITTER_PHOTONS: its render would overflow float32 to Inf/NaN."""
    from poevp_optics.sources import spectra
    from poevp_optics.render.renderer import absolute_spectrum

    for name, entry in spec.spectra.items():
        if entry.kind not in _PHOTOMETRIC:
            continue
        q = spectra.integrate(response_e_per_J * absolute_spectrum(entry))
        if not math.isfinite(q) or q > MAX_EMITTER_PHOTONS:
            key = _PHOTOMETRIC[entry.kind]
            raise _fail(spec, f"spectra.{name}.{key}",
                        f"{getattr(entry, key):g} gives {q:.3g} photo-electrons per second at the "
                        f"sensor's response, beyond what a float32 render holds (limit "
                        f"{MAX_EMITTER_PHOTONS:g}; the sun's disk is ~1e25): check the value and its unit")


def check_variant(spec: SceneSpec, plan) -> None:
    """A requested `render.variant` exists here and renders the sensor's response: a mono or
    spectral variant (an RGB one would render colour), spectral when the scene needs it."""
    v = spec.render.variant
    if v == "auto":
        return
    import mitsuba as mi

    have = mi.variants()
    if v not in have:
        raise _fail(spec, "render.variant", f"{v!r} is not a Mitsuba variant on this machine "
                    f"(have {', '.join(have)}; or 'auto')")
    if "_mono" not in v and "_spectral" not in v:
        raise _fail(spec, "render.variant", f"{v!r} renders RGB, not the sensor's response: "
                    "choose a *_mono or *_spectral variant, or 'auto'")
    if plan.mode == "spectral" and "_mono" in v:
        raise _fail(spec, "render.variant", f"{v!r} is a mono variant, but this scene needs the "
                    f"spectral path ({plan.reason})")


# ---------------------------------------------------------------------------- camera, loop
def check_relay(spec: SceneSpec) -> None:
    from poevp_optics.camera.relay import PSFFileError, measured_psf_path, read_psf_image

    if spec.relay.psf != "measured":
        return
    try:
        read_psf_image(measured_psf_path(spec.relay.measured_file, spec.toml_path.parent))
    except PSFFileError as e:
        raise _fail(spec, "relay.measured_file", str(e)) from None


def _runs_predictor(spec: SceneSpec, job: str, name: str) -> bool:
    if not spec.dmd.enabled or job == "train_sequence":     # LDR captures: no loop, no predictor
        return False
    if job == "chart":
        return spec.chart.mask_source == "loop"
    return name != "oracle"


def check_loop(spec: SceneSpec, job: str) -> None:
    """A causal predictor gets frames after its all-white initialisation frames (paper Sec. 3).
    A render whose frames are all initialisation frames is legal (a single still frame to check a
    lens, or a quick look at the LDR camera): every mask is white, no predictor runs, and the
    report says so. `compare` (predictors side by side) and `chart` (a settled mask) need frames
    after them."""
    init = spec.loop.init_frames
    if job == "chart":
        if _runs_predictor(spec, job, spec.predictor.name) and init >= spec.chart.max_iterations:
            raise _fail(spec, "loop.init_frames", f"{init} initialisation frames leave none of the "
                        f"{spec.chart.max_iterations} loop frames (chart.max_iterations) to the predictor")
        return
    if job == "compare" and spec.dmd.enabled and init >= spec.timing.frames:
        raise _fail(spec, "loop.init_frames", f"{init} all-white initialisation frames leave none of "
                    f"the {spec.timing.frames} frames (timing.frames) to the predictors compared: every "
                    "mask would be white (lower loop.init_frames or add frames)")


def check_predictor(spec: SceneSpec, job: str, name: str) -> None:
    """The predictor builds (weights load and are finite) and takes frames of
    `predictor.resolution`."""
    if not _runs_predictor(spec, job, name):
        return
    from poevp_optics.control.predictors import make_predictor
    from poevp_optics.core.weights import WeightsError

    try:
        pred = make_predictor(name, spec.predictor.weights, spec.predictor.resolution)
    except WeightsError as e:
        raise _fail(spec, "predictor.weights", str(e)) from None
    h, w = spec.predictor.resolution
    if min(h, w) < pred.min_input_px:
        raise _fail(spec, "predictor.resolution", f"{h}x{w} is too small for {name!r}, which needs "
                    f"frames of at least {pred.min_input_px} px a side")


def check_chart(spec: SceneSpec) -> None:
    if not spec.chart.patches:
        raise _fail(spec, "chart.patches", "not a chart scene (no [chart] section with patches)")
    if not spec.is_static:
        raise _fail(spec, "motion", "a dynamic-range chart must be static")
    if spec.dmd.enabled and spec.chart.mask_source == "loop" and spec.predictor.name == "oracle":
        raise _fail(spec, "predictor.name", "chart.mask_source = 'loop' runs a predictor on the chart: "
                    "give one other than 'oracle' (e.g. 'hold'), or set chart.mask_source = 'oracle'")
