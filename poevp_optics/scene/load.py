"""Scene files: `scenes/<name>/scene.toml` (+ Mitsuba XML, or the frames of a [source] kind)
-> validated, frozen `SceneSpec`.

Every key is checked on entry by its section's params class (core/params.py): unknown keys,
wrong types, out-of-range or non-finite values; then the checks that combine keys
(validate.py). `--set section.key=value` overrides (TOML value syntax) are applied to the raw
table before validation, so they are checked the same way. A failure is a `SceneError`, one
line naming the file (with its overrides) and the dotted key.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from types import MappingProxyType
from typing import Any

from poevp_optics.core.exceptions import SceneError
from poevp_optics.core.params import Where, parse_params
from poevp_optics.scene import validate
from poevp_optics.scene.defaults import apply_best_loop
from poevp_optics.scene.spec import SECTIONS, TABLE_SECTIONS, TOP_KEYS, SceneSpec


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
    except RecursionError:
        raise SceneError(f"--set {key.strip()}: the value nests brackets too deeply to read; flatten it") from None
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
#: MC error targets (ROI, or frame) of the presets: fast renders toward FAST_TARGET but never
#: past the scene's own spp; reference renders to REFERENCE_TARGET, up to 64x the scene's spp.
FAST_TARGET, REFERENCE_TARGET = 0.05, 0.005


def accuracy_overrides(scene: str | Path, overrides: list[str], preset: str) -> list[str]:
    """`--accuracy`: spp, MC error target, sub-frames and PSF support chosen together (fast:
    1/4 spp first, then to a 5 % error target within the scene's spp, K/2, 99 % PSF energy;
    reference: to a 0.5 % target within 64x spp, 4x K, 99.999 %; default: the scene's own
    values). A scene's own tighter target is kept."""
    if preset not in ACCURACY_PRESETS:
        raise SceneError(f"--accuracy {preset}: must be one of {', '.join(ACCURACY_PRESETS)}")
    if preset == "default":
        return []
    spec = load_scene(scene, overrides, cross_checks=False)
    r = spec.render
    own = r.target_rel_error if r.target_rel_error > 0 else 1.0
    if preset == "fast":
        return [f"render.spp={max(r.mc_splits, r.spp // 4)}", f"render.subframes={max(1, r.subframes // 2)}",
                f"render.target_rel_error={min(own, FAST_TARGET)}", f"render.max_spp={max(r.spp, r.mc_splits)}",
                "relay.support_energy=0.99"]
    return [f"render.spp={r.spp * 4}", f"render.subframes={r.subframes * 4}",
            f"render.target_rel_error={min(own, REFERENCE_TARGET)}",
            f"render.max_spp={max(r.max_spp, r.spp * 64)}", "relay.support_energy=0.99999"]


def load_scene(scene: str | Path, overrides: list[str] | None = None, *,
               cross_checks: bool = True) -> SceneSpec:
    """Read, override and validate a scene file. Raises `SceneError` (file + key) on bad input.

    cross_checks=False leaves out the checks that combine keys (timing fits in the frame
    period), so a sweep can tell a bad key or value (stop) from an impossible point (record)."""
    path = resolve_scene_path(scene)
    try:
        return _load(path, overrides, cross_checks)
    except RecursionError:
        raise SceneError(f"{path}: a value nests arrays or tables too deeply to read (thousands of "
                         "brackets); flatten it") from None


def _load(path: Path, overrides: list[str] | None, cross_checks: bool) -> SceneSpec:
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{path}: malformed TOML: {e}") from None
    except UnicodeDecodeError:
        raise SceneError(f"{path}: not a UTF-8 text file") from None
    overrides = list(overrides or [])
    try:
        raw = apply_overrides(raw, overrides)
    except SceneError as e:
        raise SceneError(f"{path}: {e}") from None
    where = Where(f"{path} (with --set {' '.join(overrides)})" if overrides else str(path), SceneError)
    return build_spec(raw, path, where, cross_checks=cross_checks)


def build_spec(raw: dict, path: Path, ctx: Where | None = None, *, cross_checks: bool = True) -> SceneSpec:
    """The SceneSpec of a raw table: every section parsed by its params class, then the checks
    that combine keys (validate.py)."""
    ctx = ctx or Where(str(path), SceneError)
    for k, v in raw.items():
        if k in SECTIONS or k in TABLE_SECTIONS:
            if not isinstance(v, dict):
                raise ctx.fail(k, "expected a table")
        elif k not in TOP_KEYS:
            raise ctx.fail(k, f"unknown section (known: {', '.join([*SECTIONS, *TABLE_SECTIONS])})")
    user_raw = raw
    raw, defaults_applied = apply_best_loop(raw)     # a scene that does not choose its loop (defaults.py)
    description = raw.get("description", "")
    if not isinstance(description, str):
        raise ctx.fail("description", "expected a string")
    sec = {name: parse_params(cls, raw.get(name, {}), name, ctx) for name, cls in SECTIONS.items()}
    tables = {}
    for name, cls in TABLE_SECTIONS.items():
        entries = {}
        for ident, table in raw.get(name, {}).items():
            if not isinstance(table, dict):
                raise ctx.fail(f"{name}.{ident}", "expected a table")
            entries[ident] = parse_params(cls, table, f"{name}.{ident}", ctx)
        tables[name] = MappingProxyType(entries)

    render = sec["render"]
    xml_path = validate.check_source(ctx, path, raw, sec, tables)
    sec["predictor"] = validate.check_predictor(ctx, path, sec["predictor"], cross_checks)
    validate.check_plate(ctx, sec["plate"])
    if cross_checks:
        validate.check_timing(ctx, sec["timing"])
        validate.check_accuracy(ctx, render)
        if sec["dmd"].enabled:
            validate.check_dmd_use(ctx, sec["dmd"], sec["timing"], sec["mask"])
        validate.check_sensor_levels(ctx, sec["sensor"])
    for ident, m in tables["motion"].items():
        validate.check_motion(ctx, f"motion.{ident}", m, sec["timing"])
    for ident, s in tables["spectra"].items():
        validate.check_spectrum(ctx, f"spectra.{ident}", s)
    validate.check_plugin_tables(ctx, path, tables["spectra"], tables["sheeting"])
    validate.check_world(ctx, tables["marking"], tables["vehicle"], tables["furniture"])
    from poevp_optics.sources.traffic import resolve_scene_traffic   # [motion] kind "traffic": simulated paths

    tables["motion"] = resolve_scene_traffic(ctx, sec["traffic"], tables["vehicle"], tables["motion"], sec["timing"])
    if "road" in raw:
        validate.check_road(ctx, sec["road"], tables["spectra"], tables["sheeting"], tables["vehicle"])
    validate.check_controller_prior(ctx, sec["mask"], sec["road"], tables["spectra"], "road" in raw)
    validate.check_sensor_and_relay(ctx, path, sec["sensor"], sec["relay"])
    validate.check_layout(ctx, sec)
    for ident in tables["flicker"]:
        entry = tables["spectra"].get(ident)
        if entry is None or entry.kind == "reflectance":
            raise ctx.fail(f"flicker.{ident}", "must name an emissive [spectra] entry (a lamp)")
    if tables["flicker"] and sec["budget"].late_mask == "partial":
        raise ctx.fail("budget.late_mask", "'partial' (a mask switching inside the window) is not "
                       "modelled for flickering lamps' emitter-group images; use 'next' or 'ideal'")
    validate.check_attenuator(ctx, sec)
    validate.check_metering(ctx, sec)
    if tables["flicker"] and not all(m.is_static for m in tables["motion"].values()):
        raise ctx.fail("flicker", "flickering lamps need static geometry (no moving [motion] entry)")
    spectra_ = tables["spectra"]
    if sec["chart"].patches:
        spectra_ = MappingProxyType({**spectra_, **validate.chart_spectra(ctx, path, sec["chart"], spectra_)})
    return SceneSpec(name=scene_name(path), toml_path=path, xml_path=xml_path,
                     description=description, motion=tables["motion"], spectra=spectra_,
                     flicker=tables["flicker"], sheeting=tables["sheeting"],
                     marking=tables["marking"], vehicle=tables["vehicle"],
                     furniture=tables["furniture"],
                     raw=MappingProxyType(user_raw), origin=ctx.origin, defaults_applied=defaults_applied,
                     **sec)


