"""A traffic light with PWM-driven LED signals: what an exposure collects equals its PWM table.

The signal head: a dark housing with three 200 mm lenses (EN 12368's 200 mm size) as area
emitters; the red one is lit and its LED drive is pulse-width modulated (`[flicker.signal_red]`,
core/flicker.py; 97 Hz, 30 % duty, first pulse 1.3 ms after t = 0). A camera looks at the red lens
only. The scene's geometry is static, so the renderer makes the lens's image once and the
exposure of frame i is the lens's radiance L times the drive's mean over the exposure window
[t0, t1] (render/exposures.py). Independently, the test lists the PWM table's pulses
[phase + k / f, phase + k / f + duty / f] and adds up their overlap with each window: the
exposure's radiance over the lens must be L x on-time / exposure time, with L the emitter's
radiance (a lit lens seen head-on shows its own radiance, no Monte Carlo noise on the lens).
Exposures of 4 ms at 30 fps catch the 10.3 ms PWM period at a different phase every frame: some
windows hold a whole pulse, some part of one, some none.
"""

from __future__ import annotations

import math

import numpy as np

from poevp_optics.camera.sensor import IMX253
from poevp_optics.render.exposures import render_exposures
from poevp_optics.render.renderer import Renderer, absolute_spectrum
from poevp_optics.scene.load import load_scene
from poevp_optics.sources import spectra

FREQ_HZ, DUTY, PHASE_S = 97.0, 0.3, 0.0013
FPS, EXPOSURE_S, FRAMES = 30.0, 0.004, 8

XML = """\
<scene version="3.0.0">
    <default name="signal_red" value="1"/>
    <default name="signal_amber" value="0"/>
    <default name="signal_green" value="0"/>
    <default name="housing" value="0.04"/>
    <integrator type="path"><integer name="max_depth" value="2"/></integrator>
    <sensor type="perspective" id="camera">
        <float name="fov" value="0.2"/>
        <transform name="to_world"><lookat origin="0, 4.25, -20" target="0, 4.25, 0" up="0, 1, 0"/></transform>
    </sensor>
    <shape type="cube" id="housing">
        <transform name="to_world"><scale x="0.15" y="0.45" z="0.1"/><translate y="4" z="0.1"/></transform>
        <bsdf type="diffuse"><spectrum name="reflectance" value="$housing"/></bsdf>
    </shape>
    <shape type="disk" id="lens_red">
        <transform name="to_world"><scale x="0.1" y="0.1" z="1"/><rotate y="1" angle="180"/><translate y="4.25" z="-0.001"/></transform>
        <emitter type="area"><spectrum name="radiance" value="$signal_red"/></emitter>
    </shape>
    <shape type="disk" id="lens_amber">
        <transform name="to_world"><scale x="0.1" y="0.1" z="1"/><rotate y="1" angle="180"/><translate y="4.0" z="-0.001"/></transform>
        <emitter type="area"><spectrum name="radiance" value="$signal_amber"/></emitter>
    </shape>
    <shape type="disk" id="lens_green">
        <transform name="to_world"><scale x="0.1" y="0.1" z="1"/><rotate y="1" angle="180"/><translate y="3.75" z="-0.001"/></transform>
        <emitter type="area"><spectrum name="radiance" value="$signal_green"/></emitter>
    </shape>
</scene>
"""

TOML = f"""
[render]
spp = 4
resolution = [6, 6]
spectral_mode = "mono"
[timing]
fps = {FPS}
frames = {FRAMES}
exposure_s = {EXPOSURE_S}
dmd_window_s = {EXPOSURE_S}
[dmd]
enabled = false
[flicker.signal_red]       # the red LEDs' PWM drive
frequency_hz = {FREQ_HZ}
duty = {DUTY}
phase_s = {PHASE_S}
[spectra.signal_red]       # ~400 cd on axis from a 200 mm lens: 400 / (pi 0.1^2) cd m-2
kind = "radiance"
source = "cie:LED-B4"
luminance_cd_per_m2 = 12732.0
[spectra.signal_amber]
kind = "radiance"
source = "cie:LED-B4"
luminance_cd_per_m2 = 0.0
[spectra.signal_green]
kind = "radiance"
source = "cie:LED-B4"
luminance_cd_per_m2 = 0.0
[spectra.housing]
kind = "reflectance"
source = "neutral:0.04"
[mask]
law = "white"
"""


def _on_time_s(t0, t1):
    """Seconds of [t0, t1] during which the PWM table's pulses are on (listed here, pulse by pulse)."""
    period = 1.0 / FREQ_HZ
    total, k = 0.0, int(math.floor((t0 - PHASE_S) / period)) - 1
    while PHASE_S + k * period < t1:
        a = PHASE_S + k * period
        total += max(0.0, min(a + DUTY * period, t1) - max(a, t0))
        k += 1
    return total


def test_exposure_integrates_the_pwm_table(write_scene):
    spec = load_scene(write_scene(TOML, XML, name="signal"))
    scene = spec.resolved.render
    renderer = Renderer(scene)
    response = spectra.sensor_response_e_per_J(spectra.load_spectrum(IMX253.qe, emissive=True))
    l_red = spectra.integrate(response * absolute_spectrum(spec.spectra["signal_red"]))   # e- s-1 m-2 sr-1
    fractions = []
    for ex in render_exposures(scene, renderer, progress=False):
        t0 = ex.index / FPS
        assert math.isclose(ex.t_start_s, t0, abs_tol=1e-12) and math.isclose(ex.exposure_s, EXPOSURE_S, rel_tol=1e-9)
        frac = _on_time_s(t0, t0 + EXPOSURE_S) / EXPOSURE_S
        fractions.append(frac)
        got = np.asarray(ex.radiance.data, np.float64)
        # the lens fills the field: every pixel is L x on-fraction (float32 image: 1e-6)
        np.testing.assert_allclose(got, frac * l_red, rtol=2e-6, atol=1e-9 * l_red)
    # the 8 windows sample the PWM at different phases: dark, partial and whole pulses
    assert min(fractions) == 0.0 and max(fractions) > 0.5 and any(0 < f < DUTY * 1.0 / (FREQ_HZ * EXPOSURE_S) for f in fractions)
    print("on-fractions per frame:", ", ".join(f"{f:.3f}" for f in fractions))
