"""Fog (sources/weather.py): a lamp seen through fog of visibility V is dimmed by exp(-sigma d),
with sigma = ln(1 / epsilon) / V (Koschmieder; epsilon = 0.05 for WMO's meteorological optical
range, 0.02 for Koschmieder's contrast threshold).

A lamp (an emitting disk of radiance L, 40 m away, filling the camera's field) is rendered through
the [weather] fog (Mitsuba `volpath`, a `homogeneous` medium filling a null-BSDF box, the camera
inside it) and without fog. With the droplets' albedo set to 0 the fog only extinguishes (no
in-scattered halo on the lamp's pixels), so the ratio of the two renders is the transmittance
T = exp(-sigma d), which the test computes from V alone. Each camera ray reaches the lamp with
probability T (free-flight sampling), so a pixel sample is L with probability T and 0 otherwise:
the render's Monte Carlo error is the binomial one, and the tolerance is derived from the
renders' own standard error. The camera's rays start at its near clip, 1e-4 m (Mitsuba's default
0.01 m would skip 0.01 m of fog: T 6e-4 too high at V = 50 m, resolved at 2048 spp). The render cost of fog (the same scene with the droplets'
albedo 0.999, multiple scattering) against no fog is measured and printed.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from poevp_optics.render.renderer import Renderer
from poevp_optics.scene.load import load_scene

D_M = 40.0

FOG_XML = """\
<scene version="3.0.0">
    <default name="lamp" value="1"/>
    <default name="weather_fog_sigma_t" value="0"/>
    <default name="weather_fog_albedo" value="0"/>
    <default name="weather_fog_g" value="0.85"/>
    <integrator type="volpath"><integer name="max_depth" value="6"/></integrator>
    <medium type="homogeneous" id="fog">
        <float name="sigma_t" value="$weather_fog_sigma_t"/>
        <float name="albedo" value="$weather_fog_albedo"/>
        <phase type="hg"><float name="g" value="$weather_fog_g"/></phase>
    </medium>
    <sensor type="perspective" id="camera">
        <float name="fov" value="1"/>
        <float name="near_clip" value="0.0001"/>  <!-- camera rays start here: 1e-4 m of fog skipped -->
        <transform name="to_world"><lookat origin="0, 1, 0" target="0, 1, 1" up="0, 1, 0"/></transform>
        <ref name="medium" id="fog"/>
    </sensor>
    <shape type="cube" id="fog_box">
        <transform name="to_world"><scale value="200"/></transform>
        <bsdf type="null"/>
        <ref name="interior" id="fog"/>
    </shape>
    <shape type="disk" id="lamp_lens">
        <transform name="to_world"><rotate y="1" angle="180"/><translate x="0" y="1" z="{d}"/></transform>
        <emitter type="area"><spectrum name="radiance" value="$lamp"/></emitter>
        <ref name="exterior" id="fog"/>
    </shape>
</scene>
"""


def _scene(write_scene, visibility_m, threshold, albedo, name):
    toml = f"""
    [render]
    spp = 64
    resolution = [8, 8]
    spectral_mode = "mono"
    mc_splits = 8
    seed = 11
    [timing]
    frames = 1
    [spectra.lamp]
    kind = "radiance"
    source = "cie:LED-B4"
    luminance_cd_per_m2 = 1000.0
    [weather]
    fog_visibility_m = {visibility_m}
    fog_contrast_threshold = {threshold}
    fog_albedo = {albedo}
    """
    return load_scene(write_scene(toml, FOG_XML.format(d=D_M), name=name))


def _render(spec, spp=64):
    r = Renderer(spec.resolved.render)
    t0 = time.perf_counter()
    mean, var = r.render_with_error(list(range(1, 9)), spp)
    return float(mean.mean(dtype=np.float64)), math.sqrt(float(var.sum())) / mean.size, time.perf_counter() - t0


@pytest.mark.parametrize("visibility_m,threshold", [(50.0, 0.05), (200.0, 0.05), (100.0, 0.02)])
def test_lamp_through_fog_is_dimmed_by_beer_lambert(write_scene, visibility_m, threshold):
    clear, clear_se, _ = _render(_scene(write_scene, 0.0, 0.05, 0.0, "clear"))
    assert clear_se <= 1e-6 * clear                      # no fog: the lamp's radiance, no noise
    fog, fog_se, _ = _render(_scene(write_scene, visibility_m, threshold, 0.0, f"fog{visibility_m:g}"))
    sigma = math.log(1.0 / threshold) / visibility_m     # Koschmieder, m-1
    expected = math.exp(-sigma * D_M)
    got = fog / clear
    # 5.4 standard errors: (T - exp(-sigma d)) / se is Student's t with 7 dof (8 independent-seed
    # renders), 5.4 its two-sided 99.9 % quantile; the binomial error the renders measure is
    # checked against its closed form sqrt(T (1 - T) / n) within a factor 2 (n = 64 x 64 samples)
    assert abs(got - expected) <= 5.4 * fog_se / clear, (visibility_m, got, expected, fog_se / clear)
    binomial = math.sqrt(expected * (1 - expected) / (64 * 64 * 8))
    assert 0.5 < (fog_se / clear) / binomial < 2.0, (fog_se / clear, binomial)
    print(f"V = {visibility_m:g} m (threshold {threshold}): sigma = {sigma:.5f} m-1, T({D_M:g} m) = {got:.4f} "
          f"+- {fog_se / clear:.4f}, exp(-sigma d) = {expected:.4f}")


def test_fog_render_cost_is_measured(write_scene):
    """Not a timing assertion: prints the cost of fog (albedo 0.999, multiple scattering) against
    clear air, for the docs' table; asserts only that fog adds light around the lamp (haloes)."""
    clear = _scene(write_scene, 0.0, 0.05, 0.999, "cost_clear")
    fog = _scene(write_scene, 50.0, 0.05, 0.999, "cost_fog")
    _render(clear, 8), _render(fog, 8)                  # JIT warm-up of both kernels
    c, _, t_clear = _render(clear)
    f, f_se, t_fog = _render(fog)
    t = math.exp(-math.log(20.0) / 50.0 * D_M)
    assert f / c > t + 5.4 * f_se / c                    # in-scattered light on top of the direct T
    print(f"render cost 8 x 8 px, 8 x 64 spp: clear {t_clear:.3f} s, fog V = 50 m {t_fog:.3f} s "
          f"({t_fog / t_clear:.1f}x); lamp {f / c:.3f} of clear (direct {t:.3f})")
