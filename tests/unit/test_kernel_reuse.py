"""Per-frame state reaches Mitsuba as opaque JIT values: one compiled render kernel serves every
seed and every pose of the moving objects. As Python literals, each seed and each pose was baked
into a kernel of its own, so a run compiled one kernel per call (0.3-1.4 s each on a cold kernel
cache, CPU or GPU) and the images were the same (benchmarks/results/render_backends.md)."""

from __future__ import annotations

import drjit as dr

from poevp_optics.camera.camera import Camera
from poevp_optics.render.renderer import Renderer
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES


def _render_kernels(renderer: Renderer, seed: int, box=None) -> list:
    """The kernels one render call (the whole frame, or `box` alone as the plate's extra samples
    are rendered) launched, as (hash, operation count), largest first."""
    dr.kernel_history()                                   # clears the history
    renderer.render_once(seed, 2) if box is None else renderer.render_box(seed, 2, box)
    launched = [k for k in dr.kernel_history() if "hash" in k]
    return sorted(((str(k["hash"]), k.get("operation_count", 0)) for k in launched), key=lambda k: -k[1])


def test_one_kernel_serves_every_seed_and_pose():
    # night_road moves the oncoming car with its photometric low beams (a Python emitter that
    # keeps its pose as given) and our car with the camera: every kind of moving object
    spec = load_scene(SCENES / "night_road", ["render.resolution=[45,80]", "objective.focal_length_m=0.002878",
                                              "timing.frames=3"])
    cam = Camera.from_params(spec.resolved.camera)
    r = Renderer(spec.resolved.render, guard_px=cam.guard_px)
    times = [float(spec.subframe_times_s(i)[0]) for i in (0, 2)]
    assert times[0] != times[1] and spec.motion                  # the poses really differ
    flag = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        r.set_time(times[0])
        r.render_once(1, 2)                                        # light selection, first compiles
        first = _render_kernels(r, 2)
        box = (4, 4, 12, 20)
        box_first = _render_kernels(r, 4, box)
        r.set_time(times[1])
        other_pose = _render_kernels(r, 3)
        box_other = _render_kernels(r, 5, box)
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, flag)
    assert first and other_pose
    # the render kernel (the largest) is the same program for another seed and another pose
    assert first[0] == other_pose[0], (first[:2], other_pose[:2])
    assert box_first and box_first[0] == box_other[0], (box_first[:2], box_other[:2])
