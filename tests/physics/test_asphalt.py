"""The asphalt albedo map as Mitsuba reads it (sources/asphalt.py, `raw` 16-bit PNG): a
diffuse plane with the map under a uniform sky of radiance L reflects, at each point, rho(x) L
(a Lambertian surface under a uniform hemisphere: L_out = rho L), so the mean over an orthographic
view of one whole tile is mean(rho) L, with mean(rho) the map's own mean read back from the PNG
here and the key's `albedo` the map was made for."""

from __future__ import annotations

import numpy as np
import pytest


def test_rendered_asphalt_reflects_its_mean_albedo():
    from poevp_optics.core import runtime
    from poevp_optics.core.io import read_png
    import poevp_optics.render  # noqa: F401  (installs the plugin hook)
    from poevp_optics.sources.furniture import FurnitureSpec, xml_params

    runtime.set_variant("llvm_ad_mono")
    import mitsuba as mi

    p = xml_params("road", FurnitureSpec(kind="asphalt", length_m=2.0, width_m=2.0, albedo=0.07, seed=9))
    rho = read_png(p["furniture_road_albedo_map"]).astype(np.float64) / 65535
    n = 64
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 2},
        "sensor": {"type": "orthographic",
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 1], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": n, "height": n, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 16}},
        "sky": {"type": "constant", "radiance": 1.0},
        "plane": {"type": "rectangle",
                  "bsdf": {"type": "diffuse",
                           "reflectance": {"type": "bitmap", "filename": p["furniture_road_albedo_map"], "raw": True}}},
    })
    img = np.asarray(mi.render(scene, seed=3), np.float64)[..., 0]
    # the view covers the rectangle [-1, 1]^2 = one tile exactly; bilinear lookups of a periodic
    # map average to its mean over the tile up to the pixel grid's sampling of it (~0.1 %)
    assert rho.mean() == pytest.approx(0.07, abs=1e-5)
    # Monte Carlo: the path integrator's light samples of a uniform sky; per-pixel relative sd
    # ~ 0.5 / sqrt(16) -> over 4096 pixels ~ 0.2 %; 1.5 % is > 5 sigma
    print(f"rendered mean {img.mean():.6f}, map mean {rho.mean():.6f}, sd {img.std():.4f} / {rho.std():.4f}")
    assert img.mean() == pytest.approx(rho.mean(), rel=0.015), (img.mean(), rho.mean())
    # and the texture shows: the render's pixel-to-pixel spread follows the map's (same order)
    assert 0.3 * rho.std() < img.std() < 3 * rho.std()
