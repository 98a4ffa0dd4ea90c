"""Per-frame state reaches Mitsuba as opaque JIT values (render/opaque.py): one compiled render
kernel serves every seed and every pose of the moving objects. As Python literals, each pose was
baked into a kernel of its own, so a run compiled one kernel per call (0.3-1.4 s each on a cold
kernel cache, CPU or GPU) and the images were the same
(benchmarks/results/render_backends.md).

The kernels are read in a process of their own (this file run as a script), as a `poevp render`
sees them: the JIT state that earlier tests leave in the suite's process is not the question."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path


def _render_kernels(renderer, seed: int, box=None) -> list:
    """The kernels one render call (the whole frame, or `box` alone as the plate's extra samples
    are rendered) launched, as (hash, operation count), largest first."""
    import drjit as dr

    dr.kernel_history()                                   # clears the history
    renderer.render_once(seed, 2) if box is None else renderer.render_box(seed, 2, box)
    launched = [k for k in dr.kernel_history() if "hash" in k]
    return sorted(((str(k["hash"]), k.get("operation_count", 0)) for k in launched), key=lambda k: -k[1])


def kernels_at_three_poses(scenes: Path) -> dict:
    """The largest render kernel of every call, whole frame and plate box, two seeds each at three
    poses of night_road, which moves the oncoming car with its photometric low beams (a Python
    emitter that keeps its pose as given) and our car with the camera."""
    import drjit as dr

    from poevp_optics.camera.camera import Camera
    from poevp_optics.render.renderer import Renderer
    from poevp_optics.scene.load import load_scene

    spec = load_scene(scenes / "night_road", ["render.resolution=[45,80]", "objective.focal_length_m=0.002878",
                                              "timing.frames=3"])
    cam = Camera.from_params(spec.resolved.camera)
    r = Renderer(spec.resolved.render, guard_px=cam.guard_px)
    times = [float(spec.subframe_times_s(i)[0]) for i in (0, 1, 2)]
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    r.set_time(times[0])
    r.render_once(1, 2)                                        # light selection, first compiles
    box, frame, boxes, seed = (4, 4, 12, 20), [], [], 10
    for t in times:
        r.set_time(t)
        for _ in range(2):
            frame.append(_render_kernels(r, seed)[0][0])
            boxes.append(_render_kernels(r, seed + 1, box)[0][0])
            seed += 2
    return {"times": times, "moving": sorted(spec.motion), "frame": frame, "box": boxes}


def test_one_kernel_serves_every_seed_and_pose():
    here = Path(__file__).resolve()
    done = subprocess.run([sys.executable, str(here)], capture_output=True, text=True, timeout=600,
                          cwd=str(here.parents[2]))
    assert done.returncode == 0, (done.stdout + done.stderr)[-3000:]
    k = json.loads(done.stdout.strip().splitlines()[-1])
    assert len(set(k["times"])) == 3 and k["moving"]               # the poses really differ
    # six calls (two seeds at each of three poses): literal poses give three whole-frame programs
    assert len(set(k["frame"])) == 1, k["frame"]
    # the box's program comes in one of two forms (work the JIT still holds from the call before
    # is fused into it or not), never one per seed or pose
    assert len(set(k["box"])) <= 2, k["box"]


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    from tests.conftest import SCENES

    print(json.dumps(kernels_at_three_poses(SCENES)))
