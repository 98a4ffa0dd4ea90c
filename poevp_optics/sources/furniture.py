"""Road furniture: guard rails, delineator posts, road studs, signs, kerbs, tree lines and building
facades as parametric meshes (trimesh, manifold3d), one mesh per material, placed along a run.

[furniture.<id>] keys (`FurnitureSpec`; bound into the XML as `$furniture_<id>_*` by `xml_params`):

| key            | type   | unit | default      | meaning |
|----------------|--------|------|--------------|---------|
| kind           | str    | -    | "guard_rail" | what stands there (`FURNITURE_KINDS`): guard_rail, delineator, road_stud, sign, kerb, tree_line, building, asphalt |
| position_m     | [x, z] | m    | [-4, 10]     | the run's start on the road (world frame of sources/road.py: x to the left, z ahead) |
| heading_deg    | float  | deg  | 0            | the run's direction, yaw about +y: 0 runs along +z (away from our camera) |
| length_m       | float  | m    | -1           | the run's length from position_m (0: one item; -1: the kind's) |
| spacing_m      | float  | m    | -1           | distance between repeated items: posts, delineators, studs, trees, buildings (-1: the kind's) |
| height_m       | float  | m    | -1           | rail top, post, stud, sign face, kerb upstand, tree or building height (-1: the kind's) |
| width_m        | float  | m    | -1           | W-beam depth, post, stud, sign face, kerb, crown or building width (-1: the kind's) |
| depth_m        | float  | m    | -1           | building depth, footway width behind a kerb, post or blank thickness (-1: the kind's) |
| mount_height_m | float  | m    | -1           | a sign face's lower edge above the road (-1: the kind's) |
| road_side      | str    | -    | "left"       | the road's side of the run, looking along it: rails, kerbs and facades face it |
| legend         | str    | -    | ""           | a sign's text (its face texture: black on white sheeting, with a border) |
| lit_fraction   | float  | 1    | 0.3          | a building's share of lit windows (at least one lit and one dark per run) |
| seed           | int    | -    | 0            | draws of tree and building sizes, the lit windows and the asphalt's pattern |
| albedo         | float  | 1    | 0.09         | asphalt: the albedo map's mean (dry asphalt 0.05-0.18: sources/asphalt.py) |
| roughness      | float  | 1    | 0.8          | asphalt: the roughness map's mean (`principled` roughness) |
| tile_m         | float  | m    | 2.0          | asphalt: the side of the square one map covers (the maps tile the surface) |

Frame. The furniture frame has its origin at position_m on the road, +z along the run, +y up and
x to the run's left (as the world when heading_deg = 0); `$furniture_<id>_matrix` places it (a
yaw by heading_deg, then the position). Items that face traffic (delineator reflectors, studs'
lenses, sign faces) face back along the run (-z), toward traffic driving along it; the road side
(`road_side`) is where rails, kerbs and facades turn their fronts.

Kinds and their parts (one PLY each, `$furniture_<id>_<part>`), with the kind's defaults:

* guard_rail: `rail`, a W-beam (AASHTO M180 / EN 1317 W-beam: 310 mm high, 83 mm deep, 2.7 mm
  steel; its top 0.75 m above the road, as German RPS guard rails) extruded along the run, its
  two ridges toward the road; `posts`, 100 x 100 mm steel posts every 2.0 m (German
  "Schutzplanke": 2 m post spacing; the US 1.905 m) behind it. Material: galvanised steel
  (`roughconductor`).
* delineator: `posts`, white posts 1.0 m above the road, 100 mm wide and 120 mm deep (German
  "Leitpfosten", TL-Leitpfosten), every 50 m; `reflectors`, a 40 x 180 mm retroreflector on each
  post's traffic face, its top 70 mm below the post's (EN 12899-3 retroreflectors, sheeting of an
  EN 12899-1 class: render/materials/furniture_sheeting.py).
* road_stud: `bodies`, 100 x 100 x 18 mm studs (EN 1463-1 height class H1 <= 18 mm) every 12 m;
  `reflectors`, each stud's lens (STUD_LENS_M, 80 x 12 mm) on its traffic face,
  for a `retroreflective` BSDF with `en1463_1:PRP1`.
* sign: `post`, a 76 mm steel tube from the road to the face's top; `back`, the 3 mm aluminium
  blank behind the face; the face itself is a Mitsuba `rectangle` placed by
  `$furniture_<id>_face_matrix` (rotation 180 deg about x, as the vehicles' plates: texture row 0
  at the top, u to the face's left seen from the traffic, so its bitmap takes the plates'
  `to_uv` mirror) with `$furniture_<id>_face_texture`, the legend in black (0) on white (1) with a
  border: the `weight` of a `blendbsdf` of ink and sheeting. Default face 1.0 x 0.6 m, lower edge
  2.0 m above the road (VwV-StVO zu den Zeichen: lower edge normally 2.0 m; 2.2 m over footways).
* kerb: `kerb`, a kerb unit 150 mm wide (EN 1340 kerb units: 100-300 mm) with a 120 mm upstand
  along the run; `pavement`, a footway behind it 5 mm below the kerb's top, depth_m wide (default
  2.5 m; at least 0.01 m).
* tree_line: `trunks` (0.3 m thick) and `crowns` (icospheres) every 8 m, 8 m tall with 4 m
  crowns, each tree's height and crown drawn from the seed (+-15 %).
* building: `facades`, blocks along the run (spacing_m wide, default 12 m; 15 m tall +-20 % by the
  seed, 10 m deep), set back from the run's line on its far side; `lit_windows` and
  `dark_windows`, 1.2 x 1.5 m window quads (3.0 m storeys, 3.0 m bays) 5 mm proud of the facade
  facing the road: `area` emitters for the lit ones, glass or dark paint for the others.
* asphalt: no mesh; a carriageway surface for a Mitsuba `rectangle` placed by
  `$furniture_<id>_matrix` (width_m across the run line, default 7.0 m; length_m along it), with
  the seeded maps `$furniture_<id>_albedo_map` and `$furniture_<id>_roughness_map`
  (sources/asphalt.py, 16-bit PNG: read them `raw`) repeated `$furniture_<id>_tiles_u`
  times across and `$furniture_<id>_tiles_v` along (the bitmaps' `to_uv` scale).

Every solid part is closed (trimesh boxes, cylinders and icospheres; the W-beam a manifold3d
extrusion); the meshes are cached as PLY through core/cache.py (checksum and every vertex and face
checked before Mitsuba reads them), keyed by the kind's resolved parameters and MESH_VERSION.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from poevp_optics.core.params import param
from poevp_optics.core.registry import Registry

#: A road stud's reflector lens (width, height) in m: one face of a 100 x 100 x 18 mm stud
#: (EN 1463-1 class H1: <= 18 mm above the road), its lens 80 mm wide and 12 mm tall
#: (its R per lens area: render/materials/furniture_sheeting.py).
STUD_LENS_M = (0.080, 0.012)

#: Layout version (part of the cached files' names).
MESH_VERSION = 1
#: W-beam section (m): height, depth (back plane to ridges), steel thickness; guard rail posts.
W_BEAM_HEIGHT_M, W_BEAM_DEPTH_M, W_BEAM_STEEL_M = 0.310, 0.083, 0.0027
RAIL_POST_M = 0.10
#: Delineator reflector (width, height) and its top's drop below the post's top (m).
DELINEATOR_REFLECTOR_M, DELINEATOR_DROP_M = (0.040, 0.180), 0.070
#: Sign post diameter and the sign blank's thickness (m).
SIGN_POST_M, SIGN_BLANK_M = 0.076, 0.003
#: Trees: trunk diameter (m) and the seeded spread of sizes; buildings: storey and bay (m),
#: window (width, height) and the seeded spread of heights; window quads stand proud by (m).
TRUNK_M, TREE_SPREAD = 0.30, 0.15
STOREY_M, BAY_M, WINDOW_M, BUILDING_SPREAD, WINDOW_PROUD_M = 3.0, 3.0, (1.2, 1.5), 0.20, 0.005


class FurnitureError(ValueError):
    """A furniture entry that cannot be built; `key` names the FurnitureSpec key to change."""

    def __init__(self, key: str, msg: str):
        super().__init__(msg)
        self.key = key


@dataclass(frozen=True)
class KindDefaults:
    """A kind's defaults (m) and its parts (PLY meshes)."""

    length_m: float
    spacing_m: float
    height_m: float
    width_m: float
    depth_m: float
    mount_height_m: float
    parts: tuple[str, ...]


FURNITURE_KINDS = Registry("furniture kind")
FURNITURE_KINDS.register("guard_rail",
                         KindDefaults(60.0, 2.0, 0.75, W_BEAM_DEPTH_M, RAIL_POST_M, 0.0, ("rail", "posts")),
                         source="W-beam (AASHTO M180, EN 1317): 310 x 83 mm, top 0.75 m, posts every 2.0 m")
FURNITURE_KINDS.register("delineator", KindDefaults(0.0, 50.0, 1.0, 0.10, 0.12, 0.0, ("posts", "reflectors")),
                         source="German Leitpfosten (TL-Leitpfosten): 1.0 m, every 50 m; EN 12899-3 retroreflector")
FURNITURE_KINDS.register("road_stud", KindDefaults(0.0, 12.0, 0.018, 0.10, 0.10, 0.0, ("bodies", "reflectors")),
                         source="EN 1463-1 retroreflecting road stud, 100 x 100 x 18 mm (class H1)")
FURNITURE_KINDS.register("sign", KindDefaults(0.0, 0.0, 0.6, 1.0, SIGN_BLANK_M, 2.0, ("post", "back")),
                         source="EN 12899-1 fixed sign, retroreflective face; lower edge 2.0 m (VwV-StVO)")
FURNITURE_KINDS.register("kerb", KindDefaults(60.0, 0.0, 0.12, 0.15, 2.5, 0.0, ("kerb", "pavement")),
                         source="EN 1340 kerb unit, 150 mm wide, 120 mm upstand, footway behind")
FURNITURE_KINDS.register("tree_line", KindDefaults(60.0, 8.0, 8.0, 4.0, 0.0, 0.0, ("trunks", "crowns")),
                         source="street trees every 8 m, 8 m tall, 4 m crowns")
FURNITURE_KINDS.register("building", KindDefaults(60.0, 12.0, 15.0, 12.0, 10.0, 0.0,
                                                  ("facades", "lit_windows", "dark_windows")),
                         source="urban blocks 12 m wide, 15 m tall, 3.0 m storeys")
FURNITURE_KINDS.register("asphalt", KindDefaults(100.0, 0.0, 0.0, 7.0, 0.0, 0.0, ()),
                         source="dry dense asphalt, albedo 0.05-0.18 (US EPA Cool Pavements compendium, 2008)")

_SIZE_KEYS = ("length_m", "spacing_m", "height_m", "width_m", "depth_m", "mount_height_m")


def _override(default=-1.0, hi=1e4):
    return param(default, unset=-1.0, min=0.0, max=hi)


@dataclass(frozen=True)
class FurnitureSpec:
    """[furniture.<id>]: road furniture along a run (module docstring)."""

    kind: str = param("guard_rail", choices=FURNITURE_KINDS)
    position_m: tuple[float, float] = param((-4.0, 10.0), length=2, min=-1e4, max=1e4)
    heading_deg: float = param(0.0, min=-360.0, max=360.0)
    length_m: float = _override()
    spacing_m: float = _override()
    height_m: float = _override(hi=300.0)
    width_m: float = _override(hi=300.0)
    depth_m: float = _override(hi=300.0)
    mount_height_m: float = _override(hi=30.0)
    road_side: str = param("left", choices=("left", "right"))
    legend: str = param("")
    lit_fraction: float = param(0.3, min=0.0, max=1.0)
    seed: int = param(0, min=0)
    albedo: float = param(0.09, gt=0.0, lt=1.0)
    roughness: float = param(0.8, min=0.05, max=1.0)
    tile_m: float = param(2.0, min=0.25, max=16.0)


@dataclass(frozen=True)
class Furniture:
    """A FurnitureSpec with the kind's defaults filled in (m), checked."""

    kind: str
    length_m: float
    spacing_m: float
    height_m: float
    width_m: float
    depth_m: float
    mount_height_m: float
    side: float                 # +1: the road to the run's left (+x), -1: to its right
    legend: str
    lit_fraction: float
    seed: int
    albedo: float = 0.09
    roughness: float = 0.8
    tile_m: float = 2.0


def resolve(spec: FurnitureSpec) -> Furniture:
    """The spec with the kind's defaults, checked (FurnitureError names the key)."""
    d = FURNITURE_KINDS[spec.kind]
    vals = {k: (getattr(spec, k) if getattr(spec, k) != -1.0 else getattr(d, k)) for k in _SIZE_KEYS}
    f = Furniture(spec.kind, side=1.0 if spec.road_side == "left" else -1.0, legend=spec.legend,
                  lit_fraction=spec.lit_fraction, seed=spec.seed, albedo=spec.albedo, roughness=spec.roughness,
                  tile_m=spec.tile_m, **vals)
    check(f)
    return f


def check(f: Furniture) -> None:
    """Raise FurnitureError (naming the key) where the parts would not fit."""
    def need(ok, key, msg):
        if not ok:
            raise FurnitureError(key, msg)

    for k in ("height_m", "width_m") if f.kind != "asphalt" else ("width_m",):
        need(getattr(f, k) > 0, k, "must be > 0")
    repeated = f.kind in ("guard_rail", "delineator", "road_stud", "tree_line", "building")
    if repeated and f.length_m > 0:
        need(f.spacing_m > 0, "spacing_m", f"a {f.kind} run of length_m = {f.length_m:g} m needs spacing_m > 0")
        need(f.length_m / f.spacing_m <= 2000, "spacing_m", f"{f.length_m / f.spacing_m:.0f} items along the run "
             "(length_m / spacing_m) is more than 2000")
    if f.kind in ("guard_rail", "kerb", "asphalt"):
        need(f.length_m > 0, "length_m", f"a {f.kind} needs length_m > 0")
    if f.kind == "guard_rail":
        need(f.height_m > W_BEAM_HEIGHT_M + 0.05, "height_m", f"the rail's top ({f.height_m:g} m) must be above "
             f"the {W_BEAM_HEIGHT_M:g} m beam + 0.05 m")
        need(0.01 <= f.width_m <= 0.3, "width_m", "the W-beam's depth must be in [0.01, 0.3] m")
        need(f.depth_m > 0, "depth_m", "the posts' size must be > 0")
    if f.kind == "delineator":
        need(f.height_m >= DELINEATOR_REFLECTOR_M[1] + DELINEATOR_DROP_M + 0.05, "height_m",
             f"the post ({f.height_m:g} m) is too short for its {DELINEATOR_REFLECTOR_M[1]:g} m reflector")
        need(f.width_m >= DELINEATOR_REFLECTOR_M[0] + 0.01 and f.depth_m > 0, "width_m",
             f"the post must be wider than its {DELINEATOR_REFLECTOR_M[0]:g} m reflector (and depth_m > 0)")
    if f.kind == "road_stud":
        need(f.height_m >= STUD_LENS_M[1] + 0.002, "height_m", f"the stud ({f.height_m:g} m) is lower than its "
             f"{STUD_LENS_M[1]:g} m lens")
        need(f.width_m >= STUD_LENS_M[0] + 0.005 and f.depth_m > 0, "width_m",
             f"the stud must be wider than its {STUD_LENS_M[0]:g} m lens (and depth_m > 0)")
    if f.kind == "sign":
        need(f.length_m == 0, "length_m", "a sign is one item (length_m = 0)")
        need(f.mount_height_m > 0, "mount_height_m", "the face's lower edge must be above the road")
        need(f.depth_m > 0, "depth_m", "the blank's thickness must be > 0")
        for k in ("width_m", "height_m"):
            need(getattr(f, k) <= 8.0, k, f"a sign face of {getattr(f, k):g} m: at most 8 m (a large direction "
                 "sign; its texture is 400 px per m)")
    if f.kind == "tree_line":
        need(f.height_m * (1 - TREE_SPREAD) > f.width_m * (1 + TREE_SPREAD) * 0.5 + 0.5, "height_m",
             f"the trees ({f.height_m:g} m) are too short for their {f.width_m:g} m crowns")
    if f.kind == "building":
        need(f.height_m * (1 - BUILDING_SPREAD) >= STOREY_M, "height_m", f"buildings must hold a {STOREY_M:g} m "
             "storey at their lowest draw (height_m x 0.8)")
        need(f.width_m >= BAY_M and f.depth_m > 0, "width_m", f"a building must be >= one {BAY_M:g} m bay wide "
             "(and depth_m > 0)")
        need(f.spacing_m >= f.width_m or f.length_m == 0, "spacing_m",
             f"spacing_m ({f.spacing_m:g} m) is less than the buildings' width_m ({f.width_m:g} m): they overlap")


def positions_m(f: Furniture) -> np.ndarray:
    """Along-run positions (m) of the repeated items: 0, spacing, ... <= length (one at 0 when
    length_m = 0)."""
    if f.length_m <= 0 or f.spacing_m <= 0:
        return np.zeros(1)
    return np.arange(0.0, f.length_m + 1e-9, f.spacing_m)


# ------------------------------------------------------------------------------- meshes
def _box(x0, x1, y0, y1, z0, z1):
    import trimesh

    t = np.eye(4)
    t[:3, 3] = [(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2]
    return trimesh.creation.box(extents=(x1 - x0, y1 - y0, z1 - z0), transform=t)


def _quads(quads, normal_sign_z=None, normal_sign_x=None):
    """Open rectangles (two triangles each), given as (centre, half-extents) in a plane: facing
    -z / +z (normal_sign_z) at (x, y, z) with half sizes (hx, hy), or facing +-x (normal_sign_x)
    with half sizes (hz, hy)."""
    import trimesh

    verts, faces = [], []
    for (cx, cy, cz), (ha, hy) in quads:
        k = len(verts)
        if normal_sign_z is not None:
            verts += [(cx - ha, cy - hy, cz), (cx + ha, cy - hy, cz), (cx + ha, cy + hy, cz), (cx - ha, cy + hy, cz)]
            front = normal_sign_z > 0          # (v1 - v0) x (v2 - v0) = +x cross +y = +z
        else:
            verts += [(cx, cy - hy, cz - ha), (cx, cy - hy, cz + ha), (cx, cy + hy, cz + ha), (cx, cy + hy, cz - ha)]
            front = normal_sign_x < 0          # +z cross +y = -x
        faces += [(k, k + 1, k + 2), (k, k + 2, k + 3)] if front else [(k, k + 2, k + 1), (k, k + 3, k + 2)]
    return trimesh.Trimesh(np.asarray(verts, np.float64), np.asarray(faces, np.int64), process=False)


def _concat(meshes):
    import trimesh

    return trimesh.util.concatenate(meshes)


def w_beam_profile(depth_m: float, side: float) -> np.ndarray:
    """The W-beam's section as a closed polygon (x, y) in m, counter-clockwise: the centre line
    x = depth sin^2(2 pi s), y = s x W_BEAM_HEIGHT_M (s in [0, 1]: a W with its two ridges toward the
    road, +x for side +1, at s = 1/4 and 3/4), offset by half the steel's thickness on each side
    along the line's normal (its smallest radius of curvature, 15 mm at the ridges, is far above
    the 1.35 mm offset, so the offsets do not fold)."""
    s = np.linspace(0.0, 1.0, 97)
    x = depth_m * np.sin(2 * np.pi * s) ** 2
    y = s * W_BEAM_HEIGHT_M
    dx = depth_m * 2 * np.pi * np.sin(4 * np.pi * s)          # d/ds of the centre line
    dy = np.full_like(s, W_BEAM_HEIGHT_M)
    norm = np.hypot(dx, dy)
    nx, ny = dy / norm, -dx / norm                            # the tangent turned clockwise: toward +x
    t = W_BEAM_STEEL_M / 2
    front = np.stack([x + t * nx, y + t * ny], 1)
    back = np.stack([x - t * nx, y - t * ny], 1)[::-1]
    poly = np.concatenate([front, back])
    poly[:, 0] *= side
    if side < 0:
        poly = poly[::-1]
    return poly


def _rail(f: Furniture):
    import trimesh
    from manifold3d import CrossSection, Manifold

    sec = w_beam_profile(f.width_m, f.side)
    m = Manifold.extrude(CrossSection([list(map(tuple, sec))]), f.length_m)
    m = m.translate((f.side * (W_BEAM_STEEL_M / 2 + 0.002), f.height_m - W_BEAM_HEIGHT_M, 0.0))
    out = m.to_mesh()
    return trimesh.Trimesh(np.asarray(out.vert_properties, float)[:, :3], np.asarray(out.tri_verts, np.int64),
                           process=False)


def furniture_meshes(f: Furniture) -> dict:
    """{part: trimesh.Trimesh} in the furniture frame (module docstring)."""
    import trimesh

    check(f)
    zs = positions_m(f)
    rng = np.random.default_rng(f.seed)
    s = f.side
    if f.kind == "guard_rail":
        p = f.depth_m / 2                        # posts behind the run line x = 0, the beam in front
        x0, x1 = sorted((0.0, -s * f.depth_m))
        posts = [_box(x0, x1, 0.0, f.height_m - 0.02, z - p, z + p) for z in zs]
        return {"rail": _rail(f), "posts": _concat(posts)}
    if f.kind == "delineator":
        w, d = f.width_m / 2, f.depth_m / 2
        posts = [_box(-w, w, 0.0, f.height_m, z - d, z + d) for z in zs]
        rw, rh = DELINEATOR_REFLECTOR_M
        yc = f.height_m - DELINEATOR_DROP_M - rh / 2
        refl = _quads([((0.0, yc, z - d - 0.001), (rw / 2, rh / 2)) for z in zs], normal_sign_z=-1)
        return {"posts": _concat(posts), "reflectors": refl}
    if f.kind == "road_stud":
        w, d = f.width_m / 2, f.depth_m / 2
        bodies = [_box(-w, w, 0.0, f.height_m, z - d, z + d) for z in zs]
        lw, lh = STUD_LENS_M
        yc = f.height_m / 2
        refl = _quads([((0.0, yc, z - d - 0.001), (lw / 2, lh / 2)) for z in zs], normal_sign_z=-1)
        return {"bodies": _concat(bodies), "reflectors": refl}
    if f.kind == "sign":
        top = f.mount_height_m + f.height_m
        post = trimesh.creation.cylinder(radius=SIGN_POST_M / 2, height=top, sections=24)
        post.apply_translation((0.0, 0.0, 0.0))
        post.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, (1, 0, 0)))   # z axis -> y
        post.apply_translation((0.0, top / 2, SIGN_POST_M / 2 + f.depth_m + 0.002))
        back = _box(-f.width_m / 2, f.width_m / 2, f.mount_height_m, top, 0.0005, 0.0005 + f.depth_m)
        return {"post": post, "back": back}
    if f.kind == "kerb":
        kerb = _box(-s * f.width_m if s > 0 else 0.0, 0.0 if s > 0 else f.width_m, 0.0, f.height_m, 0.0, f.length_m)
        out = {"kerb": kerb}
        x0, x1 = sorted((-s * f.width_m, -s * (f.width_m + max(f.depth_m, 0.01))))
        out["pavement"] = _box(x0, x1, 0.0, f.height_m - 0.005, 0.0, f.length_m)
        return out
    if f.kind == "tree_line":
        trunks, crowns = [], []
        for z in zs:
            k = 1 + TREE_SPREAD * (2 * rng.random() - 1)
            h, r = f.height_m * k, f.width_m * k / 2
            trunk = trimesh.creation.cylinder(radius=TRUNK_M / 2, height=h - r, sections=12)
            trunk.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, (1, 0, 0)))
            trunk.apply_translation((0.0, (h - r) / 2, z))
            crown = trimesh.creation.icosphere(subdivisions=2, radius=r)
            crown.apply_translation((0.0, h - r, z))
            trunks.append(trunk)
            crowns.append(crown)
        return {"trunks": _concat(trunks), "crowns": _concat(crowns)}
    if f.kind == "building":
        facades, windows = [], []
        for z in zs:
            h = f.height_m * (1 + BUILDING_SPREAD * (2 * rng.random() - 1))
            x0, x1 = sorted((0.0, -s * f.depth_m))
            facades.append(_box(x0, x1, 0.0, h, z, z + f.width_m))
            n_bays, n_storeys = int(f.width_m // BAY_M), int(h // STOREY_M)
            z0 = z + (f.width_m - n_bays * BAY_M) / 2
            for i in range(n_storeys):
                for j in range(n_bays):
                    windows.append(((s * WINDOW_PROUD_M, (i + 0.55) * STOREY_M, z0 + (j + 0.5) * BAY_M),
                                    (WINDOW_M[0] / 2, WINDOW_M[1] / 2)))
        n = len(windows)
        lit = rng.random(n) < f.lit_fraction
        if n >= 2:                                   # at least one of each: neither part is empty
            order = rng.permutation(n)
            lit[order[0]], lit[order[1]] = True, False
        lit_q = [w for w, on in zip(windows, lit) if on]
        dark_q = [w for w, on in zip(windows, lit) if not on] or lit_q
        return {"facades": _concat(facades), "lit_windows": _quads(lit_q, normal_sign_x=s),
                "dark_windows": _quads(dark_q, normal_sign_x=s)}
    if f.kind == "asphalt":
        return {}
    raise FurnitureError("kind", f"unknown kind {f.kind!r}")


def face_centre_m(f: Furniture) -> np.ndarray:
    """A sign face's centre in the furniture frame (m): on the blank's traffic side (-z)."""
    return np.array([0.0, f.mount_height_m + f.height_m / 2, 0.0])


def to_world(spec: FurnitureSpec) -> np.ndarray:
    """4x4 furniture frame -> world: yaw by heading_deg about +y, then the position."""
    a = math.radians(spec.heading_deg)
    c, s = math.cos(a), math.sin(a)
    m = np.eye(4)
    m[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    m[0, 3], m[2, 3] = spec.position_m
    return m


def _matrix(m: np.ndarray) -> str:
    return " ".join(f"{float(v):.9g}" for v in np.asarray(m).ravel())


# ------------------------------------------------------------------------------- cache
def _ply_problem(path: Path, mesh) -> str | None:
    """Why the PLY at `path` is not `mesh` (vertex and face arrays, exactly), or None."""
    import trimesh

    got = trimesh.load(str(path), file_type="ply", process=False, force="mesh")
    if got.vertices.shape != mesh.vertices.shape or got.faces.shape != mesh.faces.shape:
        return (f"{len(got.vertices)} vertices and {len(got.faces)} faces, not {len(mesh.vertices)} and "
                f"{len(mesh.faces)}")
    if not np.array_equal(np.asarray(got.vertices, np.float32), np.asarray(mesh.vertices, np.float32)):
        return "vertices differ from the furniture mesh's"
    if not np.array_equal(got.faces, mesh.faces):
        return "faces differ from the furniture mesh's"
    return None


def cached_furniture_meshes(f: Furniture) -> dict[str, Path]:
    """{part: PLY path} in the package cache (core/cache.py), keyed by the resolved parameters."""
    import trimesh

    from poevp_optics.core.cache import cache_file, cached_path, json_digest

    key = json_digest({"f": dataclasses.asdict(f), "v": MESH_VERSION}, sort_keys=True)
    out = {}
    for part, mesh in furniture_meshes(f).items():
        mesh = trimesh.Trimesh(np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.int64), process=False)
        path = cache_file("meshes", f"furniture_{f.kind}_{part}_{key}.ply")
        out[part] = cached_path(path, lambda tmp, m=mesh: Path(tmp).write_bytes(m.export(file_type="ply")),
                                lambda p, m=mesh: _ply_problem(p, m))
    return out


# ------------------------------------------------------------------------------- sign face
#: Sign face texture resolution (px per m), the border's inset and stroke (m).
FACE_PX_PER_M, BORDER_INSET_M, BORDER_M = 400, 0.015, 0.012


def face_texture(legend: str, width_m: float, height_m: float) -> np.ndarray:
    """uint8 (H, W): 255 where the white sheeting shows, 0 where the black ink is: a border
    inset BORDER_INSET_M, BORDER_M wide, and the legend centred, its cap height at most 40 % of
    the face (the plates' font, sources/plates.py)."""
    from PIL import Image, ImageDraw

    from poevp_optics.sources.plates import plate_font

    w, h = max(8, round(width_m * FACE_PX_PER_M)), max(8, round(height_m * FACE_PX_PER_M))
    img = Image.new("L", (w, h), 255)
    draw = ImageDraw.Draw(img)
    inset, stroke = round(BORDER_INSET_M * FACE_PX_PER_M), max(1, round(BORDER_M * FACE_PX_PER_M))
    draw.rectangle([inset, inset, w - 1 - inset, h - 1 - inset], outline=0, width=stroke)
    if legend:
        size = 0.4 * h
        font = plate_font(size)
        box = draw.textbbox((0, 0), legend, font=font)
        room = w - 2 * (inset + stroke) - 0.1 * w
        if box[2] - box[0] > room:
            font = plate_font(size * room / (box[2] - box[0]))
            box = draw.textbbox((0, 0), legend, font=font)
        draw.text(((w - (box[2] - box[0])) / 2 - box[0], (h - (box[3] - box[1])) / 2 - box[1]), legend, fill=0,
                  font=font)
    return np.asarray(img, np.uint8)


def cached_face_path(legend: str, width_m: float, height_m: float) -> Path:
    """The face texture PNG in the cache (checksum and pixels checked before use)."""
    from poevp_optics.core.cache import cache_file, cached_png, digest
    from poevp_optics.sources.plates import plate_font_sha256

    tex = face_texture(legend, width_m, height_m)
    key = f"{legend}|{width_m:.6g}|{height_m:.6g}|{FACE_PX_PER_M}|{plate_font_sha256()[:16]}|v1"
    return cached_png(cache_file("signs", f"sign_{digest(key)}.png"), tex, f"the sign face {legend!r}")


# ------------------------------------------------------------------------------- XML
def xml_params(ident: str, spec: FurnitureSpec) -> dict[str, str]:
    """`$furniture_<ident>_*`: each part's PLY, the matrix, and for a sign its face's rectangle
    matrix and texture."""
    f = resolve(spec)
    world = to_world(spec)
    pre = f"furniture_{ident}"
    out = {f"{pre}_{part}": str(p) for part, p in cached_furniture_meshes(f).items()}
    out[f"{pre}_matrix"] = _matrix(world)
    if f.kind == "sign":
        face = np.eye(4)
        face[:3, :3] = np.diag([f.width_m / 2, -f.height_m / 2, -1.0])    # 180 deg about x, scaled
        face[:3, 3] = face_centre_m(f)
        out[f"{pre}_face_matrix"] = _matrix(world @ face)
        out[f"{pre}_face_texture"] = str(cached_face_path(f.legend, f.width_m, f.height_m))
    if f.kind == "asphalt":
        from poevp_optics.sources.asphalt import cached_asphalt_maps

        # rectangle [-1, 1]^2 (normal +z) -> width x length on the road, normal +y, from z = 0 on
        surface = np.eye(4)
        rot = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])        # 90 deg about x: +z -> +y
        surface[:3, :3] = rot @ np.diag([f.width_m / 2, f.length_m / 2, 1])
        surface[2, 3] = f.length_m / 2
        out[f"{pre}_matrix"] = _matrix(world @ surface)
        albedo, rough = cached_asphalt_maps(f.albedo, f.roughness, f.tile_m, f.seed)
        out[f"{pre}_albedo_map"], out[f"{pre}_roughness_map"] = str(albedo), str(rough)
        out[f"{pre}_tiles_u"] = f"{f.width_m / f.tile_m:.9g}"
        out[f"{pre}_tiles_v"] = f"{f.length_m / f.tile_m:.9g}"
    return out


def required_params(ident: str, spec: FurnitureSpec) -> list[str]:
    """The XML parameters a [furniture.<ident>] entry binds (each must be declared)."""
    pre = f"furniture_{ident}"
    names = [f"{pre}_{p}" for p in FURNITURE_KINDS[spec.kind].parts] + [f"{pre}_matrix"]
    if spec.kind == "sign":
        names += [f"{pre}_face_matrix", f"{pre}_face_texture"]
    if spec.kind == "asphalt":
        names += [f"{pre}_albedo_map", f"{pre}_roughness_map", f"{pre}_tiles_u", f"{pre}_tiles_v"]
    return names
