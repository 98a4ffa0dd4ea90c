"""Per-frame values handed to Mitsuba as opaque JIT values, so that one compiled kernel serves
every frame (docs/architecture.md, tests/unit/test_kernel_reuse.py).

Mitsuba's JIT variants cache a compiled kernel by its program text, and a value that reaches the
program as a Python number is a literal in that text. A moving object's pose written through
`mi.traverse` (the photometric lamp, a Python emitter, keeps its pose as given) made every pose a
program of its own: 159 kernels for the 174 calls of night_road at 1/6 scale on an empty kernel
cache, 63 with the poses opaque (images bit-identical). The sampler's seed needs nothing: an int
seed compiles no kernel of its own (measured: six seeds, one program).
"""

from __future__ import annotations


def opaque_pose(pose):
    """`pose` (a Transform4f computed from Python floats) made opaque in place; returned."""
    import drjit as dr

    dr.make_opaque(pose)
    return pose
