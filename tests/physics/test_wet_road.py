"""Wet road (sources/weather.py): a water film over asphalt reflects like Fresnel's water-air interface.

The film is Mitsuba's `plastic` (a smooth dielectric over a diffuse base) with water (n = 1.333)
under air (n = 1.000277). Its specular reflectance at incidence theta is the unpolarised Fresnel
reflectance R = (r_s^2 + r_p^2) / 2, computed here from Snell's law:
r_s = (n1 cos i - n2 cos t) / (n1 cos i + n2 cos t), r_p = (n2 cos i - n1 cos t) / (n2 cos i + n1 cos t).
Checked at the grazing angles a driver sees the road at (80, 85, 88 deg from the normal, i.e. 10
to 2 deg below the horizon): (1) the BSDF's specular component sampled alone (its weight is R);
(2) rendered: a wet road over black asphalt under a uniform sky of radiance L_sky, seen at
theta, has radiance R L_sky (the sky's mirror image), with the [weather] keys bound by the loader.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from poevp_optics.render.renderer import Renderer
from poevp_optics.scene.load import load_scene

N_WATER, N_AIR = 1.333, 1.000277
ANGLES_DEG = (80.0, 85.0, 88.0)


def fresnel(theta_deg, n1=N_AIR, n2=N_WATER):
    ci = math.cos(math.radians(theta_deg))
    st = n1 / n2 * math.sin(math.radians(theta_deg))
    ct = math.sqrt(1 - st * st)
    rs = (n1 * ci - n2 * ct) / (n1 * ci + n2 * ct)
    rp = (n2 * ci - n1 * ct) / (n2 * ci + n1 * ct)
    return 0.5 * (rs * rs + rp * rp)


def test_fresnel_reference_values():
    """The formula above at normal incidence is ((n2 - n1) / (n2 + n1))^2 = 2.0 % for water."""
    assert fresnel(0.0) == pytest.approx(((N_WATER - N_AIR) / (N_WATER + N_AIR)) ** 2, rel=1e-12)
    assert 0.0199 < fresnel(0.0) < 0.0205


@pytest.mark.parametrize("variant", ["llvm_ad_mono", "llvm_ad_spectral"])
@pytest.mark.parametrize("rho", [0.0, 0.09])
def test_specular_reflectance_is_fresnel(variant, rho):
    import drjit as dr
    import mitsuba as mi

    from poevp_optics.core import runtime
    from poevp_optics.sources.weather import wet_road_bsdf

    runtime.set_variant(variant)
    bsdf = mi.load_dict(wet_road_bsdf(rho))
    ctx = mi.BSDFContext()
    ctx.type_mask = +mi.BSDFFlags.DeltaReflection            # the water surface's mirror term alone
    for theta in ANGLES_DEG:
        si = dr.zeros(mi.SurfaceInteraction3f)
        t = math.radians(theta)
        si.wi = mi.Vector3f(math.sin(t), 0.0, math.cos(t))
        si.sh_frame = mi.Frame3f(mi.Normal3f(0, 0, 1))
        bs, weight = bsdf.sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))
        got = float(np.mean(np.asarray(weight)))
        # float32 Fresnel: 1e-5 relative; the mirror direction itself is exact
        assert got == pytest.approx(fresnel(theta), rel=1e-4), (theta, got, fresnel(theta))
        assert np.allclose(np.asarray(bs.wo).ravel(), [-math.sin(t), 0.0, math.cos(t)], atol=1e-6)


WET_XML = """\
<scene version="3.0.0">
    <default name="sky" value="1"/>
    <default name="asphalt" value="0"/>
    <default name="weather_wetness" value="1"/>
    <default name="weather_water_ior" value="1.333"/>
    <default name="weather_air_ior" value="1.000277"/>
    <integrator type="path"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective" id="camera">
        <float name="fov" value="0.01"/>
        <transform name="to_world"><lookat origin="0, 1, -5" target="0, 0, 0" up="0, 1, 0"/></transform>
    </sensor>
    <emitter type="constant" id="sky"><spectrum name="radiance" value="$sky"/></emitter>
    <shape type="rectangle" id="road">
        <transform name="to_world"><scale x="1000" y="1000" z="1"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="blendbsdf">
            <float name="weight" value="$weather_wetness"/>
            <bsdf type="diffuse"><spectrum name="reflectance" value="$asphalt"/></bsdf>
            <bsdf type="plastic">
                <float name="int_ior" value="$weather_water_ior"/>
                <float name="ext_ior" value="$weather_air_ior"/>
                <spectrum name="diffuse_reflectance" value="$asphalt"/>
            </bsdf>
        </bsdf>
    </shape>
</scene>
"""


def test_rendered_wet_road_mirrors_the_sky_with_fresnel_reflectance(write_scene):
    toml = """
    [render]
    spp = 4
    resolution = [4, 4]
    spectral_mode = "mono"
    [timing]
    frames = 1
    [spectra.sky]
    kind = "radiance"
    source = "cie:D65"
    luminance_cd_per_m2 = 1.0
    [spectra.asphalt]
    kind = "reflectance"
    source = "neutral:0"
    [weather]
    wetness = 1.0
    """
    spec = load_scene(write_scene(toml, WET_XML, name="wet"))
    r = Renderer(spec.resolved.render)
    assert r.plan.xml_params["weather_water_ior"] == "1.333"
    mi = r.mi
    l_sky = float(r.plan.xml_params["sky"])                           # mono: e- s-1 m-2 sr-1
    film = {"type": "hdrfilm", "width": 4, "height": 4, "pixel_format": "luminance", "rfilter": {"type": "box"}}
    for theta in ANGLES_DEG:
        t = math.radians(theta)
        origin = [0.0, 10.0 * math.cos(t), -10.0 * math.sin(t)]     # looking at the origin, theta from +y
        sensor = mi.load_dict({"type": "perspective", "fov": 0.01, "film": film,
                               "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=[0, 0, 0], up=[0, 1, 0])})
        img = np.asarray(mi.render(r.mi_scene, sensor=sensor, spp=4, seed=1), dtype=np.float64)
        # the delta reflection and a uniform sky leave no Monte Carlo noise; over the 0.01-deg
        # field theta varies by +-0.005 deg: dR/dtheta / R < 0.1 per deg at 88 deg, so < 5e-4
        assert img.mean() / l_sky == pytest.approx(fresnel(theta), rel=1e-3), (theta, img.mean() / l_sky)
