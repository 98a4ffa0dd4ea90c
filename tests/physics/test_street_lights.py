"""Street lights from photometric files (assets/lamps/street_led.ldt, street_hps.ies; type C):
the illuminance they put on the road.

A luminaire 10 m above a white Lambertian road (reflectance rho) is the `photometric` emitter with
its local axes the world's (C = 0 along the road, +z; C = 90 across it, +x; the nadir -y). A road
point P seen from the lamp in the direction d (gamma from the nadir) is at r = h / cos(gamma), so
its horizontal illuminance is E = I(gamma, C) cos(gamma) / r^2 = I cos^3(gamma) / h^2 and the
road's radiance there L = rho E / pi. A 4 x 4-pixel camera at the lamp looks at each road point
through a 0.004-deg field; E recovered as pi L / rho must equal the file's candela (read here with
eulumdat-py or photompy and interpolated bilinearly with scipy, not by the plugin) times cos^3 / h^2,
averaged over the same field. The LED luminaire has the CIE LED-B3 spectrum, the sodium lamp
CIE HP1 (CIE 015:2018 Table 10, the standard high-pressure sodium lamp), rendered spectrally too.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from poevp_optics.camera.sensor import IMX253
from poevp_optics.render.renderer import Renderer, absolute_spectrum
from poevp_optics.scene.load import load_scene
from poevp_optics.sources import spectra
from poevp_optics.sources.spectra import ASSETS_DIR

H_M = 10.0
RHO = 0.5
TILE_FOV_DEG = 0.004
#: road points (x across toward the carriageway, z along the road), m from the foot of the pole
POINTS = [(0.0, 0.0), (0.0, 10.0), (0.0, -15.0), (3.5, 5.0), (3.5, 20.0), (-2.0, 8.0), (6.0, -12.0), (1.0, 25.0)]

XML = """\
<scene version="3.0.0">
    <default name="lamp" value="1"/>
    <default name="lamp_distribution" value=""/>
    <default name="road" value="0.5"/>
    <integrator type="path"><integer name="max_depth" value="2"/></integrator>
    <sensor type="perspective" id="camera">
        <float name="fov" value="1"/>
        <transform name="to_world"><lookat origin="0, 10, 0" target="0, 0, 0.001" up="0, 0, 1"/></transform>
    </sensor>
    <emitter type="photometric" id="lamp">
        <transform name="to_world"><translate y="10"/></transform>
        <spectrum name="intensity" value="$lamp"/>
        <string name="distribution" value="$lamp_distribution"/>
    </emitter>
    <shape type="rectangle" id="road">
        <transform name="to_world"><scale x="200" y="200" z="1"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="diffuse"><spectrum name="reflectance" value="$road"/></bsdf>
    </shape>
</scene>
"""


def _file_candela(path, dirs):
    """Candela toward world directions from the file, without the plugin's reader (type C: C
    counter-clockwise from +z seen from above, toward +x at 90; gamma from the nadir -y)."""
    from scipy.interpolate import RegularGridInterpolator

    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    c = np.degrees(np.arctan2(x, z)) % 360.0
    g = np.degrees(np.arccos(np.clip(-y, -1, 1)))
    if path.suffix == ".ldt":
        from pyldt import LdtReader

        ldt = LdtReader.read(str(path))
        cs = np.append(np.asarray(ldt.header.c_angles, float), 360.0)
        gs = np.asarray(ldt.header.g_angles, float)
        table = np.asarray(ldt.intensities, float)
        table = np.concatenate([table, table[:1]]) * ldt.header.lamp_flux[0] / 1000.0
    else:
        from photompy import IESFile

        phot = IESFile.read(path).photometry
        cs, gs, table = np.asarray(phot.phis, float), np.asarray(phot.thetas, float), np.asarray(phot.values, float)
    return RegularGridInterpolator((cs, gs), table)(np.stack([c, g], axis=-1))


def _tile_directions(d, n=16):
    up = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(up, d)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    t = math.tan(math.radians(TILE_FOV_DEG) / 2) * ((np.arange(n) + 0.5) / n * 2 - 1)
    a, b = np.meshgrid(t, t)
    w = d[None, None, :] + a[..., None] * e1 + b[..., None] * e2
    return (w / np.linalg.norm(w, axis=-1, keepdims=True)).reshape(-1, 3)


@pytest.mark.parametrize("lamp_file,source,mode", [("lamps/street_led.ldt", "cie:LED-B3", "mono"),
                                                   ("lamps/street_hps.ies", "cie:HP1", "mono"),
                                                   ("lamps/street_hps.ies", "cie:HP1", "spectral")])
def test_road_illuminance_matches_the_file(write_scene, lamp_file, source, mode):
    from poevp_optics.render.materials.photometric_lamp import load_distribution

    path = ASSETS_DIR / lamp_file
    peak = load_distribution(str(path)).peak_cd
    toml = f"""
    [render]
    spp = 4
    resolution = [4, 4]
    spectral_mode = "{mode}"
    [timing]
    frames = 1
    [spectra.lamp]
    kind = "intensity"
    source = "{source}"
    intensity_cd = {peak!r}           # the file's own peak: absolute candela
    distribution = "file:{lamp_file}"
    [spectra.road]
    kind = "reflectance"
    source = "neutral:{RHO}"
    """
    spec = load_scene(write_scene(toml, XML, name=f"street_{path.stem}_{mode}"))
    r = Renderer(spec.resolved.render)
    assert r.plan.mode == mode
    mi = r.mi
    if mode == "spectral":
        film = {"type": "specfilm", "width": 4, "height": 4, "component_format": "float32", "rfilter": {"type": "box"},
                "S": {"type": "irregular", "wavelengths": ", ".join(f"{x:g}" for x in spectra.WAVELENGTHS_NM),
                      "values": ", ".join(f"{x:.7g}" for x in r.plan.response_e_per_J)}}
        spp, seeds = 64, range(1, 9)
    else:
        film = {"type": "hdrfilm", "width": 4, "height": 4, "pixel_format": "luminance", "rfilter": {"type": "box"}}
        spp, seeds = 4, range(1, 5)
    response = spectra.sensor_response_e_per_J(spectra.load_spectrum(IMX253.qe, emissive=True))
    i_s_per_cd = spectra.integrate(response * absolute_spectrum(spec.spectra["lamp"])) / peak
    rows = []
    for x, z in POINTS:
        d = np.array([x, -H_M, z]) / math.sqrt(x * x + H_M * H_M + z * z)
        sensor = mi.load_dict({"type": "perspective", "fov": TILE_FOV_DEG, "film": film,
                               "to_world": mi.ScalarTransform4f().look_at(origin=[0, H_M, 0], target=[x, 0, z],
                                                                          up=[0, 0, 1] if abs(d[2]) < 0.9 else [1, 0, 0])})
        vals = np.array([np.asarray(mi.render(r.mi_scene, sensor=sensor, spp=spp, seed=s), np.float64).mean()
                         for s in seeds])
        e_rendered = math.pi * vals.mean() / RHO / i_s_per_cd
        e_se = math.pi * vals.std(ddof=1) / math.sqrt(len(vals)) / RHO / i_s_per_cd
        dirs = _tile_directions(d)
        e_file = float(np.mean(_file_candela(path, dirs) * (-dirs[:, 1]) ** 3)) / H_M ** 2
        rows.append((x, z, e_rendered, e_file, e_se))
        # 5.4 standard errors (Student's t, 7 dof for 8 seeds / 3 dof for 4: mono has no wavelength
        # noise, its spread is the pixels' position jitter only) plus 2e-4 for float32 directions
        # and the 16 x 16 expectation over the tile
        assert abs(e_rendered - e_file) <= 5.4 * e_se + 2e-4 * e_file + 1e-9, rows[-1]
    print("\n".join(f"{lamp_file} {mode} ({x:+5.1f}, {z:+5.1f}) m: E = {a:8.4f} lx rendered, {b:8.4f} lx from "
                    f"file (+- {s:.4f})" for x, z, a, b, s in rows))
