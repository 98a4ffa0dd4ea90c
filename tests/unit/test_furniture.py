"""Road furniture (sources/furniture.py): the meshes have the sizes their keys and the standards
give, every solid part is closed, the XML parameters are bound, bad values are one line naming the
key; the asphalt maps (sources/asphalt.py) have their stated mean."""

from __future__ import annotations

import math

import numpy as np
import pytest

from poevp_optics.core.exceptions import SceneError
from poevp_optics.render.renderer import plan_spectra
from poevp_optics.scene.load import load_scene
from poevp_optics.sources.furniture import FurnitureSpec, furniture_meshes, resolve, to_world, xml_params

XML = """\
<scene version="3.0.0">
    {defaults}
    <sensor type="perspective"><float name="fov" value="10"/></sensor>
</scene>
"""


def _meshes(**kw):
    return furniture_meshes(resolve(FurnitureSpec(**kw)))


def test_guard_rail_is_a_w_beam_on_posts():
    m = _meshes(kind="guard_rail", length_m=20.0, spacing_m=2.0, road_side="left")
    rail, posts = m["rail"], m["posts"]
    assert rail.is_watertight and posts.is_watertight
    (x0, y0, z0), (x1, y1, z1) = rail.bounds
    # AASHTO M180 W-beam: 310 mm high, 83 mm deep (+ the 2.7 mm steel), its top at 0.75 m
    assert y1 == pytest.approx(0.75, abs=1e-6) and y1 - y0 == pytest.approx(0.310, abs=1e-6)
    assert x1 - x0 == pytest.approx(0.083 + 0.0027, abs=2e-4) and x0 > 0     # ridges toward the road (+x)
    assert (z0, z1) == pytest.approx((0.0, 20.0))
    # the section's area: two ridges of a sin^2 profile: length of the centre line x steel thickness
    s = np.linspace(0, 1, 20001)
    x, y = 0.083 * np.sin(2 * np.pi * s) ** 2, 0.310 * s
    arc = np.sum(np.hypot(np.diff(x), np.diff(y)))
    assert rail.volume / 20.0 == pytest.approx(arc * 0.0027, rel=0.02)
    assert len(posts.split(only_watertight=True)) == 11                       # 0, 2, ..., 20 m
    assert posts.bounds[1][0] <= 0.0                                          # behind the beam
    right = _meshes(kind="guard_rail", length_m=20.0, road_side="right")["rail"]
    assert right.bounds[1][0] < 0 and right.is_watertight


def test_delineator_stud_and_sign_sizes():
    d = _meshes(kind="delineator", length_m=100.0)
    assert len(d["posts"].split(only_watertight=True)) == 3                  # every 50 m
    assert d["posts"].bounds[1][1] == pytest.approx(1.0)
    refl = d["reflectors"]
    assert refl.area == pytest.approx(3 * 0.040 * 0.180, rel=1e-9)
    assert np.allclose(refl.face_normals, [0, 0, -1])                         # toward the traffic
    stud = _meshes(kind="road_stud")
    assert stud["bodies"].is_watertight and stud["bodies"].bounds[1][1] == pytest.approx(0.018)
    assert stud["reflectors"].area == pytest.approx(0.080 * 0.012, rel=1e-9)
    sign = _meshes(kind="sign", width_m=1.2, height_m=0.8, mount_height_m=2.2)
    assert sign["post"].is_watertight and sign["back"].is_watertight
    assert sign["back"].bounds[:, 1] == pytest.approx([2.2, 3.0])
    assert sign["back"].bounds[:, 0] == pytest.approx([-0.6, 0.6])


def test_sign_face_matrix_and_texture():
    spec = FurnitureSpec(kind="sign", position_m=(-5.0, 30.0), heading_deg=0.0, legend="STOP")
    p = xml_params("s", spec)
    face = np.array(p["furniture_s_face_matrix"].split(), float).reshape(4, 4)
    corners = face @ np.array([[-1, -1, 0, 1], [1, 1, 0, 1]], float).T
    assert np.ptp(corners[0]) == pytest.approx(1.0) and np.ptp(corners[1]) == pytest.approx(0.6)
    assert face[:3, 2] == pytest.approx([0, 0, -1])                           # the face's normal toward us
    assert face[:3, 3] == pytest.approx([-5.0, 2.3, 30.0])
    from poevp_optics.core.io import read_png

    tex = read_png(p["furniture_s_face_texture"])
    assert tex.shape == (240, 400) and tex.dtype == np.uint8
    ink = tex < 128
    assert 0.05 < ink.mean() < 0.5 and not ink[120, 5] and ink[8, 200]         # border ink, white margin


def test_buildings_trees_kerb():
    b = _meshes(kind="building", length_m=24.0, spacing_m=12.0, lit_fraction=0.5, seed=3)
    assert b["facades"].is_watertight and len(b["facades"].split(only_watertight=True)) == 3
    n_lit, n_dark = len(b["lit_windows"].faces) // 2, len(b["dark_windows"].faces) // 2
    assert n_lit >= 1 and n_dark >= 1 and np.allclose(b["lit_windows"].face_normals, [1, 0, 0])
    h = b["facades"].bounds[1][1]
    assert 15 * 0.8 <= h <= 15 * 1.2
    t = _meshes(kind="tree_line", length_m=16.0, seed=1)
    assert t["crowns"].is_watertight and len(t["trunks"].split(only_watertight=True)) == 3
    k = _meshes(kind="kerb", length_m=30.0, road_side="right")
    assert k["kerb"].bounds[:, 0] == pytest.approx([0.0, 0.15]) and k["kerb"].bounds[1][1] == pytest.approx(0.12)


def test_world_matrix_turns_the_run():
    m = to_world(FurnitureSpec(kind="kerb", position_m=(2.0, 5.0), heading_deg=90.0))
    # heading 90 deg: the run's +z turns toward world +x
    assert m[:3, :3] @ np.array([0, 0, 1.0]) == pytest.approx([1, 0, 0], abs=1e-12)
    assert m[:3, 3] == pytest.approx([2.0, 0.0, 5.0])


def test_asphalt_maps_have_the_stated_mean():
    from poevp_optics.core.io import read_png

    p = xml_params("road", FurnitureSpec(kind="asphalt", position_m=(0.0, 0.0), length_m=40.0, width_m=7.0,
                                                    albedo=0.11, seed=4))
    a = read_png(p["furniture_road_albedo_map"]).astype(np.float64) / 65535
    r = read_png(p["furniture_road_roughness_map"]).astype(np.float64) / 65535
    # the maps are scaled to their means before rounding to 1/65535: the mean keeps them to < 1e-5
    assert a.mean() == pytest.approx(0.11, abs=1e-5) and r.mean() == pytest.approx(0.8, abs=1e-5)
    assert a.std() > 0.01 and 0 <= a.min() and a.max() <= 1 and 0.05 - 1e-5 <= r.min()
    # it tiles: opposite edges continue one another (the noise is periodic), no seam larger than
    # the map's own neighbour differences
    seam = np.abs(a[:, 0] - a[:, -1]).mean()
    inner = np.abs(np.diff(a, axis=1)).mean()
    assert seam < 2 * inner
    assert float(p["furniture_road_tiles_u"]) == pytest.approx(3.5) and float(p["furniture_road_tiles_v"]) == 20
    surface = np.array(p["furniture_road_matrix"].split(), float).reshape(4, 4)
    assert surface[:3, 2] == pytest.approx([0, 1, 0])                         # normal up
    corners = surface @ np.array([[-1, -1, 0, 1], [1, 1, 0, 1]], float).T
    assert sorted(corners[2]) == pytest.approx([0.0, 40.0]) and sorted(corners[0]) == pytest.approx([-3.5, 3.5])


@pytest.mark.parametrize("toml,key", [
    ('kind = "sign"\nlength_m = 5.0', "furniture.x.length_m"),
    ('kind = "sign"\nwidth_m = 40.0', "furniture.x.width_m"),
    ('kind = "guard_rail"\nheight_m = 0.2', "furniture.x.height_m"),
    ('kind = "building"\nwidth_m = 20.0\nspacing_m = 10.0', "furniture.x.spacing_m"),
    ('kind = "bench"', "furniture.x.kind"),
    ('kind = "delineator"\nheight_m = 0.1', "furniture.x.height_m"),
    ('kind = "asphalt"\nalbedo = 1.5', "furniture.x.albedo"),
    ('kind = "kerb"\nroad_side = "up"', "furniture.x.road_side"),
])
def test_bad_furniture_values_name_their_key(write_scene, toml, key):
    folder = write_scene(f"[furniture.x]\n{toml}\n", XML.format(defaults=""), name="bad")
    with pytest.raises(SceneError) as e:
        load_scene(folder)
    assert key in str(e.value) and "\n" not in str(e.value), str(e.value)


def test_undeclared_furniture_parameters_are_one_line(write_scene):
    folder = write_scene('[furniture.rail]\nkind = "guard_rail"\n', XML.format(defaults=""))
    with pytest.raises(SceneError) as e:
        plan_spectra(load_scene(folder).resolved.render)
    msg = str(e.value)
    assert "furniture.rail" in msg and "furniture_rail_rail" in msg and "\n" not in msg, msg
    names = ["furniture_rail_rail", "furniture_rail_posts", "furniture_rail_matrix"]
    folder = write_scene('[furniture.rail]\nkind = "guard_rail"\n',
                         XML.format(defaults="\n".join(f'<default name="{n}" value=""/>' for n in names)), name="ok")
    params = plan_spectra(load_scene(folder).resolved.render).xml_params
    assert set(names) <= set(params) and params["furniture_rail_rail"].endswith(".ply")
    assert math.isfinite(float(params["furniture_rail_matrix"].split()[3]))
