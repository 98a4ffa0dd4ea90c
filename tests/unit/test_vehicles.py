"""Parametric vehicles (sources/vehicles.py): closed parts, dimensions equal to the parameters,
the plate recess and frame at the plate format's size, and the [vehicle.<id>] scene keys."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from poevp_optics.sources.vehicles import (PLATE_FORMATS, VEHICLE_KINDS, VehicleShapeError, VehicleSpec,
                                           cached_vehicle_meshes, shape_of, vehicle_meshes, xml_params)

#: plate sizes (m) written out here: EU 520 x 110 mm, US 12 x 6 in
PLATES = {"eu": (0.520, 0.110), "us": (12 * 0.0254, 6 * 0.0254)}
MARGIN, DEPTH = 0.020, 0.030     # recess margin per side and depth (module docstring)


@pytest.mark.parametrize("kind", list(VEHICLE_KINDS))
def test_parts_are_closed_and_the_vehicle_has_its_dimensions(kind):
    import trimesh

    s = VEHICLE_KINDS[kind]
    parts = vehicle_meshes(s)
    for name in ("body", "glass", "trim", "wheels"):
        m = parts[name]
        assert m.is_watertight and m.is_winding_consistent and m.volume > 0, (kind, name)
    for name in ("tail_lamps", "brake_lamps", "head_lamps"):
        m = parts[name]
        assert len(m.faces) == 4 and not m.is_watertight       # two open quads, facing out
        normal_z = m.face_normals[:, 2]
        assert np.all(normal_z > 0.999) if name == "head_lamps" else np.all(normal_z < -0.999)
    allm = trimesh.util.concatenate(list(parts.values()))
    np.testing.assert_allclose(allm.bounds, [[-s.width_m / 2, 0.0, 0.0], [s.width_m / 2, s.height_m, s.length_m]],
                               atol=2e-6)
    # four wheels of the given radius, on the axles, touching the road
    wheels = parts["wheels"].split(only_watertight=True)
    assert len(wheels) == 4
    axles = sorted({round(float(w.bounds.mean(axis=0)[2]), 5) for w in wheels})
    np.testing.assert_allclose(axles, [s.rear_overhang_m, s.length_m - s.front_overhang_m], atol=1e-5)
    for w in wheels:
        np.testing.assert_allclose(w.bounds[:, 1], [0.0, 2 * s.wheel_radius_m], atol=2e-6)


@pytest.mark.parametrize("fmt", ["eu", "us"])
def test_plate_recess_frame_and_plate_have_the_format_size(fmt):
    spec = VehicleSpec(kind="sedan", plate_format=fmt, heading_deg=0.0, position_m=(0.0, 0.0))
    s = shape_of(spec)
    pw, ph = PLATES[fmt]
    assert PLATE_FORMATS[fmt] == pytest.approx((pw, ph), abs=1e-4)
    pw, ph = PLATE_FORMATS[fmt]
    parts = vehicle_meshes(s, fmt)
    body = parts["body"]
    # the recess floor: rear-facing body faces at z = DEPTH
    floor = body.faces[(np.abs(body.triangles_center[:, 2] - DEPTH) < 1e-6) & (body.face_normals[:, 2] < -0.999)]
    v = body.vertices[np.unique(floor)]
    np.testing.assert_allclose(v[:, 0].max() - v[:, 0].min(), pw + 2 * MARGIN, atol=2e-6)
    np.testing.assert_allclose(v[:, 1].max() - v[:, 1].min(), ph + 2 * MARGIN, atol=2e-6)
    np.testing.assert_allclose((v[:, 1].max() + v[:, 1].min()) / 2, s.plate_height_m, atol=2e-6)
    # the frame's opening is the plate: the ring's inner edges at +-pw/2, plate_height +- ph/2
    trim = parts["trim"]
    ring = trim.vertices[(trim.vertices[:, 2] > DEPTH - 0.007) & (trim.vertices[:, 2] < DEPTH + 1e-6)]
    xs, ys = np.unique(np.round(np.abs(ring[:, 0]), 6)), np.unique(np.round(ring[:, 1] - s.plate_height_m, 6))
    assert xs.min() == pytest.approx(pw / 2, abs=2e-6) and np.abs(ys).min() == pytest.approx(ph / 2, abs=2e-6)
    # the plate rectangle ([-1, 1]^2, normal +z) placed by its matrix: the format's size, facing back
    m = np.array([float(x) for x in xml_params("car", spec)["vehicle_car_plate_matrix"].split()]).reshape(4, 4)
    corners = (m @ np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [1, 1, 0, 1]]).T).T[:, :3]
    assert np.linalg.norm(corners[1] - corners[0]) == pytest.approx(pw, abs=1e-7)
    assert np.linalg.norm(corners[2] - corners[1]) == pytest.approx(ph, abs=1e-7)
    assert np.linalg.det(m[:3, :3]) > 0        # a rotation: geometric and shading normals agree (media)
    normal = m[:3, :3] @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(normal / np.linalg.norm(normal), [0, 0, -1], atol=1e-9)
    assert corners[:, 2] == pytest.approx(DEPTH - 0.002)        # 2 mm proud of the recess floor


def test_overrides_change_the_shape_and_bad_shapes_name_their_key():
    spec = VehicleSpec(kind="suv", length_m=5.0, height_m=1.8, cabin_height_m=-1.0)
    s = shape_of(spec)
    assert (s.length_m, s.height_m) == (5.0, 1.8)
    bounds = np.vstack([m.bounds for m in vehicle_meshes(s).values()])
    assert bounds[:, 2].max() == pytest.approx(5.0, abs=2e-6) and bounds[:, 1].max() == pytest.approx(1.8, abs=2e-6)
    for over, key in (({"front_overhang_m": 0.2}, "front_overhang_m"), ({"bonnet_length_m": 4.8}, "bonnet_length_m"),
                      ({"plate_height_m": 1.5}, "plate_height_m"), ({"roof_front_m": 0.1}, "roof_rear_m")):
        with pytest.raises(VehicleShapeError) as e:
            shape_of(dataclasses.replace(spec, **over))
        assert e.value.key == key, (over, e.value.key, str(e.value))


def test_cached_meshes_load_in_mitsuba():
    import mitsuba as mi

    from poevp_optics.core import runtime

    runtime.set_variant("llvm_ad_mono")
    s = VEHICLE_KINDS["van"]
    paths = cached_vehicle_meshes(s)
    assert cached_vehicle_meshes(s) == paths                     # the same files on a second call
    meshes = vehicle_meshes(s)
    for part, p in paths.items():
        shape = mi.load_dict({"type": "ply", "filename": str(p)})
        assert shape.face_count() == len(meshes[part].faces), part


VEHICLE_XML = """\
<scene version="3.0.0">
    <default name="vehicle_car_body" value=""/>
    {extra}
    <sensor type="perspective"><float name="fov" value="10"/></sensor>
</scene>
"""


def test_vehicle_scene_keys_are_checked(write_scene):
    from poevp_optics.core.exceptions import SceneError
    from poevp_optics.render.renderer import plan_spectra
    from poevp_optics.scene.load import load_scene

    bad = [("kind = \"tram\"", "vehicle.car.kind"), ("position_m = [1.0]", "vehicle.car.position_m"),
           ("front_overhang_m = 0.1", "vehicle.car.front_overhang_m"), ("plate_format = \"jp\"", "vehicle.car.plate_format")]
    for i, (line, key) in enumerate(bad):
        folder = write_scene(f"[vehicle.car]\n{line}\n", VEHICLE_XML.format(extra=""), name=f"bad{i}")
        with pytest.raises(SceneError) as e:
            load_scene(folder)
        assert key in str(e.value) and "\n" not in str(e.value), str(e.value)
    # an XML that does not declare the vehicle's parameters: one line naming the key
    folder = write_scene("[vehicle.car]\nkind = \"sedan\"\n", VEHICLE_XML.format(extra=""), name="undeclared")
    with pytest.raises(SceneError) as e:
        plan_spectra(load_scene(folder).resolved.render)
    assert "vehicle.car" in str(e.value) and "vehicle_car_" in str(e.value) and "\n" not in str(e.value)
