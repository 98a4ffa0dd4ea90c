"""Scene files: `scenes/<name>/scene.toml` (+ Mitsuba XML) -> validated, frozen `SceneSpec`.

Every key is checked on entry: unknown keys, wrong types, out-of-range or non-finite values,
negative times, impossible timing and missing files raise `SceneError`, one line naming the
file and the dotted key. `--set section.key=value` overrides (TOML value syntax) are applied
to the raw table before validation, so they are checked the same way.

Sections (DESIGN.md "Scene keys"; units in the key names):

    [render]   xml, spp, resolution=[H, W], subframes, seed, variant, spectral_mode,
               mc_splits, roi_shape                      (accuracy: spp, subframes, mc_splits)
    [timing]   fps, frames, exposure_s, exposure_offset_s, dmd_window_s,
               dmd_window_offset_s, outside_window       (offsets from the frame start)
    [motion.<id>]   kind = "linear" | "keyframes" | "static"; attached = [ids]
    [spectra.<param>]  kind, source, intensity_cd | luminance_cd_per_m2 | illuminance_lux | scale,
                       distribution (kind = "intensity": "file:<.ies|.ldt>", bound to $<param>_distribution)
    [sheeting.<param>] source ("astm_d4956:I|II|III" or "file:<csv>"), efficiency  (materials/)
    [dmd] [relay] [sensor] [mask] [predictor] [loop] [outputs]   later stages' parameters
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping, get_args, get_origin, get_type_hints

import numpy as np

from poevp_optics.control.predictors import PREDICTORS, TAKES_WEIGHTS
from poevp_optics.analysis.tonemap import TONEMAP_METHODS
from poevp_optics.core.exceptions import UserError


class SceneError(UserError):
    """Invalid scene file or override; the message names the file and the key."""


def _f(default=dataclasses.MISSING, **meta):
    """Dataclass field with validation metadata: min, max, gt, lt, choices, length; `unset`
    (a value outside the bounds that means "from the preset") and `why` (said when a bound
    fails: what the bound protects)."""
    if isinstance(default, (list, dict)):
        raise TypeError("use tuples for defaults")
    return field(default=default, metadata=meta)


# ---------------------------------------------------------------------------- sections
@dataclass(frozen=True)
class RenderSpec:
    """[render]: Mitsuba scene and accuracy settings (spp, subframes, mc_splits)."""

    xml: str = _f("scene.xml")
    spp: int = _f(16, min=1, max=1 << 20)
    resolution: tuple[int, int] = _f((368, 640), length=2, min=1, max=16384)
    subframes: int = _f(4, min=1, max=4096)          # uniform radiance nodes in time per exposure
    pwm_nodes: bool = _f(True)                       # also sample at the DMD's switching times
    temporal_spp: int = _f(0, min=0, max=1 << 20)    # spp of the temporal-error check; 0: render.spp
    seed: int = _f(0, min=0, max=2**31 - 1)
    variant: str = _f("auto")                        # "auto" or a Mitsuba variant name
    spectral_mode: str = _f("auto", choices=("auto", "spectral", "mono"))
    mc_splits: int = _f(2, min=2, max=64)            # independent-seed renders for MC error
    roi_shape: str = _f("")                          # shape id whose image box is the ROI


@dataclass(frozen=True)
class TimingSpec:
    """[timing]: frame clock, sensor exposure and DMD display window (s, from frame start)."""

    fps: float = _f(30.0, gt=0, max=1e6)
    frames: int = _f(8, min=1, max=100000)
    exposure_s: float = _f(1 / 60, gt=0, max=100.0)
    exposure_offset_s: float = _f(0.0, min=0)
    dmd_window_s: float = _f(1 / 60, gt=0, max=100.0)
    dmd_window_offset_s: float = _f(0.0, min=0)
    outside_window: str = _f("white", choices=("white", "dark"))


@dataclass(frozen=True)
class MotionSpec:
    """[motion.<id>]: displacement (m) of a shape or emitter from its XML pose over time."""

    kind: str = _f("linear", choices=("linear", "keyframes", "static"))
    start_offset_m: tuple[float, float, float] = _f((0.0, 0.0, 0.0), length=3)
    velocity_m_per_s: tuple[float, float, float] = _f((0.0, 0.0, 0.0), length=3)
    times_s: tuple[float, ...] = _f((), min=0)
    offsets_m: tuple[tuple[float, float, float], ...] = _f((), length=3)
    attached: tuple[str, ...] = _f(())               # other XML ids moving with this one

    def offset_m(self, t_s: float) -> np.ndarray:
        """Displacement (m) at time `t_s`: linear in t, or piecewise linear between keyframes
        (held constant outside the keyframe span)."""
        if self.kind == "static":
            return np.zeros(3)
        if self.kind == "linear":
            return np.asarray(self.start_offset_m) + np.asarray(self.velocity_m_per_s) * t_s
        offs = np.asarray(self.offsets_m, dtype=float)
        return np.array([np.interp(t_s, self.times_s, offs[:, i]) for i in range(3)])

    @property
    def is_static(self) -> bool:
        if self.kind == "static":
            return True
        if self.kind == "linear":
            return not any(self.velocity_m_per_s)
        offs = np.asarray(self.offsets_m, dtype=float)
        return bool(np.all(offs == offs[0]))


@dataclass(frozen=True)
class SpectrumSpec:
    """[spectra.<param>]: a spectrum bound to the XML parameter `$<param>`.

    kind: "intensity" (W sr-1 nm-1, scaled by intensity_cd), "radiance" (W m-2 sr-1 nm-1,
    luminance_cd_per_m2), "irradiance" (W m-2 nm-1, illuminance_lux) or "reflectance"
    (unitless, times `scale`, must stay <= 1).
    """

    kind: str = _f(choices=("intensity", "radiance", "irradiance", "reflectance"))
    source: str = _f()
    intensity_cd: float = _f(math.nan, min=0)
    luminance_cd_per_m2: float = _f(math.nan, min=0)
    illuminance_lux: float = _f(math.nan, min=0)
    scale: float = _f(1.0, min=0)
    distribution: str = _f("")


@dataclass(frozen=True)
class SheetingSpec:
    """[sheeting.<param>]: retroreflective sheeting bound to `$<param>` of a `retroreflective` BSDF
    (materials/retroreflective.py): an R_A table and its efficiency bound (NaN: the preset's)."""

    source: str = _f()
    efficiency: float = _f(math.nan, gt=0, lt=1)


@dataclass(frozen=True)
class FlickerSpec:
    """[flicker.<param>]: the emitter spectrum `$<param>` is PWM-driven (flicker.py)."""

    frequency_hz: float = _f(gt=0, max=1e7)
    duty: float = _f(0.5, gt=0, max=1.0)
    phase_s: float = _f(0.0, min=0)
    off_fraction: float = _f(0.0, min=0, max=1.0)


@dataclass(frozen=True)
class RegistrationSpec:
    """[dmd.registration]: affine map mirror grid -> sensor grid."""

    scale: float = _f(1.0, gt=0, max=100.0)
    rotation_deg: float = _f(0.0, min=-180.0, max=180.0)
    offset_px: tuple[float, float] = _f((0.0, 0.0), length=2)


@dataclass(frozen=True)
class DMDSpec:
    """[dmd]: micromirror array and its PWM (TI DLP6500 + DLPC900 defaults, FACTS.md)."""

    enabled: bool = _f(True)
    bits: int = _f(8, min=1, max=16)
    bit_order: str = _f("lsb_first", choices=("lsb_first", "msb_first"))
    contrast_ratio: float = _f(1000.0, gt=1.0, why="at 1:1 an off mirror passes as much light as an on "
                               "mirror, so no mask could dim anything")
    fill_factor: float = _f(0.92, gt=0, max=1.0)
    reflectance: float = _f(0.88, gt=0, max=1.0)
    settle_s: float = _f(0.0, min=0, max=1.0)
    pitch_m: float = _f(7.56e-6, gt=0, max=1e-3)
    registration: RegistrationSpec = _f(RegistrationSpec())


@dataclass(frozen=True)
class RelaySpec:
    """[relay]: relay lens between DMD and sensor."""

    psf: str = _f("delta", choices=("delta", "gaussian", "airy", "measured"))
    f_number: float = _f(math.nan, gt=0, max=1000.0)  # relay aperture stop (image side); NaN: none
    magnification: float = _f(math.nan, gt=0, max=1000.0)  # NaN: from the registration (layout.py)
    sigma_px: float = _f(1.0, gt=0, max=1000.0)
    support_px: int = _f(0, min=0, max=4097)         # 0: chosen from the PSF's energy
    support_energy: float = _f(0.999, gt=0.5, lt=1.0)  # energy held by the automatic support
    measured_file: str = _f("")
    transmission: float = _f(0.9, gt=0, max=1.0)
    glare_fraction: float = _f(0.0, min=0, max=0.5)   # veiling glare: energy in a wide halo
    glare_sigma_px: float = _f(40.0, gt=0, max=4096.0)
    crosstalk_tolerance: float = _f(0.05, gt=0, max=10.0)  # flag 8: |blurred / own exposure - 1| above
    guard_max_px: int = _f(256, min=0, max=4096)      # widest guard band rendered for the PSF (px)


@dataclass(frozen=True)
class ObjectiveSpec:
    """[objective]: the lens that images the scene onto the DMD (layout.py)."""

    f_number: float = _f(math.nan, gt=0, max=1000.0)  # at the DMD; NaN: from sensor.f_number


@dataclass(frozen=True)
class SensorSpec:
    """[sensor]: preset plus overrides; NaN / -1 / "" mean "from the preset"."""

    preset: str = _f("IMX253", choices=("IMX253", "generic"))
    bits: int = _f(-1, min=1, max=24, unset=-1)      # DN are float32: exact integers up to 2^24
    full_well_e: float = _f(math.nan, gt=0)
    read_noise_e: float = _f(math.nan, min=0)
    gain_dn_per_e: float = _f(math.nan, gt=0)
    offset_dn: float = _f(math.nan, min=0)
    dark_current_e_per_s: float = _f(math.nan, min=0)
    prnu: float = _f(math.nan, min=0, max=1)
    dsnu_e: float = _f(math.nan, min=0)
    pixel_pitch_m: float = _f(math.nan, gt=0, max=1e-3)
    f_number: float = _f(math.nan, gt=0, max=1000.0)
    optical_throughput: float = _f(math.nan, gt=0, max=1.0)
    qe: str = _f("")
    noise: bool = _f(True)
    seed: int = _f(0, min=0, max=2**31 - 1)


@dataclass(frozen=True)
class MaskSpec:
    """[mask]: mask law and its coefficients (paper Eq. 2: vs, a, b)."""

    law: str = _f("target", choices=("threshold_exp", "threshold_ratio", "target", "white"))
    vs: float = _f(200.0, gt=0, lt=255)
    a: float = _f(0.9, min=0, max=1)
    b: float = _f(0.0, min=0, max=1)
    target: float = _f(0.5, gt=0, max=1)
    smooth_px: float = _f(4.0, min=0, max=1000)
    clipped_gain: float = _f(32.0, min=1, max=1e9)   # target law: assumed x saturation where clipped
    min_level: int = _f(0, min=0, max=65535)         # lowest DMD level a law may use (masks.py)


@dataclass(frozen=True)
class PredictorSpec:
    """[predictor]: video predictor by name."""

    name: str = _f("oracle", choices=PREDICTORS)
    weights: str = _f("")                            # relative paths: from the scene's folder
    resolution: tuple[int, int] = _f((368, 640), length=2, min=8, max=8192)


@dataclass(frozen=True)
class LoopSpec:
    """[loop]: what the predictor sees (DESIGN.md "Loop modes")."""

    mode: str = _f("open", choices=("open", "raw", "demodulated"))
    init_frames: int = _f(2, min=0, max=1000)


@dataclass(frozen=True)
class OutputsSpec:
    """[outputs]: which files a run writes."""

    radiance_exr: bool = _f(True)
    subframes_exr: bool = _f(False)
    previews: bool = _f(True)
    contact_sheet: bool = _f(True)
    tonemap: str = _f("reinhard2004", choices=tuple(TONEMAP_METHODS))


@dataclass(frozen=True)
class PlateSpec:
    """[plate]: plate text; when set, a texture is generated and bound to `$<param>`."""

    text: str = _f("")
    param: str = _f("plate_texture")
    width_px: int = _f(1040, min=64, max=8192)
    height_px: int = _f(220, min=16, max=2048)


@dataclass(frozen=True)
class ChartSpec:
    """[chart]: back-lit transmissive dynamic-range chart (charts.py); absent: not a chart.

    Patch i has density D_i (equal steps from d_min to d_max, or the explicit `densities`) and
    is bound to the XML parameter `$<param_prefix>NN`: its radiance is the light box's
    (`source`, `luminance_cd_per_m2`) times 10^-D_i (a neutral film over a Lambertian box).
    """

    patches: int = _f(0, min=0, max=1000)
    d_min: float = _f(0.0, min=0, max=20)
    d_max: float = _f(8.0, min=0, max=20)
    densities: tuple[float, ...] = _f((), min=0, max=20)
    source: str = _f("cie:LED-B5")
    luminance_cd_per_m2: float = _f(1.0e5, gt=0)
    param_prefix: str = _f("patch_")
    repeats: int = _f(16, min=2, max=4096)            # captures for the temporal noise
    roi_inset_px: int = _f(4, min=1, max=1000)        # patch border left out (edges, PSF)
    mask_source: str = _f("loop", choices=("loop", "oracle"))
    max_iterations: int = _f(12, min=1, max=1000)     # loop frames allowed to settle the mask
    reference_camera: str = _f("")                    # scene whose camera sections are also run

    def density_list(self) -> tuple[float, ...]:
        if self.densities:
            return self.densities
        return tuple(float(d) for d in np.linspace(self.d_min, self.d_max, self.patches))

    def param(self, i: int) -> str:
        return f"{self.param_prefix}{i:02d}"


@dataclass(frozen=True)
class Accuracy:
    """Numerical accuracy settings, kept apart from physics (STYLE.md 5)."""

    spp: int
    subframes: int
    mc_splits: int


@dataclass(frozen=True)
class SceneSpec:
    """A validated scene: paths resolved, every section frozen."""

    name: str
    toml_path: Path
    xml_path: Path
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
    outputs: OutputsSpec
    plate: PlateSpec
    chart: ChartSpec
    raw: Mapping[str, Any]
    origin: str = ""               # the file and the --set overrides it was read with (messages)

    @property
    def accuracy(self) -> Accuracy:
        return Accuracy(self.render.spp, self.render.subframes, self.render.mc_splits)

    @property
    def geometry_static(self) -> bool:
        """True when no shape or emitter moves."""
        return all(m.is_static for m in self.motion.values())

    @property
    def is_static(self) -> bool:
        """True when nothing changes in time (no motion, no flicker): rendered once, K = 1."""
        return self.geometry_static and not self.flicker

    def frame_start_s(self, index: int) -> float:
        return index / self.timing.fps

    def exposure_window_s(self, index: int) -> tuple[float, float]:
        t0 = self.frame_start_s(index) + self.timing.exposure_offset_s
        return t0, t0 + self.timing.exposure_s

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
    "relay": RelaySpec,
    "sensor": SensorSpec, "mask": MaskSpec, "predictor": PredictorSpec, "loop": LoopSpec,
    "outputs": OutputsSpec, "plate": PlateSpec, "chart": ChartSpec,
}
TABLE_SECTIONS = {"motion": MotionSpec, "spectra": SpectrumSpec, "flicker": FlickerSpec,
                  "sheeting": SheetingSpec}
TOP_KEYS = {"description"}


# ---------------------------------------------------------------------------- checking
class _Ctx:
    def __init__(self, file: Path | str):
        self.file = file

    def fail(self, key: str, msg: str) -> SceneError:
        return SceneError(f"{self.file}: {key}: {msg}")


def _check_number(ctx, key, value, meta, want_int):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ctx.fail(key, f"expected {'an integer' if want_int else 'a number'}, got {value!r}")
    if want_int and not isinstance(value, int):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise ctx.fail(key, f"expected an integer, got {value!r}")
    if not math.isfinite(value):
        raise ctx.fail(key, f"must be finite, got {value!r}")
    if "unset" in meta and value == meta["unset"]:
        return int(value) if want_int else float(value)
    lo, hi = meta.get("min"), meta.get("max")
    hint = (f" (or {meta['unset']}: the preset's value)" if "unset" in meta else "") + \
        (f": {meta['why']}" if "why" in meta else "")
    if "gt" in meta and not value > meta["gt"]:
        raise ctx.fail(key, f"must be > {meta['gt']}{hint}, got {value!r}")
    if "lt" in meta and not value < meta["lt"]:
        raise ctx.fail(key, f"must be < {meta['lt']}{hint}, got {value!r}")
    if lo is not None and value < lo:
        what = "negative times are not allowed" if key.endswith("_s") and lo == 0 else f"must be >= {lo}"
        raise ctx.fail(key, f"{what}{hint}, got {value!r}")
    if hi is not None and value > hi:
        raise ctx.fail(key, f"must be <= {hi}{hint}, got {value!r}")
    return int(value) if want_int else float(value)


def _check_value(ctx, key, value, tp, meta):
    origin = get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ctx.fail(key, f"expected a table, got {value!r}")
        return _build(ctx, key, tp, value)
    if origin is tuple:
        args = get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ctx.fail(key, f"expected an array, got {value!r}")
        inner = args[0]
        if len(args) == 2 and args[1] is Ellipsis:
            inner_meta = dict(meta)
            if get_origin(inner) is tuple:
                return tuple(_check_value(ctx, f"{key}[{i}]", v, inner, inner_meta)
                             for i, v in enumerate(value))
            inner_meta.pop("length", None)
            return tuple(_check_value(ctx, f"{key}[{i}]", v, inner, inner_meta)
                         for i, v in enumerate(value))
        if len(value) != len(args):
            raise ctx.fail(key, f"expected {len(args)} values, got {len(value)}")
        inner_meta = {k: v for k, v in meta.items() if k != "length"}
        return tuple(_check_value(ctx, f"{key}[{i}]", v, a, inner_meta)
                     for i, (v, a) in enumerate(zip(value, args)))
    if tp is bool:
        if not isinstance(value, bool):
            raise ctx.fail(key, f"expected true or false, got {value!r}")
        return value
    if tp is int or tp is float:
        return _check_number(ctx, key, value, meta, tp is int)
    if tp is str:
        if not isinstance(value, str):
            raise ctx.fail(key, f"expected a string, got {value!r}")
        if "choices" in meta and value not in meta["choices"]:
            raise ctx.fail(key, f"must be one of {', '.join(map(repr, meta['choices']))}, got {value!r}")
        return value
    raise TypeError(f"unsupported field type {tp}")  # programming error


def _build(ctx, prefix, cls, table: dict):
    hints = get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for k in table:
        if k not in fields:
            raise ctx.fail(f"{prefix}.{k}", f"unknown key (known: {', '.join(fields)})")
    kwargs = {}
    for name, f in fields.items():
        key = f"{prefix}.{name}"
        if name in table:
            kwargs[name] = _check_value(ctx, key, table[name], hints[name], f.metadata)
        elif f.default is dataclasses.MISSING:
            raise ctx.fail(key, "required key is missing")
    return cls(**kwargs)


def parse_override(text: str) -> tuple[list[str], Any]:
    """'section.key=value' -> (['section', 'key'], value). Values use TOML syntax; a value
    that is not valid TOML is taken as a bare string (so `--set predictor.name=flow` works)."""
    if "=" not in text:
        raise SceneError(f"--set {text}: expected section.key=value")
    key, value = text.split("=", 1)
    path = [p.strip() for p in key.strip().split(".")]
    if len(path) < 2 or not all(path):
        raise SceneError(f"--set {text}: key must be dotted, like render.spp")
    try:
        parsed = tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value.strip()
    return path, parsed


def apply_overrides(raw: dict, overrides: list[str]) -> dict:
    """Return a deep copy of `raw` with dotted overrides set (validation happens later)."""
    import copy

    out = copy.deepcopy(raw)
    for text in overrides:
        path, value = parse_override(text)
        node = out
        for p in path[:-1]:
            nxt = node.setdefault(p, {})
            if not isinstance(nxt, dict):
                raise SceneError(f"--set {text}: {p} is not a table")
            node = nxt
        node[path[-1]] = value
    return out


def scene_name(toml_path: Path) -> str:
    """A scene's name: its folder's name, never empty (`poevp render .` inside the folder
    names it like `poevp render scenes/x`); outputs default to out/<name>."""
    p = Path(toml_path).resolve()
    return p.parent.name or p.stem


def resolve_scene_path(scene: str | Path) -> Path:
    """A scene is a folder holding scene.toml, or the .toml file itself."""
    p = Path(scene)
    if p.is_dir():
        p = p / "scene.toml"
    if not p.is_file():
        raise SceneError(f"{p}: scene file not found")
    return p


ACCURACY_PRESETS = ("fast", "default", "reference")


def accuracy_overrides(scene: str | Path, overrides: list[str], preset: str) -> list[str]:
    """`--accuracy`: spp, sub-frames and PSF support chosen together (fast: 1/4 spp, K/2, 99 %
    PSF energy; reference: 4x spp, 4x K, 99.999 %; default: the scene's own values)."""
    if preset not in ACCURACY_PRESETS:
        raise SceneError(f"--accuracy {preset}: must be one of {', '.join(ACCURACY_PRESETS)}")
    if preset == "default":
        return []
    spec = load_scene(scene, overrides, cross_checks=False)
    r = spec.render
    if preset == "fast":
        return [f"render.spp={max(r.mc_splits, r.spp // 4)}", f"render.subframes={max(1, r.subframes // 2)}",
                "relay.support_energy=0.99"]
    return [f"render.spp={r.spp * 4}", f"render.subframes={r.subframes * 4}", "relay.support_energy=0.99999"]


def load_scene(scene: str | Path, overrides: list[str] | None = None, *,
               cross_checks: bool = True) -> SceneSpec:
    """Read, override and validate a scene file. Raises `SceneError` (file + key) on bad input.

    cross_checks=False leaves out the checks that combine keys (timing fits in the frame
    period), so a sweep can tell a bad key or value (stop) from an impossible point (record)."""
    path = resolve_scene_path(scene)
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{path}: malformed TOML: {e}") from None
    except UnicodeDecodeError:
        raise SceneError(f"{path}: not a UTF-8 text file") from None
    overrides = list(overrides or [])
    ctx = _Ctx(path)
    try:
        raw = apply_overrides(raw, overrides)
    except SceneError as e:
        raise SceneError(f"{path}: {e}") from None
    if overrides:
        ctx = _Ctx(f"{path} (with --set {' '.join(overrides)})")
    return build_spec(raw, path, ctx, cross_checks=cross_checks)


def build_spec(raw: dict, path: Path, ctx: _Ctx | None = None, *, cross_checks: bool = True) -> SceneSpec:
    ctx = ctx or _Ctx(path)
    for k, v in raw.items():
        if k in SECTIONS or k in TABLE_SECTIONS:
            if not isinstance(v, dict):
                raise ctx.fail(k, "expected a table")
        elif k not in TOP_KEYS:
            raise ctx.fail(k, f"unknown section (known: {', '.join([*SECTIONS, *TABLE_SECTIONS])})")
    description = raw.get("description", "")
    if not isinstance(description, str):
        raise ctx.fail("description", "expected a string")
    sec = {name: _build(ctx, name, cls, raw.get(name, {})) for name, cls in SECTIONS.items()}
    tables = {}
    for name, cls in TABLE_SECTIONS.items():
        entries = {}
        for ident, table in raw.get(name, {}).items():
            if not isinstance(table, dict):
                raise ctx.fail(f"{name}.{ident}", "expected a table")
            entries[ident] = _build(ctx, f"{name}.{ident}", cls, table)
        tables[name] = MappingProxyType(entries)

    render: RenderSpec = sec["render"]
    xml_path = (path.parent / render.xml).resolve()
    if not xml_path.is_file():
        raise ctx.fail("render.xml", f"Mitsuba scene file not found: {xml_path}")
    sec["predictor"] = _check_predictor(ctx, path, sec["predictor"], cross_checks)
    _check_plate(ctx, sec["plate"])
    if cross_checks:
        _check_timing(ctx, sec["timing"])
        _check_accuracy(ctx, render)
        if sec["dmd"].enabled:
            _check_dmd_use(ctx, sec["dmd"], sec["timing"], sec["mask"])
        _check_sensor_levels(ctx, sec["sensor"])
    for ident, m in tables["motion"].items():
        _check_motion(ctx, f"motion.{ident}", m)
    for ident, s in tables["spectra"].items():
        _check_spectrum(ctx, f"spectra.{ident}", s)
    _check_plugin_tables(ctx, path, tables["spectra"], tables["sheeting"])
    _check_sensor_and_relay(ctx, path, sec["sensor"], sec["relay"])
    _check_layout(ctx, sec)
    for ident in tables["flicker"]:
        entry = tables["spectra"].get(ident)
        if entry is None or entry.kind == "reflectance":
            raise ctx.fail(f"flicker.{ident}", "must name an emissive [spectra] entry (a lamp)")
    if tables["flicker"] and not all(m.is_static for m in tables["motion"].values()):
        raise ctx.fail("flicker", "flickering lamps need static geometry (no moving [motion] entry)")
    spectra_ = tables["spectra"]
    if sec["chart"].patches:
        spectra_ = MappingProxyType({**spectra_, **_chart_spectra(ctx, path, sec["chart"], spectra_)})
    return SceneSpec(name=scene_name(path), toml_path=path, xml_path=xml_path,
                     description=description, motion=tables["motion"], spectra=spectra_,
                     flicker=tables["flicker"], sheeting=tables["sheeting"],
                     raw=MappingProxyType(raw), origin=str(ctx.file), **sec)


def _chart_spectra(ctx, path: Path, chart: ChartSpec, given) -> dict:
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
        _check_spectrum(ctx, "chart.source", entry)
        out[name] = entry
    return out


def _check_timing(ctx, t: TimingSpec):
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


def _check_accuracy(ctx, r: RenderSpec):
    if r.spp < r.mc_splits:
        raise ctx.fail("render.spp", f"must be >= render.mc_splits = {r.mc_splits} (the Monte Carlo "
                       f"error comes from {r.mc_splits} independent-seed renders, each needs a "
                       f"sample), got {r.spp}")


def _check_dmd_use(ctx, dmd: DMDSpec, t: TimingSpec, mask: MaskSpec):
    """A DMD that can act on the capture: its window overlaps the exposure, and the mask law
    has levels below white to use."""
    e0, e1 = t.exposure_offset_s, t.exposure_offset_s + t.exposure_s
    d0, d1 = t.dmd_window_offset_s, t.dmd_window_offset_s + t.dmd_window_s
    if min(e1, d1) - max(e0, d0) <= 0:
        raise ctx.fail("timing.dmd_window_offset_s",
                       f"the DMD window [{d0:.6g}, {d1:.6g}] s misses the exposure [{e0:.6g}, "
                       f"{e1:.6g}] s (from the frame start): no mask could act on the capture")
    top = (1 << dmd.bits) - 1
    if mask.law != "white" and mask.min_level >= top:
        raise ctx.fail("mask.min_level", f"must be < {top}, the white level of a {dmd.bits}-bit DMD "
                       f"(dmd.bits), so the mask law has a level that dims; got {mask.min_level}")


def _check_sensor_levels(ctx, sensor: SensorSpec):
    """The preset with the scene's overrides leaves codes between black level and top code."""
    from poevp_optics.camera.sensor import PRESETS

    bits = sensor.bits if sensor.bits != -1 else PRESETS[sensor.preset].bits
    top = (1 << bits) - 1
    if not math.isnan(sensor.offset_dn) and sensor.offset_dn >= top:
        raise ctx.fail("sensor.offset_dn", f"must be below the top code {top} of the {bits}-bit ADC "
                       f"(sensor.bits), or no signal could be read; got {sensor.offset_dn:g}")


def _check_plate(ctx, plate: PlateSpec):
    if plate.text and not plate.text.strip():
        raise ctx.fail("plate.text", f"blank text {plate.text!r}: give the plate's characters, "
                       "or leave it out ('') for the XML's own texture")


def _check_predictor(ctx, path: Path, pred: PredictorSpec, cross_checks: bool) -> PredictorSpec:
    """Resolve `weights` against the scene's folder (as render.xml is) and check it is used."""
    if not pred.weights:
        return pred
    if cross_checks and pred.name not in TAKES_WEIGHTS:
        raise ctx.fail("predictor.weights", f"predictor {pred.name!r} takes no weights (only "
                       f"{', '.join(TAKES_WEIGHTS)} do); remove the key or change predictor.name")
    w = Path(pred.weights).expanduser()
    w = w if w.is_absolute() else (path.parent / w)
    w = w.resolve()
    if not w.is_file():
        raise ctx.fail("predictor.weights", f"weights file not found: {w}"
                       + (" (relative paths are read from the scene's folder)" if not Path(pred.weights).is_absolute() else ""))
    return dataclasses.replace(pred, weights=str(w))


def _check_motion(ctx, key, m: MotionSpec):
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


def _check_spectrum(ctx, key, s: SpectrumSpec):
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


def resolve_layout(spec) -> "OpticalLayout":
    """The optical layout (layout.py) of a scene's (or a section mapping's) optics keys."""
    from poevp_optics.camera.layout import optical_layout
    from poevp_optics.camera.sensor import PRESETS

    get = (lambda k: spec[k]) if isinstance(spec, dict) else (lambda k: getattr(spec, k))
    sensor, dmd = get("sensor"), get("dmd")
    preset = PRESETS[sensor.preset]
    pitch = sensor.pixel_pitch_m if not math.isnan(sensor.pixel_pitch_m) else preset.pixel_pitch_m
    return optical_layout(objective_f_number=get("objective").f_number, sensor_f_number=sensor.f_number,
                          preset_f_number=preset.f_number, relay_f_number=get("relay").f_number,
                          relay_magnification=get("relay").magnification, dmd_enabled=dmd.enabled,
                          registration_scale=dmd.registration.scale, sensor_pitch_m=pitch,
                          mirror_pitch_m=dmd.pitch_m)


def _check_layout(ctx, sec: dict):
    from poevp_optics.camera.layout import LayoutError

    try:
        resolve_layout(sec)
    except LayoutError as e:
        raise ctx.fail(e.key, str(e)) from None


def _check_plugin_tables(ctx, path: Path, spectra_, sheeting):
    """Photometric files of [spectra] lamps and [sheeting] tables (materials/): readable, in range."""
    from poevp_optics.render.materials.photometric_lamp import LampFileError, resolve_distribution
    from poevp_optics.render.materials.retroreflective import SheetingError, parse_sheeting, retro_law

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


def sheeting_string(sh: SheetingSpec, base_dir: Path) -> str:
    """The `sheeting` property string a [sheeting.<param>] entry binds (file paths made absolute)."""
    source = sh.source
    if source.startswith("file:") and not Path(source[5:]).is_absolute() and (base_dir / source[5:]).is_file():
        source = f"file:{(base_dir / source[5:]).resolve()}"
    return source if math.isnan(sh.efficiency) else f"{source};efficiency={sh.efficiency:.9g}"


def _check_sensor_and_relay(ctx, path: Path, sensor: SensorSpec, relay: RelaySpec):
    from poevp_optics.sources.spectra import SpectrumError, load_spectrum

    if sensor.qe:
        try:
            load_spectrum(sensor.qe, emissive=True)
        except SpectrumError as e:
            raise ctx.fail("sensor.qe", str(e)) from None
    if relay.psf == "measured":
        if not relay.measured_file:
            raise ctx.fail("relay.measured_file", "required when psf = 'measured'")
        from poevp_optics.sources.spectra import ASSETS_DIR

        p = Path(relay.measured_file)
        cand = [p] if p.is_absolute() else [path.parent / p, ASSETS_DIR / p]
        if not any(c.is_file() for c in cand):
            raise ctx.fail("relay.measured_file", f"PSF image not found: {relay.measured_file}")
