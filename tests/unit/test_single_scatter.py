"""The `single_scatter` integrator (render/materials/single_scatter.py) on a small fog scene: a
camera inside a homogeneous medium bounded by a null cube, a diffuse wall, a point lamp, a small
area lamp and the sky. In a pure absorber its pixels are the closed form rho / pi x I / r^2 x
exp(-sigma_t (d_light + d_camera)); in a scattering fog its image agrees with Mitsuba's own
`volpath` (max_depth 2: the same single-scattering integral, estimated by delta tracking) within
the two renders' Monte Carlo errors, with a smaller error than volpath's at the same spp."""

from __future__ import annotations

import math

import numpy as np
import pytest

import poevp_optics.render  # noqa: F401  (registers the plugins with every variant set)
from poevp_optics.core import runtime

SIGMA_T, DIST, RHO, INTENSITY = 0.4, 3.0, 0.5, 20.0


def scene(integrator: str, albedo: float, lamps: bool = True):
    import mitsuba as mi

    runtime.set_variant("llvm_ad_mono")
    fog = mi.load_dict({"type": "homogeneous", "sigma_t": SIGMA_T, "albedo": albedo,
                        "phase": {"type": "hg", "g": 0.6}})
    d = {"type": "scene",
         "integrator": {"type": integrator, "max_depth": 2},
         "sensor": {"type": "perspective", "fov": 30, "medium": fog,
                    "to_world": mi.ScalarTransform4f().look_at([0, 0, 0], [0, 0, 1], [0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": 8, "height": 8, "pixel_format": "luminance",
                             "rfilter": {"type": "box"}},
                    "sampler": {"type": "independent"}},
         "box": {"type": "cube", "bsdf": {"type": "null"}, "interior": fog,
                 "to_world": mi.ScalarTransform4f().scale(20)},
         "wall": {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": RHO},
                  "to_world": mi.ScalarTransform4f().translate([0, 0, DIST]).rotate([0, 1, 0], 180)
                  .scale(10)},
         "lamp": {"type": "point", "position": [0, 0, 0], "intensity": INTENSITY}}
    if lamps:
        d["sky"] = {"type": "constant", "radiance": 0.5}
        d["panel"] = {"type": "rectangle", "emitter": {"type": "area", "radiance": 30.0},
                      "to_world": mi.ScalarTransform4f().translate([0.8, 0.6, 1.5]).rotate([1, 0, 0], 180)
                      .scale(0.1)}
        d["lamp"]["position"] = [0.5, -0.3, 0.5]
    return mi.load_dict(d)


def render(sc, spp: int, reps: int) -> np.ndarray:
    import mitsuba as mi

    return np.stack([np.array(mi.render(sc, seed=k, spp=spp))[..., 0] for k in range(reps)])


def test_pure_absorber_is_beer_lambert_times_the_lit_wall():
    imgs = render(scene("single_scatter", 0.0, lamps=False), 64, 2)
    # the image centre sees the wall head-on, lit by the lamp at the camera: r = d = DIST
    expected = RHO / math.pi * INTENSITY / DIST ** 2 * math.exp(-2 * SIGMA_T * DIST)
    centre = imgs[:, 3:5, 3:5].mean()
    # pixel footprint over the centre 2x2: cos^4-like falloff < 0.3 % at +-1 px of 30 deg / 8 px
    assert abs(centre / expected - 1) < 0.01


def test_scattering_fog_agrees_with_volpath_within_mc_error():
    reps = 6
    ss = render(scene("single_scatter", 0.9), 64, reps)
    vp = render(scene("volpath", 0.9), 64, reps)
    for img in (ss, vp):
        assert np.all(np.isfinite(img))
    # 2x2 blocks of 4x4 px: the means and their standard errors over the independent renders
    blocks = lambda a: a.reshape(reps, 2, 4, 2, 4).mean(axis=(2, 4)).reshape(reps, 4)
    bs, bv = blocks(ss), blocks(vp)
    z = (bs.mean(0) - bv.mean(0)) / np.hypot(bs.std(0, ddof=1), bv.std(0, ddof=1)) * math.sqrt(reps)
    assert np.all(np.abs(z) < 4.5), z
    # the closed-form transmittance keeps every sample: a smaller per-pixel error than tracking
    assert ss.std(0, ddof=1).mean() < 0.85 * vp.std(0, ddof=1).mean()      # 0.68x here: the lamp's own
    # in-scattering 0.5 m from the camera (1 / r^2) is as noisy in both


def test_max_depth_other_than_two_is_refused():
    import mitsuba as mi

    runtime.set_variant("llvm_ad_mono")
    with pytest.raises(Exception, match="max_depth must be 2"):
        mi.load_dict({"type": "single_scatter", "max_depth": 3})
