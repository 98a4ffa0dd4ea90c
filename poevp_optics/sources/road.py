"""Night-road geometry: our headlamps, the camera's offset from them, the car ahead's
retroreflective plate, and the box car that carries it where no [vehicle.<id>] does
(scenes/night_road).

World frame (metres): y up, the road plane y = 0, our car's front at z = 0 looking down +z, x to
the left (Mitsuba's `lookat` with up +y puts local +x on the left). Our two headlamps sit at
(+-lamp_spacing_m / 2, lamp_height_m, 0), aimed straight ahead (+z); the camera sits at the
LEFT lamp + `camera_offset_m`. The car ahead's plate centre is at `plate_position_m` at t = 0
and moves with `[motion.plate]`; its normal faces us (-z).

[road] keys (`RoadSpec`; bound into the XML as `$road_*` parameters by `xml_params`):

| key                 | type      | unit | default         | meaning |
|---------------------|-----------|------|-----------------|---------|
| camera_offset_m     | [x, y, z] | m    | [0, 0.5, 0]     | camera position minus the left headlamp's: sets the observation angle |
| lamp_spacing_m      | float     | m    | 1.4             | distance between our headlamps' centres |
| lamp_height_m       | float     | m    | 0.65            | height of our headlamps' centres |
| camera_aim_m        | float     | m    | 25.0            | the camera looks at the lane centre at plate height this far ahead |
| plate_position_m    | [x, y, z] | m    | [0, 0.5, 60]    | the plate's centre at t = 0 |
| oncoming_position_m | [x, z]    | m    | [3.5, 80]       | the oncoming car's front centre on the road at t = 0 (box car only) |
| highbeam            | str       | -    | "highbeam"      | the [spectra] entry of our high beams (intensity_cd, distribution) |
| sheeting            | str       | -    | "plate_sheeting"| the [sheeting] entry of the plate's sheeting |
| vehicle             | str       | -    | ""              | the [vehicle.<id>] whose plate is the plate; "" : the box car below |

With `vehicle` set (sources/vehicles.py), that vehicle's plate rectangle is the plate: it must face
us (heading_deg 0, normal -z) with its centre at `plate_position_m` at t = 0 (`vehicle_plate_problem`,
checked when the scene loads), and the XML takes its meshes, plate and lamps from the
`$vehicle_<id>_*` parameters; the `$road_*` parameters are then the camera's and our high beams'
only. Without it, the XML places the box car below and the oncoming car from `$road_*`.

Angles of retroreflection (CIE 54.2-2001; ASTM E808): for the lamp at P_l, the camera at P_c and
the plate centre at P_p with normal n, the observation angle alpha is the angle at P_p between
P_l - P_p and P_c - P_p; the entrance angle beta is the angle between P_l - P_p and n. The
illuminance on a plane perpendicular to the light is E_perp = I(H, V) / d^2, I the lamp's
candela toward the plate (its photometric file, scaled so the file's peak is `intensity_cd`),
and the coefficient of retroreflected luminance seen by the camera is R_A(alpha, beta) / cos
theta_v (retroreflective.py), theta_v the viewing angle from the normal. The plate's
retroreflected luminance is sum over lamps of R_A E_perp / cos theta_v.

The car ahead's rear is a procedural mesh (`car_rear_mesh`): a 1.8 x 1.2 x 4.2 m box whose rear
face holds a 560 x 150 mm recess, 30 mm deep, for the 520 x 110 mm plate (EU plate, DIN 74069),
which sits 2 mm proud of the recess floor; the tail lamps are separate emitting rectangles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from poevp_optics.core.params import param

#: Car-ahead body (m): half width, bottom and top heights, length; recess half sizes and depth.
BODY_HALF_WIDTH_M, BODY_BOTTOM_M, BODY_TOP_M, BODY_LENGTH_M = 0.9, 0.25, 1.45, 4.2
RECESS_HALF_W_M, RECESS_HALF_H_M, RECESS_DEPTH_M = 0.28, 0.075, 0.03
#: Plate centre in the car's frame (x, y above the road, z into the car from the rear face).
PLATE_LOCAL_M = (0.0, 0.5, RECESS_DEPTH_M - 0.002)
#: Mesh layout version (part of the cached file's name).
MESH_VERSION = 1


@dataclass(frozen=True)
class RoadSpec:
    """[road]: night-road geometry (module docstring); present only in road scenes."""

    camera_offset_m: tuple[float, float, float] = param((0.0, 0.5, 0.0), length=3, min=-10.0, max=10.0)
    lamp_spacing_m: float = param(1.4, gt=0, max=3.0)
    lamp_height_m: float = param(0.65, gt=0, max=3.0)
    camera_aim_m: float = param(25.0, gt=1.0, max=1000.0)
    plate_position_m: tuple[float, float, float] = param((0.0, 0.5, 60.0), length=3, min=-1000.0, max=1000.0)
    oncoming_position_m: tuple[float, float] = param((3.5, 80.0), length=2, min=-1000.0, max=1000.0)
    highbeam: str = param("highbeam")
    sheeting: str = param("plate_sheeting")
    vehicle: str = param("")

    def lamps_m(self) -> dict[str, np.ndarray]:
        """Our headlamps' centres (world, m): left (+x) and right."""
        h, s = self.lamp_height_m, self.lamp_spacing_m / 2
        return {"left": np.array([s, h, 0.0]), "right": np.array([-s, h, 0.0])}

    def camera_m(self) -> np.ndarray:
        return self.lamps_m()["left"] + np.asarray(self.camera_offset_m, float)

    def camera_target_m(self) -> np.ndarray:
        return np.array([0.0, self.plate_position_m[1], self.camera_aim_m])


def _vec(v) -> str:
    return ", ".join(f"{float(x):.9g}" for x in v)


def xml_params(road: RoadSpec) -> dict[str, str]:
    """The `$road_*` XML parameters (origins/targets as 'x, y, z', coordinates as numbers): the
    camera's and our high beams'; without `road.vehicle` also the box car's mesh file
    (`$road_car_mesh`), its plate's and the oncoming car's coordinates."""
    lamps = road.lamps_m()
    out = {"road_camera_origin": _vec(road.camera_m()), "road_camera_target": _vec(road.camera_target_m())}
    for side, p in lamps.items():
        out[f"road_highbeam_{side}_origin"] = _vec(p)
        out[f"road_highbeam_{side}_target"] = _vec(p + np.array([0.0, 0.0, 1.0]))
    if road.vehicle:
        return out
    plate = np.asarray(road.plate_position_m, float)
    car = plate - np.asarray(PLATE_LOCAL_M)
    ox, oz = road.oncoming_position_m
    out["road_car_mesh"] = str(cached_car_mesh())
    for name, v in (("car", car), ("plate", plate)):
        for axis, x in zip("xyz", v):
            out[f"road_{name}_{axis}"] = f"{x:.9g}"
    out["road_oncoming_x"], out["road_oncoming_z"] = f"{ox:.9g}", f"{oz:.9g}"
    return out


def vehicle_plate_problem(road: RoadSpec, vehicles) -> tuple[str, str] | None:
    """(key, why) when `road.vehicle` names no [vehicle.<id>] of `vehicles`, or that vehicle's
    plate does not face us (heading_deg 0: normal -z, as `plate_geometry` takes it) or does not
    centre on `plate_position_m` at t = 0 within 0.5 mm; None when it does (or no vehicle is
    named)."""
    if not road.vehicle:
        return None
    spec = vehicles.get(road.vehicle)
    if spec is None:
        known = ", ".join(sorted(vehicles)) or "none"
        return "road.vehicle", f"{road.vehicle!r} names no [vehicle.<id>] entry (known: {known})"
    from poevp_optics.sources.vehicles import plate_world_m

    key = f"vehicle.{road.vehicle}"
    if math.remainder(spec.heading_deg, 360.0) != 0.0:
        return f"{key}.heading_deg", (f"{spec.heading_deg:g} deg: the plate named by road.vehicle must face "
                                      "our camera (heading_deg = 0, its rear toward us)")
    centre, _ = plate_world_m(spec)
    want = np.asarray(road.plate_position_m, float)
    if np.max(np.abs(centre - want)) > 5e-4:
        return f"{key}.position_m", (f"its plate centres at ({_vec(centre)}) m, not at road.plate_position_m "
                                     f"({_vec(want)}) m: the report's angles would be another plate's")
    return None


# ------------------------------------------------------------------------------- geometry
def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def lamp_angles_deg(direction_from_lamp: np.ndarray) -> tuple[float, float]:
    """(H, V) of a world direction for a lamp aimed down +z with +y up (Type A, LM-63: H + to
    the lamp's right = world -x, V + up)."""
    x, y, z = direction_from_lamp / np.linalg.norm(direction_from_lamp)
    return math.degrees(math.atan2(-x, z)), math.degrees(math.asin(max(-1.0, min(1.0, y))))


def plate_geometry(road: RoadSpec, plate_centre_m, candela, ra) -> dict:
    """Per lamp: distance (m), observation angle alpha and entrance angle beta (deg), the
    lamp's H/V toward the plate and candela I, E_perp = I / d^2 (lx), R_A (cd lx-1 m-2), and the
    plate's retroreflected luminance R_A E_perp / cos theta_v (cd m-2); totals over lamps.
    candela(h_deg, v_deg) -> cd; ra(alpha_deg, beta_deg) -> R_A."""
    p = np.asarray(plate_centre_m, float)
    n = np.array([0.0, 0.0, -1.0])
    cam = road.camera_m()
    view = cam - p
    theta_v = _angle_deg(view, n)
    lamps = {}
    for side, pl in road.lamps_m().items():
        to_lamp = pl - p
        d = float(np.linalg.norm(to_lamp))
        alpha, beta = _angle_deg(to_lamp, view), _angle_deg(to_lamp, n)
        h, v = lamp_angles_deg(p - pl)
        i_cd = float(candela(h, v))
        e = i_cd / (d * d)
        r_a = float(ra(alpha, beta))
        lamps[side] = {"distance_m": d, "observation_deg": alpha, "entrance_deg": beta, "lamp_h_deg": h,
                       "lamp_v_deg": v, "intensity_cd": i_cd, "illuminance_perp_lx": e, "r_a": r_a,
                       "retro_luminance_cd_m2": r_a * e / math.cos(math.radians(theta_v))}
    return {"camera_distance_m": float(np.linalg.norm(view)), "viewing_deg": theta_v, "lamps": lamps,
            "retro_luminance_cd_m2": sum(v["retro_luminance_cd_m2"] for v in lamps.values())}


def plate_centre_m(scene, t_s: float) -> np.ndarray:
    """The plate's centre (world, m) at time t_s: [road] plate_position_m + [motion.plate]."""
    p = np.asarray(scene.road.plate_position_m, float)
    m = scene.motion.get("plate")
    return p + (m.offset_m(t_s) if m is not None else 0.0)


# ------------------------------------------------------------------------------- mesh
def _quad(a, b, c, d):
    return [a, b, c, d]


def car_rear_mesh() -> tuple[np.ndarray, np.ndarray]:
    """(vertices (N, 3) float32, triangles (M, 3) uint32) of the car ahead in its own frame
    (origin on the road below the rear face's centre, +z into the car, x left): a box with a
    plate recess in its rear face (module docstring). Quads do not share vertices (flat
    shading); the XML wraps the body in a two-sided BSDF."""
    w, y0, y1, length = BODY_HALF_WIDTH_M, BODY_BOTTOM_M, BODY_TOP_M, BODY_LENGTH_M
    rw, rh, depth = RECESS_HALF_W_M, RECESS_HALF_H_M, RECESS_DEPTH_M
    py = PLATE_LOCAL_M[1]
    ry0, ry1 = py - rh, py + rh
    quads = [
        # rear face (z = 0) around the recess: below, above, left, right strips
        _quad((-w, y0, 0), (w, y0, 0), (w, ry0, 0), (-w, ry0, 0)),
        _quad((-w, ry1, 0), (w, ry1, 0), (w, y1, 0), (-w, y1, 0)),
        _quad((rw, ry0, 0), (w, ry0, 0), (w, ry1, 0), (rw, ry1, 0)),
        _quad((-w, ry0, 0), (-rw, ry0, 0), (-rw, ry1, 0), (-w, ry1, 0)),
        # recess walls and floor
        _quad((-rw, ry0, 0), (rw, ry0, 0), (rw, ry0, depth), (-rw, ry0, depth)),
        _quad((-rw, ry1, 0), (rw, ry1, 0), (rw, ry1, depth), (-rw, ry1, depth)),
        _quad((rw, ry0, 0), (rw, ry1, 0), (rw, ry1, depth), (rw, ry0, depth)),
        _quad((-rw, ry0, 0), (-rw, ry1, 0), (-rw, ry1, depth), (-rw, ry0, depth)),
        _quad((-rw, ry0, depth), (rw, ry0, depth), (rw, ry1, depth), (-rw, ry1, depth)),
        # the rest of the box: top, bottom, sides, front
        _quad((-w, y1, 0), (w, y1, 0), (w, y1, length), (-w, y1, length)),
        _quad((-w, y0, 0), (w, y0, 0), (w, y0, length), (-w, y0, length)),
        _quad((w, y0, 0), (w, y1, 0), (w, y1, length), (w, y0, length)),
        _quad((-w, y0, 0), (-w, y1, 0), (-w, y1, length), (-w, y0, length)),
        _quad((-w, y0, length), (w, y0, length), (w, y1, length), (-w, y1, length)),
    ]
    verts = np.array([v for q in quads for v in q], np.float32)
    tris = np.array([[4 * i, 4 * i + 1, 4 * i + 2] for i in range(len(quads))] +
                    [[4 * i, 4 * i + 2, 4 * i + 3] for i in range(len(quads))], np.uint32)
    return verts, tris


def write_ply(path: Path, verts: np.ndarray, tris: np.ndarray) -> None:
    """An ASCII PLY (vertices, triangles) written atomically."""
    from poevp_optics.core.io import atomic_path

    lines = ["ply", "format ascii 1.0", f"element vertex {len(verts)}", "property float x", "property float y",
             "property float z", f"element face {len(tris)}", "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(f"{c:.6f}" for c in v) for v in verts]
    lines += ["3 " + " ".join(str(int(i)) for i in t) for t in tris]
    with atomic_path(path) as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n")


def _ply_problem(path: Path, verts: np.ndarray, tris: np.ndarray) -> str | None:
    """Why the PLY at `path` is not `write_ply`'s file of (verts, tris): its header (format,
    counts, properties), then every vertex (to the 6 decimals written) and face; or None."""
    lines = path.read_text(encoding="ascii").split("\n")
    header = ["ply", "format ascii 1.0", f"element vertex {len(verts)}", "property float x", "property float y",
              "property float z", f"element face {len(tris)}", "property list uchar int vertex_indices", "end_header"]
    body = lines[len(header):]
    if lines[:len(header)] != header:
        return f"PLY header is not that of a {len(verts)}-vertex, {len(tris)}-face ASCII mesh"
    if len(body) != len(verts) + len(tris) + 1 or body[-1] != "":
        return f"{len(body) - 1} element lines after the header, not {len(verts) + len(tris)}"
    v = np.array([ln.split() for ln in body[:len(verts)]], float)
    f = np.array([ln.split() for ln in body[len(verts):-1]], np.int64)
    if v.shape != verts.shape or not np.allclose(v, verts, rtol=0, atol=5.1e-7):      # %.6f: half a unit
        return "vertices differ from the car mesh's"
    if f.shape != (len(tris), 4) or np.any(f[:, 0] != 3) or np.any(f[:, 1:] != tris):
        return "faces differ from the car mesh's"
    return None


def cached_car_mesh() -> Path:
    """The car mesh's PLY in the package cache (written once per MESH_VERSION and layout),
    checked (checksum and every vertex and face) before anything reads it; a file that fails is
    rebuilt (core/cache.py)."""
    from poevp_optics.core.cache import cache_file, cached_path, digest

    verts, tris = car_rear_mesh()
    path = cache_file("meshes", f"car_rear_{digest(verts.tobytes() + tris.tobytes() + str(MESH_VERSION).encode())}.ply")
    return cached_path(path, lambda tmp: write_ply(tmp, verts, tris), lambda p: _ply_problem(p, verts, tris))
