"""Follow a run's scene value through the calls: which functions receive the scene object or a
part resolved from it, in which package, and how often the value climbs back up.

A *stop* is a call of a poevp_optics function one of whose arguments is a scene value (by class
name, so the same tracer reads an old checkout: `SceneSpec`, and in newer trees also
`ResolvedScene`, `RenderScene`, `CameraParams`, `LoopParams`; the value's own methods and
properties are not stops: the value does not travel there). A *climb back up* is a stop in a
package that sits above the previous stop's in the import table (tests/helpers.py MAY_IMPORT,
docs/architecture.md's: it may import it): the value went down into a stage and came back to a caller above to be handed down
again. Siblings (camera -> render) are not climbs.

The tracer reads every traced frame's `f_locals` under `sys.setprofile` while Mitsuba and DrJit
run their own threads; in CPython 3.11 a profile hook that materialises `f_locals` writes the
locals back into the frame after the hook returns (`PyFrame_LocalsToFast`), the write-back that
CPython gh-74929 shows corrupting frames when threads, tracing and closures meet (replaced by
PEP 667's proxies only in 3.13): the likely cause of the one crash seen, which took down a whole
test session (a segmentation fault inside Mitsuba's render, about 70 % into the
suite), so tests follow a run in a process of its own (`follow_run_isolated`): a crash there fails
one test with its signal, never the suite. `python tests/scene_flow.py RUN SCENES OUT` is that
process: it prints the Flow as JSON.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

try:
    from tests.helpers import MAY_IMPORT, ROOT_PKG
except ModuleNotFoundError:            # run as a script: `python tests/scene_flow.py ...`
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from tests.helpers import MAY_IMPORT, ROOT_PKG

SCENE_VALUES = ("SceneSpec", "ResolvedScene", "RenderScene", "CameraParams", "LoopParams")

#: The runs followed (`poevp` arguments; the scene is a folder of scenes/): a moving render, the
#: night road (exposure controller, report plug-ins) at 1/24 of its mirrors, a DR chart.
RUNS = {
    "render": ["render", "smoke", "--frames", "2", "--resolution", "16x24", "--spp", "2"],
    "night_road": ["render", "night_road", "--set", "render.resolution=[45,80]",
                   "--set", "objective.focal_length_m=0.002878", "--set", "mask.smooth_px=1.0",
                   "--set", "attenuator.serve_min_mirrors=6", "--set", "render.spp=2",
                   "--set", "render.roi_spp=0", "--set", "timing.frames=4"],
    "chart": ["chart", "dr_chart36", "--resolution", "64x64", "--spp", "2", "--set", "chart.repeats=2",
              "--set", "chart.max_iterations=2", "--set", "chart.roi_inset_px=1",
              "--set", "predictor.resolution=[64,64]"],
}


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


def _package_dir() -> Path:
    """The poevp_optics being traced (the one imported: an older checkout's when it is first on
    the path)."""
    import poevp_optics

    return Path(poevp_optics.__file__).resolve().parent


def _package(filename: str, package_dir: Path) -> tuple[str, str] | None:
    try:
        rel = Path(filename).resolve().relative_to(package_dir)
    except ValueError:
        return None
    top = rel.parts[0]
    pkg = {"cli.py": "cli", "__init__.py": ROOT_PKG}.get(top, top)
    return (pkg, str(rel)) if pkg in MAY_IMPORT else None


def follow(run) -> Flow:
    """Call `run()` under a profiler and return the scene value's stops."""
    flow = Flow()
    seen: dict = {}
    package_dir = _package_dir()

    def tracer(frame, event, arg):
        if event != "call":
            return
        code = frame.f_code
        where = seen.get(code.co_filename)
        if where is None:
            where = seen[code.co_filename] = _package(code.co_filename, package_dir) or ("", "")
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
        if "SceneSpec" in hits and where[0] in MAY_IMPORT["scene"]:      # the stages below scene/
            flow.whole_scene_below_apps.append(f"{where[1]}:{code.co_name}")

    sys.setprofile(tracer)
    try:
        run()
    finally:
        sys.setprofile(None)
    return flow


def follow_run(name: str, out_dir: Path, scenes_dir: Path) -> Flow:
    """Follow `poevp` RUNS[name] writing into `out_dir`."""
    from poevp_optics.cli import main

    cmd, scene, *rest = RUNS[name]
    codes: list[int] = []
    flow = follow(lambda: codes.append(main([cmd, str(scenes_dir / scene), "--out", str(out_dir), "--quiet",
                                             *rest])))
    if codes != [0]:
        raise RuntimeError(f"poevp {' '.join(RUNS[name])} exited {codes}")
    return flow


def follow_run_isolated(name: str, out_dir: Path, scenes_dir: Path, timeout_s: float = 600.0) -> Flow:
    """`follow_run` in a child process (this file run as a script), so that a crash of the
    profiled render ends that process, not the caller's; a child killed by a signal or exiting
    non-zero raises RuntimeError with its signal and the end of its output."""
    env = {**os.environ, "PYTHONFAULTHANDLER": "1"}
    done = subprocess.run([sys.executable, str(Path(__file__).resolve()), name, str(scenes_dir), str(out_dir)],
                          capture_output=True, text=True, timeout=timeout_s, env=env,
                          cwd=str(Path(__file__).resolve().parent.parent))
    if done.returncode != 0:
        how = (f"killed by signal {-done.returncode}" if done.returncode < 0 else f"exited {done.returncode}")
        raise RuntimeError(f"tracing poevp {' '.join(RUNS[name])} in its own process: {how}\n"
                           + (done.stdout + done.stderr)[-3000:])
    data = json.loads(done.stdout.strip().splitlines()[-1])
    return Flow(stops=[tuple(s) for s in data["stops"]], whole_scene_below_apps=data["whole_scene_below_apps"])


if __name__ == "__main__":
    run_name, scenes, out = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
    result = follow_run(run_name, out, scenes)
    sys.stdout.flush()
    print(json.dumps(asdict(result)))
