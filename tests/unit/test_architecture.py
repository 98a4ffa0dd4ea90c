"""The package's shape (issue 15): the chain visible in the folders, no import cycles, no private
name imported across modules, no long functions, registries that are the validator's choices,
and a new PSF in a few lines."""

from __future__ import annotations

import ast
import dataclasses
import typing
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ROOT, SCENES
from tests.helpers import graph_cycles

PKG = ROOT / "poevp_optics"
MAX_FUNCTION_LINES = 80
MAX_MODULE_LINES = 600          # issue 29: one job per module


def _modules() -> dict[str, ast.Module]:
    out = {}
    for p in PKG.rglob("*.py"):
        rel = p.relative_to(ROOT).with_suffix("")
        name = ".".join(rel.parts[:-1] if rel.parts[-1] == "__init__" else rel.parts)
        out[name] = ast.parse(p.read_text(), str(p))
    return out


MODULES = _modules()


def _imports(name: str, tree: ast.Module):
    """(imported module, imported names) of every import in a module, at any depth."""
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.module, [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, []


def _target(mod: str, names: list[str]) -> list[str]:
    """The package modules an import statement loads (a `from pkg import module` loads module)."""
    out = []
    for n in names or [""]:
        full = f"{mod}.{n}" if n else mod
        out.append(full if full in MODULES else mod)
    return [m for m in out if m in MODULES]


def test_the_chain_is_visible_in_the_folders():
    packages = {p.name for p in PKG.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert {"core", "scene", "sources", "render", "camera", "control", "analysis", "apps"} <= packages
    top = {p.stem for p in PKG.glob("*.py")}
    assert top == {"__init__", "cli"}, top


def test_no_import_cycles():
    """Every import (module level or inside a function) between our modules, as a graph: no
    strongly connected component larger than one module (Tarjan)."""
    graph = {m: set() for m in MODULES}
    for name, tree in MODULES.items():
        for mod, names in _imports(name, tree):
            for t in _target(mod, names):
                if t != name and not name.startswith(t + "."):      # a package's own __init__
                    graph[name].add(t)
    cycles = graph_cycles(graph)
    assert not cycles, cycles


def test_sources_import_only_core():
    """DESIGN.md's package table: sources/ (spectra, flicker, plates, the [source] kinds) may
    import only core/ (and itself); the Mitsuba kind is opened from render/radiance.py."""
    bad = []
    for name, tree in MODULES.items():
        if not name.startswith("poevp_optics.sources"):
            continue
        for mod, names in _imports(name, tree):
            for t in _target(mod, names):
                if not t.startswith(("poevp_optics.core", "poevp_optics.sources")) and t != "poevp_optics":
                    bad.append(f"{name} imports {t}")
    assert not bad, bad


def test_benchmarks_and_scripts_import_names_that_exist():
    """Every `from poevp_optics... import name` in benchmarks/ and scripts/ resolves (a module
    move must carry the scripts that live outside the package along)."""
    import importlib

    missing = []
    for path in sorted([*(ROOT / "benchmarks").glob("*.py"), *(ROOT / "scripts").glob("*.py")]):
        for node in ast.walk(ast.parse(path.read_text())):
            if not (isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("poevp_optics")):
                continue
            module = importlib.import_module(node.module)
            for alias in node.names:
                if hasattr(module, alias.name):
                    continue
                try:
                    importlib.import_module(f"{node.module}.{alias.name}")
                except ImportError:
                    missing.append(f"{path.name}:{node.lineno} {node.module}.{alias.name}")
    assert not missing, missing


def test_no_private_name_is_imported_from_another_module():
    bad = []
    for name, tree in MODULES.items():
        for mod, names in _imports(name, tree):
            if mod.startswith("poevp_optics"):
                bad += [f"{name}: from {mod} import {n}" for n in names if n.startswith("_") and n != "__version__"]
    assert not bad, bad


def test_no_function_is_longer_than_80_lines():
    long = []
    for name, tree in MODULES.items():
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{name}.{node.name}: {n} lines")
    assert not long, long


def test_no_module_is_longer_than_600_lines():
    """Issue 29: a module over 600 lines holds more than one job (camera/objective.py had 1087
    and became the camera/objective/ package)."""
    long = {str(p.relative_to(ROOT)): n for p in PKG.rglob("*.py")
            if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, long


def _registry_fields():
    """(section class, field name, its choices) for every field whose choices are a registry."""
    from poevp_optics.core.registry import Registry
    from poevp_optics.scene.spec import SECTIONS, TABLE_SECTIONS

    out = []
    for cls in [*SECTIONS.values(), *TABLE_SECTIONS.values()]:
        for f in dataclasses.fields(cls):
            if isinstance(f.metadata.get("choices"), Registry):
                out.append((cls, f.name, f.metadata["choices"]))
    return out


def test_every_registry_is_its_keys_validator_choices():
    """The scene validator accepts exactly the registered names: each name parses, an unknown
    one is a one-line error listing the registry's names."""
    from poevp_optics.camera.relay import PSFS
    from poevp_optics.camera.sensor import POISSON_SAMPLERS, SENSOR_PRESETS
    from poevp_optics.control.loop_step import LOOP_MODES
    from poevp_optics.control.masks import MASK_LAWS
    from poevp_optics.control.predictors import PREDICTORS
    from poevp_optics.analysis.tonemap import TONEMAPPERS
    from poevp_optics.core.params import parse_params
    from poevp_optics.core.exceptions import ParamError
    from poevp_optics.sources.kinds import SOURCES
    from poevp_optics.sources.ldr_highlight import RADIUS_RULES, TRANSFERS

    found = {id(reg) for _, _, reg in _registry_fields()}
    for reg in (PSFS, SENSOR_PRESETS, POISSON_SAMPLERS, LOOP_MODES, MASK_LAWS, PREDICTORS, TONEMAPPERS,
                SOURCES, TRANSFERS, RADIUS_RULES):
        assert id(reg) in found, reg
    for cls, field, reg in _registry_fields():
        hints = typing.get_type_hints(cls)
        assert hints[field] is str
        for n in reg:
            assert getattr(parse_params(cls, {field: n} | _required(cls)), field) == n
        with pytest.raises(ParamError, match="must be one of"):
            parse_params(cls, {field: "no-such-entry"} | _required(cls))


def _required(cls) -> dict:
    """Values for a class's required fields (SpectrumSpec has two)."""
    need = {f.name for f in dataclasses.fields(cls)
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING}
    return {k: v for k, v in {"kind": "reflectance", "source": "neutral:0.5"}.items() if k in need}


def test_a_stage_is_built_from_a_small_dict_without_a_scene_file():
    from poevp_optics.camera.camera import Camera
    from poevp_optics.camera.dmd import DMDSpec
    from poevp_optics.camera.objective import ObjectiveSpec
    from poevp_optics.camera.relay import RelaySpec
    from poevp_optics.camera.sensor import NoiseSwitches, SensorSpec
    from poevp_optics.core.params import parse_params
    from poevp_optics.core.timing import TimingSpec

    cam = Camera(parse_params(SensorSpec, {"bits": 12}), parse_params(DMDSpec, {"bits": 6}),
                 parse_params(RelaySpec, {"psf": "gaussian", "sigma_px": 1.0}), ObjectiveSpec(),
                 parse_params(TimingSpec, {"exposure_s": 0.01, "dmd_window_s": 0.01}), (16, 24),
                 switches=NoiseSwitches.off())
    rad = np.full(cam.mirror_shape, 1e13, np.float32)
    cap = cam.capture([rad], cam.white_mask(), 0, seed=1)
    assert cap.dn.shape == (16, 24) and cam.top_level == 63 and cam.params.bits == 12


def test_a_new_psf_is_one_registry_entry(tmp_path):
    """Register a box PSF in a few lines, render `smoke` with it, and find the blur in the run."""
    from poevp_optics.apps.run.render_run import run_render
    from poevp_optics.camera.relay import PSF, PSFS, PSFModel
    from poevp_optics.scene.load import load_scene

    def box(spec, ctx):
        k = np.ones((5, 5)) / 25.0
        return PSF("box5", k, 0.0)

    PSFS.register("box5", PSFModel(box, lambda spec, ctx: 2), source="a 5x5 box (test)")
    try:
        spec = load_scene(SCENES / "smoke", ["relay.psf='box5'", "timing.frames=1", "render.spp=4",
                                             "outputs.previews=false", "outputs.contact_sheet=false"])
        report = run_render(spec, tmp_path, progress=False)
        assert report["optics"]["guard_px"] == 2 and "relay" not in report["skipped_stages"]
        assert report["errors"]["psf_truncation"]["support_px"] == 5
    finally:
        PSFS.unregister("box5")
