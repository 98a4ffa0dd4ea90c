"""scenes/night_road as a road world: the car ahead is a [vehicle.*] whose plate is the plate the
[road] report reads, the oncoming SUV carries its low beams, the lane markings retroreflect as
their EN 1436 class, and everything on the road moves past the camera as one rigid world.

Checked against numbers written out here (the scene's own geometry, EN 1436's table), not
against the code that places the parts: the plate's rectangle is read back from the matrix the
XML receives and compared with the recess's closed form and with [road] plate_position_m."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from poevp_optics.scene.load import load_scene
from poevp_optics.sources.road import plate_centre_m
from poevp_optics.sources.vehicles import xml_params as vehicle_xml_params
from tests.conftest import SCENES

NIGHT = SCENES / "night_road"
#: sources/vehicles.py's recess: the plate 2 mm proud of a 30 mm deep floor; EU plate 520 x 110 mm.
RECESS_DEPTH_M, PROUD_M, PLATE_W_M, PLATE_H_M = 0.030, 0.002, 0.520, 0.110
#: EN 1436:2018 Table 4: class R3 (dry) minimum R_L, mcd m-2 lx-1; its 30 m geometry (deg above the road).
R3_MCD, ILLUM_DEG, OBS_DEG = 150.0, 1.24, 2.29
#: Our speed toward the stopped car (m/s) and the oncoming SUV's speed toward us (m/s).
OUR_SPEED, ONCOMING_SPEED = 25.0, 15.0


@pytest.fixture(scope="module")
def spec():
    return load_scene(NIGHT)


@pytest.fixture(scope="module")
def xml():
    return ET.parse(NIGHT / "scene.xml").getroot()


def _matrix(text: str) -> np.ndarray:
    return np.array(text.split(), float).reshape(4, 4)


def _shape(xml, ident):
    (node,) = [n for n in xml if n.get("id") == ident]      # top-level elements (a <ref> carries an id too)
    return node


def _ids(xml, tag) -> set[str]:
    return {n.get("id") for n in xml if n.tag == tag}


def test_the_vehicles_plate_is_the_plate_the_road_report_reads(spec, xml):
    """The rectangle `plate` is placed by [vehicle.car]'s plate matrix (a rotation times the
    plate's half sizes, texture mirrored in u): its centre is the recess's closed form (rear face
    + 30 mm - 2 mm, at plate_height_m) and [road] plate_position_m, its normal -z (the normal the
    report's entrance angle takes), and at every exposure the report's plate centre is that point
    moved by the motion that also carries the car's meshes."""
    assert spec.road.vehicle == "car"
    car = spec.vehicle["car"]
    assert car.kind == "sedan" and car.heading_deg == 0.0
    m = _matrix(vehicle_xml_params("car", car)["vehicle_car_plate_matrix"])
    centre = (m @ [0.0, 0.0, 0.0, 1.0])[:3]
    x, z_rear = car.position_m
    np.testing.assert_allclose(centre, [x, car.plate_height_m, z_rear + RECESS_DEPTH_M - PROUD_M], atol=1e-9)
    np.testing.assert_allclose(centre, spec.road.plate_position_m, atol=1e-6)
    normal = m[:3, :3] @ [0.0, 0.0, 1.0]             # the rectangle's local +z
    np.testing.assert_allclose(normal / np.linalg.norm(normal), [0.0, 0.0, -1.0], atol=1e-12)
    assert np.linalg.det(m[:3, :3]) > 0                # a rotation, no mirror
    np.testing.assert_allclose(np.linalg.norm(m[:3, :2], axis=0), [PLATE_W_M / 2, PLATE_H_M / 2], rtol=1e-9)

    plate = _shape(xml, "plate")
    assert plate.find("transform/matrix").get("value") == "$vehicle_car_plate_matrix"
    uv = plate.find(".//texture/transform")
    assert uv.get("name") == "to_uv" and uv.find("scale").get("x") == "-1"
    assert plate.find(".//texture/string[@name='filename']").get("value") == f"${spec.plate.param}"

    moving = {"plate", *spec.motion["plate"].attached}
    car_parts = {n.get("id") for n in xml if n.tag == "shape" and
                 n.find("transform/matrix") is not None and n.find("transform/matrix").get("value") == "$vehicle_car_matrix"}
    assert len(car_parts) == 7 and car_parts <= moving
    render = spec.resolved.render
    for i in range(spec.timing.frames):
        t = 0.5 * sum(spec.timing.exposure_window_s(i))
        np.testing.assert_allclose(plate_centre_m(render, t), centre + [0.0, 0.0, -OUR_SPEED * t], atol=1e-9)


def test_a_plate_that_is_not_the_vehicles_is_a_one_line_error():
    from poevp_optics.core.exceptions import SceneError

    for override, key in (("road.vehicle='bus'", "road.vehicle"), ("vehicle.car.position_m=[0.0,59.5]",
                                                                   "vehicle.car.position_m"),
                          ("vehicle.car.plate_height_m=0.55", "vehicle.car.position_m"),
                          ("vehicle.car.heading_deg=180.0", "vehicle.car.heading_deg")):
        with pytest.raises(SceneError, match=key) as e:
            load_scene(NIGHT, [override])
        assert "\n" not in str(e.value)


def test_the_oncoming_suv_carries_its_low_beams(spec, xml):
    """The photometric low beams sit at the SUV's headlamp lenses and point along its heading (at
    us, -z); they, its lit lenses and its meshes ride on one motion: 15 m/s toward our 25 m/s."""
    onc = spec.vehicle["oncoming"]
    assert onc.kind == "suv" and onc.heading_deg == 180.0
    params = vehicle_xml_params("oncoming", onc)
    world = _matrix(params["vehicle_oncoming_matrix"])
    for side in ("left", "right"):
        node = _shape(xml, f"lowbeam_{side}")
        assert node.tag == "emitter" and node.get("type") == "photometric"
        assert node.find("transform/matrix").get("value") == f"$vehicle_oncoming_headlamp_{side}_matrix"
        lamp = _matrix(params[f"vehicle_oncoming_headlamp_{side}_matrix"])
        np.testing.assert_allclose(lamp[:3, 2], [0.0, 0.0, -1.0], atol=1e-12)
        front_z = world[2, 3] - 4.49                    # the SUV's rear face minus its length (VW Tiguan)
        assert front_z < lamp[2, 3] < front_z + 0.01 and 0.5 < lamp[1, 3] < 1.0
    lenses = _shape(xml, "oncoming_head_lamps")
    assert lenses.find("emitter/spectrum").get("value") == "$oncoming_lens"
    m = spec.motion["oncoming_body"]
    assert {"lowbeam_left", "lowbeam_right", "oncoming_head_lamps"} <= set(m.attached)
    np.testing.assert_allclose(m.velocity_m_per_s, [0.0, 0.0, -(OUR_SPEED + ONCOMING_SPEED)])


def test_the_road_moves_past_the_camera_as_one_world(spec, xml):
    """We drive at 25 m/s with the camera at z = 0: every shape on the road (the stopped car, its
    plate, the markings, the posts) moves at -25 m/s under one [motion] entry; what stays put is
    our own lamps, the sky and the asphalt and verges, which are uniform along z and cover the road
    in view (from the nearest row the camera sees, 13.5 m, to 400 m) at every time."""
    world = {"plate", *spec.motion["plate"].attached}
    oncoming = {"oncoming_body", *spec.motion["oncoming_body"].attached}
    assert not world & oncoming
    np.testing.assert_allclose(spec.motion["plate"].velocity_m_per_s, [0.0, 0.0, -OUR_SPEED])
    everything = _ids(xml, "shape") | _ids(xml, "emitter")
    static = everything - world - oncoming
    assert static == {"road", "verge_left", "verge_right", "highbeam_left", "highbeam_right", "sky"}
    t_end = spec.timing.exposure_window_s(spec.timing.frames - 1)[1]
    for ident in ("road", "verge_left", "verge_right"):
        tr = _shape(xml, ident).find("transform")
        half = float(tr.find("scale").get("y"))
        z = float(tr.find("translate").get("z"))
        assert z - half <= 13.5 and z + half >= 400.0
    markings = {n.get("id") for n in xml if n.tag == "shape" and n.find("ref") is not None
                and n.find("ref").get("id") == "lane_paint"}
    assert markings and markings <= world
    # the dashed centre line: 6 m dashes every 18 m at x = 1.75 m cover the view all the way
    dashes = sorted(float(_shape(xml, i).find("transform/translate").get("z")) for i in markings if i.startswith("dash"))
    assert np.allclose(np.diff(dashes), 18.0)
    assert dashes[0] - OUR_SPEED * 0 <= 13.5 + 18 and dashes[-1] - OUR_SPEED * t_end >= 380.0
    for i in markings:
        tr = _shape(xml, i).find("transform")
        x, y = float(tr.find("translate").get("x")), float(tr.find("translate").get("y"))
        w = 2 * float(tr.find("scale").get("x"))
        if i.startswith("dash"):
            assert (x, w, 2 * float(tr.find("scale").get("y"))) == (1.75, 0.12, 6.0)
        else:
            assert x in (-1.75, 5.25) and w == 0.15
        assert 0 < y <= 0.005                            # on the asphalt, a few mm proud
    # delineator posts (sources/furniture.py) every 50 m on both verges, their reflectors on the world too
    reflectors = {n.get("id") for n in xml if n.tag == "shape" and n.find("ref") is not None
                  and n.find("ref").get("id") == "delineator"}
    assert reflectors == {"reflectors_right", "reflectors_left"} and reflectors <= world
    assert {"posts_right", "posts_left"} <= world
    for run in spec.furniture.values():
        assert run.kind == "delineator" and run.heading_deg == 0.0 and run.spacing_m in (-1.0, 50.0)
        assert run.position_m[1] - OUR_SPEED * t_end + run.length_m >= 350.0
    assert sorted(r.position_m[0] for r in spec.furniture.values()) == [-3.0, 6.5]   # 1.25 m beyond the edge lines
    assert _shape(xml, "delineator").get("type") == "retroreflective"


def test_the_markings_return_their_en1436_class(spec, xml):
    """The markings' BSDF is `road_marking` bound to [marking.lane], class R3; evaluated (Mitsuba)
    with the scene's own binding at EN 1436's 30 m geometry it returns R_L = 150 mcd m-2 lx-1
    plus the paint's diffuse rho sin(1.24 deg) / pi (EN 1436 section 4.3; the BSDF's eval is
    f cos(theta_light) = L / E_perp)."""
    import drjit as dr
    import mitsuba as mi

    from poevp_optics.core import runtime
    from poevp_optics.render.materials.bindings import plugin_xml_params
    import poevp_optics.render  # noqa: F401  (installs the plugin hook)

    paint = _shape(xml, "lane_paint")
    assert paint.get("type") == "road_marking"
    assert paint.find("string[@name='marking']").get("value") == "$lane"
    assert spec.marking["lane"].source == "en1436:R3"
    declared = frozenset(n.get("name") for n in xml if n.tag == "default")
    bound = plugin_xml_params(spec.resolved.render, declared)["lane"]
    runtime.set_variant("llvm_ad_mono")

    def unit(elevation_deg):
        e = math.radians(elevation_deg)
        return [math.cos(e), 0.0, math.sin(e)]

    for rho in (0.0, 0.6):
        bsdf = mi.load_dict({"type": "road_marking", "marking": bound, "reflectance": rho})
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi, si.n = mi.Vector3f(*unit(OBS_DEG)), mi.Normal3f(0, 0, 1)
        si.sh_frame = mi.Frame3f(si.n)
        got = float(np.mean(np.asarray(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*unit(ILLUM_DEG))))))
        # 1e-3: the class is a node of the R_A table; float32 directions are good to ~1e-6
        assert got == pytest.approx(R3_MCD / 1e3 + rho * math.sin(math.radians(ILLUM_DEG)) / math.pi, rel=1e-3)
