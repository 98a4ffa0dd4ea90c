"""Test helpers: small Mitsuba scenes with closed-form answers, and EXR-sequence scenes."""

import textwrap
from pathlib import Path

#: A Lambertian plane facing a coaxial point light and camera (closed-form radiometry).
PLANE_XML = """\
<scene version="3.0.0">
    <default name="lamp" value="1"/>
    <default name="rho" value="0.5"/>
    <integrator type="path"><integer name="max_depth" value="2"/></integrator>
    <sensor type="perspective" id="camera">
        <float name="fov" value="{fov}"/>
        <transform name="to_world"><lookat origin="0, 0, 0" target="0, 0, 1" up="0, 1, 0"/></transform>
    </sensor>
    <emitter type="point" id="lamp">
        <point name="position" x="0" y="0" z="0"/>
        <spectrum name="intensity" value="$lamp"/>
    </emitter>
    <shape type="rectangle" id="plane">
        <transform name="to_world"><scale x="20" y="20" z="1"/><rotate y="1" angle="180"/><translate z="{d}"/></transform>
        <bsdf type="diffuse"><spectrum name="reflectance" value="$rho"/></bsdf>
    </shape>
</scene>
"""


def graph_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan), each sorted: the import
    cycles of a graph {node: nodes it imports} (test_architecture, test_import_contract)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while (w := stack.pop()) != v:
                on.discard(w)
                comp.append(w)
            on.discard(v)
            out.append(sorted([v, *comp]))

    for v in list(graph):
        if v not in index:
            visit(v)
    return [c for c in out if len(c) > 1]


ROOT_PKG = "poevp_optics"          # the package root, poevp_optics/__init__.py (its __version__)

_STAGES = ("core", "sources", "render", "camera", "control", "analysis")
_BELOW_APPS = (*_STAGES, "scene", ROOT_PKG)

#: Which top-level packages each may import (itself always). DESIGN.md's table, updated where the
#: code taught better (docs/architecture.md says what changed and why); test_import_contract checks
#: the code against it, tests/scene_flow.py counts climbs by it.
MAY_IMPORT: dict[str, frozenset[str]] = {
    "core": frozenset(),
    "sources": frozenset({"core"}),
    "render": frozenset({"core", "sources"}),
    "camera": frozenset({"core"}),
    "control": frozenset({"core", "camera"}),
    "analysis": frozenset({"core"}),
    "scene": frozenset(_STAGES),
    "apps": frozenset(_BELOW_APPS),
    "cli": frozenset({*_BELOW_APPS, "apps"}),
    ROOT_PKG: frozenset({"core"}),
}


def exr_sequence_scene(folder: Path, h: int, w: int, frames: int, tail: str = "") -> Path:
    """Write `folder`/scene.toml for an EXR sequence (frames/*.exr: sensor-weighted photon radiance,
    one frame per 10 ms exposure at 30 fps, h x w px, no relay blur) with the TOML `tail` appended;
    returns the folder (its frames/ made, the EXRs are the caller's)."""
    (folder / "frames").mkdir(parents=True, exist_ok=True)
    (folder / "scene.toml").write_text(textwrap.dedent(f"""\
        [source]
        kind = "exr_sequence"
        frames = "frames/*.exr"
        unit = "photon_radiance"
        fps = 30.0
        subframes = "nearest"
        [render]
        resolution = [{h}, {w}]
        seed = 5
        [timing]
        fps = 30.0
        frames = {frames}
        exposure_s = 0.01
        dmd_window_s = 0.01
        [relay]
        psf = "delta"
        """) + textwrap.dedent(tail))
    return folder
