"""Follow a run's scene value through the calls (issue 30): which functions receive the scene
object or a part resolved from it, in which package, and how often the value climbs back up.

A *stop* is a call of a poevp_optics function one of whose arguments is a scene value (by class
name, so the same tracer reads an old checkout: `SceneSpec`, and since issue 30 also
`ResolvedScene`, `RenderScene`, `CameraParams`, `LoopParams`; the value's own methods and
properties are not stops: the value does not travel there). A *climb back up* is a stop in a
package that sits above the previous stop's in the import table (docs/architecture.md: it may
import it): the value went down into a stage and came back to a caller above to be handed down
again. Siblings (camera -> render) are not climbs.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

#: Who may import whom (docs/architecture.md's table, tests/unit/test_import_contract.py).
MAY_IMPORT = {"core": set(), "sources": {"core"}, "render": {"core", "sources"}, "camera": {"core"},
              "control": {"core", "camera"}, "analysis": {"core"},
              "scene": {"core", "sources", "render", "camera", "control", "analysis"},
              "apps": {"core", "sources", "render", "camera", "control", "analysis", "scene"},
              "cli": {"core", "sources", "render", "camera", "control", "analysis", "scene", "apps"}}
RANK = {p: len(v) for p, v in MAY_IMPORT.items()}
SCENE_VALUES = ("SceneSpec", "ResolvedScene", "RenderScene", "CameraParams", "LoopParams")
PACKAGE_DIR = Path(__file__).resolve().parent.parent / "poevp_optics"


@dataclass
class Flow:
    stops: list[tuple[str, str, str]] = field(default_factory=list)   # (package, file, function)
    whole_scene_below_apps: list[str] = field(default_factory=list)   # "file:function" given a SceneSpec

    @property
    def path(self) -> list[tuple[str, str, str]]:
        """The distinct stops in first-visit order: the path a reader follows (a frame loop or a
        generator visits the same stops every frame; they count once)."""
        return list(dict.fromkeys(self.stops))

    @property
    def files(self) -> set[str]:
        return {f for _, f, _ in self.stops}

    @property
    def climbs(self) -> int:
        pkgs = [p for p, _, _ in self.path]
        return sum(1 for a, b in zip(pkgs, pkgs[1:]) if a in MAY_IMPORT[b])


def _package(filename: str) -> tuple[str, str] | None:
    try:
        rel = Path(filename).resolve().relative_to(PACKAGE_DIR)
    except ValueError:
        return None
    top = rel.parts[0]
    pkg = "cli" if top == "cli.py" else top
    return (pkg, str(rel)) if pkg in RANK else None


def follow(run) -> Flow:
    """Call `run()` under a profiler and return the scene value's stops."""
    flow = Flow()
    seen: dict = {}

    def tracer(frame, event, arg):
        if event != "call":
            return
        code = frame.f_code
        where = seen.get(code.co_filename)
        if where is None:
            where = seen[code.co_filename] = _package(code.co_filename) or ("", "")
        if not where[0]:
            return
        n = code.co_argcount + code.co_kwonlyargcount
        names = [type(frame.f_locals.get(v)).__name__ for v in code.co_varnames[:n]]
        hits = [c for c in names if c in SCENE_VALUES]
        if hits and n and code.co_varnames[0] == "self" and names[0] in SCENE_VALUES:
            hits = hits[1:]              # the value's own methods and properties: not a stop
        if not hits:
            return
        flow.stops.append((where[0], where[1], code.co_name))
        if "SceneSpec" in hits and RANK[where[0]] < RANK["scene"]:
            flow.whole_scene_below_apps.append(f"{where[1]}:{code.co_name}")

    sys.setprofile(tracer)
    try:
        run()
    finally:
        sys.setprofile(None)
    return flow
