"""Parametric vehicles: sedan, SUV, van, truck and bus meshes, one mesh per material, with a
registration plate in its recess and frame at the plate format's real size.

[vehicle.<id>] keys (`VehicleSpec`; bound into the XML as `$vehicle_<id>_*` by `xml_params`):

| key                | type    | unit | default | meaning |
|--------------------|---------|------|---------|---------|
| kind               | str     | -    | "sedan" | body preset (`VEHICLE_KINDS`); the shape keys below override it |
| position_m         | [x, z]  | m    | [0, 20] | the rear face's centre on the road at t = 0 (world frame of sources/road.py) |
| heading_deg        | float   | deg  | 0       | yaw about +y: 0 drives along +z (its rear toward our camera), 180 toward us |
| plate_text         | str     | -    | ""      | the rear plate's characters; "" keeps the XML's own plate texture |
| plate_format       | str     | -    | "eu"    | plate size (`PLATE_FORMATS`): eu 520 x 110 mm, us 305 x 152 mm |
| plate_height_m     | float   | m    | -1      | the plate centre's height above the road (-1: the kind's) |
| length_m           | float   | m    | -1      | overall length, bumper to bumper (-1: the kind's) |
| width_m            | float   | m    | -1      | overall width (no mirrors) (-1: the kind's) |
| height_m           | float   | m    | -1      | overall height (roof, or the cargo box) (-1: the kind's) |
| ground_clearance_m | float   | m    | -1      | underside of the body above the road (-1: the kind's) |
| front_overhang_m   | float   | m    | -1      | front face to the front axle (-1: the kind's) |
| rear_overhang_m    | float   | m    | -1      | rear face to the rear axle (-1: the kind's) |
| wheel_radius_m     | float   | m    | -1      | tyre radius (the wheels touch the road) (-1: the kind's) |
| wheel_width_m      | float   | m    | -1      | tyre width (-1: the kind's) |
| nose_height_m      | float   | m    | -1      | top of the front face (the bonnet's leading edge) (-1: the kind's) |
| bonnet_length_m    | float   | m    | -1      | front face to the windscreen's base (-1: the kind's) |
| beltline_m         | float   | m    | -1      | height of the window sills (-1: the kind's) |
| boot_length_m      | float   | m    | -1      | rear face to the rear window's base (0: hatchback, van, bus) (-1: the kind's) |
| tail_height_m      | float   | m    | -1      | top of the rear face (-1: the kind's) |
| roof_rear_m        | float   | m    | -1      | the flat roof's rear end, from the rear face (-1: the kind's) |
| roof_front_m       | float   | m    | -1      | the flat roof's front end, from the rear face (-1: the kind's) |
| cabin_height_m     | float   | m    | -1      | the cab's roof height where a cargo box is taller (trucks) (-1: the kind's) |
| cargo_length_m     | float   | m    | -1      | length of a box body on the rear deck (0: none) (-1: the kind's) |

Shape (vehicle frame: origin on the road below the rear face's centre, +z toward the front, +y
up, x to the vehicle's left; all in metres): `length_m`, `width_m`, `height_m` (overall, the
bounding box of every part), `ground_clearance_m`, `front_overhang_m` and `rear_overhang_m`
(bumper face to axle), `wheel_radius_m`, `wheel_width_m`, `nose_height_m` (top of the front
face), `bonnet_length_m` (front face to the windscreen's base), `beltline_m` (window sills),
`boot_length_m` (rear face to the rear window's base; 0: hatchback or van), `tail_height_m` (top
of the rear face), `roof_rear_m` and `roof_front_m` (the flat roof's ends, from the rear face),
`cabin_height_m` (the cab's roof where a cargo box is taller), `cargo_length_m` (a box body on the
rear deck: trucks).

Parts and the material each is meant for (one PLY each, `$vehicle_<id>_<part>`): `body`
(clear-coated paint: `roughplastic` or `principled` with clearcoat), `glass` (the greenhouse, a
closed prism: `dielectric`), `trim` (bumpers and the plate frame: black plastic or chrome),
`wheels` (tyres), and the lamp lenses `tail_lamps`, `brake_lamps`, `head_lamps` (open quads
facing out, 5 mm deep in 10 mm pockets: `area` emitters). The body is the side profile extruded
across the width (the greenhouse and roof inset 12 cm per side at 1.83 m, in proportion to the
width) with wheel arches, lamp pockets and the plate recess cut out (manifold3d
booleans: every solid part is closed and watertight). The plate itself is a Mitsuba `rectangle`
placed by `$vehicle_<id>_plate_matrix` (a rotation: texture row 0 at the top, u running to the
vehicle's left, so its bitmap takes `<transform name="to_uv"><scale x="-1"/><translate x="1"/></transform>`
to read left to right from behind); `$vehicle_<id>_matrix` places
the meshes and `$vehicle_<id>_headlamp_{left,right}_matrix` the headlamps' `photometric`
emitters (local +z along the vehicle's +z, +y up).

Plate recess: the plate's size plus RECESS_MARGIN_M on each side, RECESS_DEPTH_M deep; the frame
is a ring FRAME_WIDTH_M wide around the plate on the recess floor, the plate 2 mm proud of the
floor (as sources/road.py's box car).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from poevp_optics.core.params import param
from poevp_optics.core.registry import Registry
from poevp_optics.sources.plates import PLATE_FORMATS as _PLATES

#: Plate formats: (width, height) in m, the sizes of sources/plates.py's formats (whose textures
#: the plates carry). EU: EN/DIN 74069 one-line plate; US: 12 x 6 in (AAMVA).
PLATE_FORMATS = Registry("plate format")
PLATE_FORMATS.register("eu", (_PLATES["eu"].width_mm / 1e3, _PLATES["eu"].height_mm / 1e3),
                       source="DIN 74069 / EU one-line plate, 520 x 110 mm")
PLATE_FORMATS.register("us", (_PLATES["us"].width_mm / 1e3, _PLATES["us"].height_mm / 1e3),
                       source="AAMVA / US plate, 12 x 6 in (305 x 152 mm)")
#: Recess margin around the plate (per side), recess depth, frame ring width and depth (m).
RECESS_MARGIN_M, RECESS_DEPTH_M = 0.020, 0.030
FRAME_WIDTH_M, FRAME_DEPTH_M = 0.012, 0.006
PLATE_PROUD_M = 0.002
#: Lamp lenses (width, height) in m, their pocket depth, and the lens's depth in the pocket.
TAIL_LAMP_M, BRAKE_LAMP_M, HEAD_LAMP_M = (0.30, 0.10), (0.30, 0.06), (0.25, 0.10)
LAMP_POCKET_M, LAMP_LENS_DEPTH_M = 0.010, 0.005
#: Roof panel thickness, bumper height and the shut-line gap above it (m).
ROOF_M, BUMPER_M, SHUT_LINE_M = 0.04, 0.12, 0.01
#: Layout version (part of the cached files' names).
MESH_VERSION = 1
PARTS = ("body", "glass", "trim", "wheels", "tail_lamps", "brake_lamps", "head_lamps")
SOLID_PARTS = ("body", "glass", "trim", "wheels")


class VehicleShapeError(ValueError):
    """A shape whose parts do not fit; `key` names the VehicleSpec key to change."""

    def __init__(self, key: str, msg: str):
        super().__init__(msg)
        self.key = key


@dataclass(frozen=True)
class VehicleShape:
    """A vehicle's dimensions in metres (module docstring)."""

    length_m: float
    width_m: float
    height_m: float
    ground_clearance_m: float
    front_overhang_m: float
    rear_overhang_m: float
    wheel_radius_m: float
    wheel_width_m: float
    nose_height_m: float
    bonnet_length_m: float
    beltline_m: float
    boot_length_m: float
    tail_height_m: float
    roof_rear_m: float
    roof_front_m: float
    cabin_height_m: float
    cargo_length_m: float
    plate_height_m: float


VEHICLE_KINDS = Registry("vehicle kind")
VEHICLE_KINDS.register("sedan", VehicleShape(4.77, 1.83, 1.46, 0.14, 0.93, 1.05, 0.334, 0.215, 0.75, 1.35, 0.98,
                                             0.95, 0.95, 1.60, 3.00, 1.46, 0.0, 0.55),
                       source="VW Passat B8 saloon: 4767 x 1832 x 1456 mm, wheelbase 2786 mm, 215/55 R17")
VEHICLE_KINDS.register("suv", VehicleShape(4.49, 1.84, 1.67, 0.19, 0.88, 0.93, 0.355, 0.235, 0.95, 1.15, 1.10,
                                           0.0, 1.10, 0.25, 2.90, 1.67, 0.0, 0.62),
                       source="VW Tiguan (2016): 4486 x 1839 x 1673 mm, wheelbase 2681 mm, 235/55 R18")
VEHICLE_KINDS.register("van", VehicleShape(4.90, 1.90, 1.99, 0.18, 0.90, 1.00, 0.334, 0.215, 1.00, 0.75, 1.15,
                                           0.0, 1.15, 0.05, 3.90, 1.99, 0.0, 0.60),
                       source="VW Transporter T6 (short wheelbase): 4904 x 1904 x 1990 mm, wheelbase 3000 mm")
VEHICLE_KINDS.register("truck", VehicleShape(7.50, 2.50, 3.40, 0.25, 1.30, 1.90, 0.45, 0.30, 1.40, 0.10, 1.45,
                                             5.70, 1.45, 5.85, 7.30, 2.90, 5.60, 0.80),
                       source="7.5 t rigid box truck (e.g. MAN TGL 8.190): about 7.5 x 2.5 x 3.4 m, wheelbase 4.3 m")
VEHICLE_KINDS.register("bus", VehicleShape(12.0, 2.55, 3.00, 0.30, 2.70, 3.30, 0.48, 0.30, 1.10, 0.05, 1.15,
                                           0.0, 1.15, 0.05, 11.95, 3.00, 0.0, 0.60),
                       source="12 m city bus (e.g. Mercedes-Benz Citaro): 12.0 x 2.55 x 3.0 m; 2.55 m is the EU "
                              "width limit (Directive 96/53/EC)")

_SHAPE_KEYS = tuple(f.name for f in dataclasses.fields(VehicleShape))


def _override(default=-1.0):
    return param(default, unset=-1.0, min=0.0, max=30.0)


@dataclass(frozen=True)
class VehicleSpec:
    """[vehicle.<id>]: a parametric vehicle with its plate (module docstring)."""

    kind: str = param("sedan", choices=VEHICLE_KINDS)
    position_m: tuple[float, float] = param((0.0, 20.0), length=2, min=-1e4, max=1e4)
    heading_deg: float = param(0.0, min=-360.0, max=360.0)
    plate_text: str = param("")
    plate_format: str = param("eu", choices=PLATE_FORMATS)
    plate_height_m: float = _override()
    length_m: float = _override()
    width_m: float = _override()
    height_m: float = _override()
    ground_clearance_m: float = _override()
    front_overhang_m: float = _override()
    rear_overhang_m: float = _override()
    wheel_radius_m: float = _override()
    wheel_width_m: float = _override()
    nose_height_m: float = _override()
    bonnet_length_m: float = _override()
    beltline_m: float = _override()
    boot_length_m: float = _override()
    tail_height_m: float = _override()
    roof_rear_m: float = _override()
    roof_front_m: float = _override()
    cabin_height_m: float = _override()
    cargo_length_m: float = _override()


# ------------------------------------------------------------------------------- checks
def _lamp_layout(s: VehicleShape) -> dict[str, list[tuple[float, float, float, float]]]:
    """Lamp lenses per part: (centre x, centre y, width, height) on the rear (tail, brake) or
    front (head) face, symmetric pairs, inset 5 cm from the sides and 4 cm below the face's top."""
    half_w = s.width_m / 2
    ty = s.tail_height_m - 0.04 - TAIL_LAMP_M[1] / 2
    by = ty - TAIL_LAMP_M[1] / 2 - 0.01 - BRAKE_LAMP_M[1] / 2
    hy = s.nose_height_m - 0.04 - HEAD_LAMP_M[1] / 2
    out = {}
    for part, (w, h), y in (("tail_lamps", TAIL_LAMP_M, ty), ("brake_lamps", BRAKE_LAMP_M, by),
                            ("head_lamps", HEAD_LAMP_M, hy)):
        x = half_w - 0.05 - w / 2
        out[part] = [(x, y, w, h), (-x, y, w, h)]
    return out


def _plate_recess(s: VehicleShape, plate_format: str) -> tuple[float, float]:
    """Half width and half height (m) of the plate recess."""
    w, h = PLATE_FORMATS[plate_format]
    return w / 2 + RECESS_MARGIN_M, h / 2 + RECESS_MARGIN_M


def check_shape(s: VehicleShape, plate_format: str = "eu") -> None:
    """Raise VehicleShapeError (naming the key) where the parts would not fit together."""
    def need(ok, key, msg):
        if not ok:
            raise VehicleShapeError(key, msg)

    for k in _SHAPE_KEYS:
        need(getattr(s, k) > 0 or k in ("boot_length_m", "cargo_length_m"), k, "must be > 0")
    L, W, r = s.length_m, s.width_m, s.wheel_radius_m
    need(s.front_overhang_m >= r + 0.05, "front_overhang_m", f"{s.front_overhang_m:g} m leaves no room for the "
         f"front wheel arch (>= wheel_radius_m + 0.05 = {r + 0.05:g} m)")
    need(s.rear_overhang_m >= r + 0.05, "rear_overhang_m", f"{s.rear_overhang_m:g} m leaves no room for the "
         f"rear wheel arch (>= wheel_radius_m + 0.05 = {r + 0.05:g} m)")
    wheelbase = L - s.front_overhang_m - s.rear_overhang_m
    need(wheelbase >= 2 * r + 0.2, "length_m", f"the wheelbase {wheelbase:.3g} m (length - overhangs) is shorter "
         f"than two wheels ({2 * r + 0.2:.3g} m)")
    need(s.wheel_width_m <= W / 4, "wheel_width_m", f"must be <= width_m / 4 = {W / 4:g} m")
    need(s.ground_clearance_m < 2 * r, "ground_clearance_m", f"must be below the wheels' top {2 * r:g} m")
    arch_top = 2 * r + 0.04
    for key in ("nose_height_m", "tail_height_m"):
        need(s.ground_clearance_m + BUMPER_M + 0.1 < getattr(s, key) <= s.beltline_m, key,
             f"{getattr(s, key):g} m must lie above the bumper ({s.ground_clearance_m + BUMPER_M + 0.1:g} m) "
             f"and not above beltline_m = {s.beltline_m:g} m")
    need(arch_top < min(s.nose_height_m, s.tail_height_m), "wheel_radius_m", f"the wheel arches (top "
         f"{arch_top:.3g} m) reach above the front or rear face")
    need(s.bonnet_length_m + s.boot_length_m < L - 0.3, "bonnet_length_m", f"bonnet {s.bonnet_length_m:g} m "
         f"+ boot {s.boot_length_m:g} m leave < 0.3 m of cabin in {L:g} m")
    cabin = s.cabin_height_m if s.cargo_length_m > 0 else s.height_m
    need(s.beltline_m + ROOF_M + 0.2 < cabin <= s.height_m, "cabin_height_m" if s.cargo_length_m > 0 else "height_m",
         f"the roof ({cabin:g} m) must be above beltline_m + {ROOF_M + 0.2:g} m and not above height_m")
    need(s.boot_length_m <= s.roof_rear_m < s.roof_front_m <= L - s.bonnet_length_m, "roof_rear_m",
         f"need boot_length_m <= roof_rear_m < roof_front_m <= length_m - bonnet_length_m, got "
         f"{s.boot_length_m:g} <= {s.roof_rear_m:g} < {s.roof_front_m:g} <= {L - s.bonnet_length_m:g}")
    need(s.cargo_length_m <= s.boot_length_m, "cargo_length_m", f"the cargo box ({s.cargo_length_m:g} m) must "
         f"sit on the rear deck, behind the cab (boot_length_m = {s.boot_length_m:g} m)")
    lamps = _lamp_layout(s)
    low = min(y - h / 2 for x, y, w, h in lamps["brake_lamps"] + lamps["head_lamps"])
    need(low > s.ground_clearance_m + BUMPER_M + SHUT_LINE_M, "tail_height_m",
         "the lamps do not fit between the bumper and the top of the rear or front face")
    rw, rh = _plate_recess(s, plate_format)
    py = s.plate_height_m
    need(py - rh > s.ground_clearance_m + BUMPER_M + SHUT_LINE_M + 0.005 and py + rh < s.tail_height_m - 0.01,
         "plate_height_m", f"the plate recess ({2 * rh:.3g} m tall at {py:g} m) must lie between the rear bumper "
         f"and tail_height_m = {s.tail_height_m:g} m")
    tail = lamps["brake_lamps"][0]
    side_clear = rw < tail[0] - tail[2] / 2 - 0.01
    below = py + rh < min(y - h / 2 for x, y, w, h in lamps["brake_lamps"]) - 0.01
    need(side_clear or below, "plate_height_m", "the plate recess overlaps the rear lamps")
    need(rw < W / 2 - 0.05, "width_m", f"the plate recess ({2 * rw:.3g} m) is wider than the rear face")


def shape_of(spec: VehicleSpec) -> VehicleShape:
    """The kind's preset with the spec's overrides, checked (VehicleShapeError names the key)."""
    base = VEHICLE_KINDS[spec.kind]
    over = {k: getattr(spec, k) for k in _SHAPE_KEYS if getattr(spec, k) != -1.0}
    shape = dataclasses.replace(base, **over)
    check_shape(shape, spec.plate_format)
    return shape


# ------------------------------------------------------------------------------- meshes
def _to_vehicle(v: np.ndarray, width_m: float) -> np.ndarray:
    """Profile frame (X along the vehicle from the rear, Y up, Z across from 0 to W) -> vehicle
    frame (x = W/2 - Z, y = Y, z = X): a proper rotation, so windings stay outward."""
    return np.stack([width_m / 2 - v[:, 2], v[:, 1], v[:, 0]], axis=1)


def _trimesh(manifold, width_m):
    import trimesh

    m = manifold.to_mesh()
    verts = _to_vehicle(np.asarray(m.vert_properties, float)[:, :3], width_m)
    return trimesh.Trimesh(verts.astype(np.float32), np.asarray(m.tri_verts, np.int64), process=False)


def _box(x0, x1, y0, y1, z0, z1):
    from manifold3d import Manifold

    return Manifold.cube((x1 - x0, y1 - y0, z1 - z0)).translate((x0, y0, z0))


def _prism(points_xy, z0, z1):
    from manifold3d import CrossSection, Manifold

    return Manifold.extrude(CrossSection([list(map(tuple, points_xy))]), z1 - z0).translate((0.0, 0.0, z0))


def _solids(s: VehicleShape, plate_format: str) -> dict:
    """The closed parts as manifolds in the profile frame."""
    from manifold3d import Manifold

    L, W, gc, r = s.length_m, s.width_m, s.ground_clearance_m, s.wheel_radius_m
    lower = _prism([(0, gc), (L, gc), (L, s.nose_height_m), (L - s.bonnet_length_m, s.beltline_m),
                    (s.boot_length_m, s.beltline_m), (0, s.tail_height_m)], 0.0, W)
    cabin = s.cabin_height_m if s.cargo_length_m > 0 else s.height_m
    tumble = min(0.12 * W / 1.83, W / 8)
    body = lower + _box(s.roof_rear_m, s.roof_front_m, cabin - ROOF_M, cabin, tumble, W - tumble)
    if s.cargo_length_m > 0:
        body = body + _box(0.0, s.cargo_length_m, s.beltline_m, s.height_m, 0.0, W)
    axles = (s.rear_overhang_m, L - s.front_overhang_m)
    wheels, cuts = [], []
    for ax in axles:
        for z0, z1 in ((0.0, s.wheel_width_m), (W - s.wheel_width_m, W)):
            wheels.append(Manifold.cylinder(z1 - z0 - 0.02, r, circular_segments=48).translate((ax, r, z0 + 0.01)))
            cuts.append(Manifold.cylinder(z1 - z0 + 2.05, r + 0.04, circular_segments=48)
                        .translate((ax, r, z0 - 1.0 if z0 == 0 else z0 - 0.05)))
    bumper_top = gc + BUMPER_M
    cuts.append(_box(-1.0, 0.04, gc - 1.0, bumper_top + SHUT_LINE_M, -1.0, W + 1.0))
    cuts.append(_box(L - 0.04, L + 1.0, gc - 1.0, bumper_top + SHUT_LINE_M, -1.0, W + 1.0))
    rw, rh = _plate_recess(s, plate_format)
    py = s.plate_height_m
    cuts.append(_box(-1.0, RECESS_DEPTH_M, py - rh, py + rh, W / 2 - rw, W / 2 + rw))
    for part, lenses in _lamp_layout(s).items():
        front = part == "head_lamps"
        for x, y, w, h in lenses:
            xs = (L - LAMP_POCKET_M, L + 1.0) if front else (-1.0, LAMP_POCKET_M)
            cuts.append(_box(*xs, y - h / 2, y + h / 2, W / 2 - x - w / 2, W / 2 - x + w / 2))
    body = body - Manifold.batch_boolean(cuts, _union_op())
    trim = (_box(0.0, 0.25, gc + 0.02, bumper_top, 0.01, W - 0.01)
            + _box(L - 0.25, L, gc + 0.02, bumper_top, 0.01, W - 0.01))
    pw, ph = PLATE_FORMATS[plate_format]
    ring = (_box(RECESS_DEPTH_M - FRAME_DEPTH_M, RECESS_DEPTH_M, py - ph / 2 - FRAME_WIDTH_M, py + ph / 2 + FRAME_WIDTH_M,
                 W / 2 - pw / 2 - FRAME_WIDTH_M, W / 2 + pw / 2 + FRAME_WIDTH_M)
            - _box(RECESS_DEPTH_M - FRAME_DEPTH_M - 1.0, RECESS_DEPTH_M + 1.0, py - ph / 2, py + ph / 2,
                   W / 2 - pw / 2, W / 2 + pw / 2))
    glass_base = max(s.boot_length_m, s.cargo_length_m + 0.1 if s.cargo_length_m > 0 else 0.0)
    glass = _prism([(glass_base, s.beltline_m), (L - s.bonnet_length_m, s.beltline_m),
                    (s.roof_front_m, cabin - ROOF_M), (s.roof_rear_m, cabin - ROOF_M)], tumble, W - tumble)
    return {"body": body, "glass": glass, "trim": trim + ring, "wheels": Manifold.batch_boolean(wheels, _union_op())}


def _union_op():
    from manifold3d import OpType

    return OpType.Add


def _lens_mesh(s: VehicleShape, lenses, front: bool):
    """Open quads (two triangles each) facing out of the rear (-z) or front (+z) face, in the
    vehicle frame, LAMP_LENS_DEPTH_M inside their pockets."""
    import trimesh

    z = s.length_m - LAMP_LENS_DEPTH_M if front else LAMP_LENS_DEPTH_M
    verts, faces = [], []
    for x, y, w, h in lenses:
        k = len(verts)
        verts += [(x - w / 2, y - h / 2, z), (x + w / 2, y - h / 2, z), (x + w / 2, y + h / 2, z), (x - w / 2, y + h / 2, z)]
        # normal +z is (v1 - v0) x (v2 - v0) = +x cross +y: keep for the front, flip for the rear
        faces += [(k, k + 1, k + 2), (k, k + 2, k + 3)] if front else [(k, k + 2, k + 1), (k, k + 3, k + 2)]
    return trimesh.Trimesh(np.asarray(verts, np.float32), np.asarray(faces, np.int64), process=False)


def vehicle_meshes(s: VehicleShape, plate_format: str = "eu") -> dict:
    """{part: trimesh.Trimesh} in the vehicle frame (module docstring); checks the shape first."""
    check_shape(s, plate_format)
    out = {k: _trimesh(m, s.width_m) for k, m in _solids(s, plate_format).items()}
    for part, lenses in _lamp_layout(s).items():
        out[part] = _lens_mesh(s, lenses, part == "head_lamps")
    return out


def plate_centre_m(s: VehicleShape) -> np.ndarray:
    """The plate's centre in the vehicle frame (m): 2 mm proud of the recess floor."""
    return np.array([0.0, s.plate_height_m, RECESS_DEPTH_M - PLATE_PROUD_M])


def headlamp_centres_m(s: VehicleShape) -> dict[str, np.ndarray]:
    """The headlamp lenses' centres in the vehicle frame (m): left (+x) and right."""
    (x, y, _, _), _ = _lamp_layout(s)["head_lamps"]
    z = s.length_m - LAMP_LENS_DEPTH_M
    return {"left": np.array([x, y, z]), "right": np.array([-x, y, z])}


def to_world(spec: VehicleSpec) -> np.ndarray:
    """4x4 vehicle frame -> world at t = 0: yaw by heading_deg about +y, then the position."""
    a = math.radians(spec.heading_deg)
    c, s = math.cos(a), math.sin(a)
    m = np.eye(4)
    m[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    m[0, 3], m[2, 3] = spec.position_m
    return m


def plate_world_m(spec: VehicleSpec) -> tuple[np.ndarray, np.ndarray]:
    """(centre, unit normal) of the vehicle's plate in the world at t = 0 (m): `plate_centre_m`
    and the plate's face normal (-z in the vehicle frame, out of its rear) through `to_world`."""
    world = to_world(spec)
    rot = world[:3, :3]
    return rot @ plate_centre_m(shape_of(spec)) + world[:3, 3], rot @ np.array([0.0, 0.0, -1.0])


def _matrix(m: np.ndarray) -> str:
    return " ".join(f"{float(v):.9g}" for v in np.asarray(m).ravel())


def _ply_problem(path: Path, mesh) -> str | None:
    """Why the PLY at `path` is not `mesh` (vertex and face arrays, exactly), or None."""
    import trimesh

    got = trimesh.load(str(path), file_type="ply", process=False, force="mesh")
    if got.vertices.shape != mesh.vertices.shape or got.faces.shape != mesh.faces.shape:
        return f"{len(got.vertices)} vertices and {len(got.faces)} faces, not {len(mesh.vertices)} and {len(mesh.faces)}"
    if not np.array_equal(np.asarray(got.vertices, np.float32), np.asarray(mesh.vertices, np.float32)):
        return "vertices differ from the vehicle mesh's"
    if not np.array_equal(got.faces, mesh.faces):
        return "faces differ from the vehicle mesh's"
    return None


def cached_vehicle_meshes(s: VehicleShape, plate_format: str = "eu") -> dict[str, Path]:
    """{part: PLY path} in the package cache (core/cache.py: checksum and every vertex and face
    checked before Mitsuba reads it; a damaged file is rebuilt), keyed by the shape and format."""
    from poevp_optics.core.cache import cache_file, cached_path, json_digest

    key = json_digest({"shape": dataclasses.asdict(s), "plate": plate_format, "v": MESH_VERSION}, sort_keys=True)
    out = {}
    for part, mesh in vehicle_meshes(s, plate_format).items():
        path = cache_file("meshes", f"vehicle_{part}_{key}.ply")
        out[part] = cached_path(path, lambda tmp, m=mesh: Path(tmp).write_bytes(m.export(file_type="ply")),
                                lambda p, m=mesh: _ply_problem(p, m))
    return out


def xml_params(ident: str, spec: VehicleSpec) -> dict[str, str]:
    """`$vehicle_<ident>_*`: each part's PLY, the meshes' matrix, the plate's rectangle matrix,
    the headlamps' emitter matrices, and the plate texture when plate_text is set."""
    s = shape_of(spec)
    world = to_world(spec)
    pre = f"vehicle_{ident}"
    out = {f"{pre}_{part}": str(p) for part, p in cached_vehicle_meshes(s, spec.plate_format).items()}
    out[f"{pre}_matrix"] = _matrix(world)
    w, h = PLATE_FORMATS[spec.plate_format]
    plate = np.eye(4)
    # a proper rotation (180 deg about x: facing -z, texture rows from the top) scaled to the plate:
    # a mirroring matrix would flip the geometric normal against the shading one, and media (fog)
    # take the side from the geometric normal; the XML mirrors u instead (`to_uv`, module docstring)
    plate[:3, :3] = np.diag([w / 2, -h / 2, -1.0])
    plate[:3, 3] = plate_centre_m(s)
    out[f"{pre}_plate_matrix"] = _matrix(world @ plate)
    for side, c in headlamp_centres_m(s).items():
        lamp = np.eye(4)
        lamp[:3, 3] = c
        out[f"{pre}_headlamp_{side}_matrix"] = _matrix(world @ lamp)
    if spec.plate_text:
        from poevp_optics.sources.plates import cached_plate_path

        out[f"{pre}_plate_texture"] = str(cached_plate_path(spec.plate_text, plate_format=spec.plate_format))
    return out
