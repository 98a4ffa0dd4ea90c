"""Held-out traffic for scoring predictors: a generator of its own, apart from the one the learned
predictor is trained on (analysis/motion_paths.py).

A dark road seen by a camera at night (8-bit, 1-2 DN noise), with several vehicles at once, each a
dim body carrying two headlamps (Gaussian ellipses `HEADLAMP_E` times over saturation) and a
plate between them (a Gaussian highlight `PLATE_E` over saturation, paper Eq. 3), plus standing
lights (a street lamp, a parked car's lamps). Each scene follows one motion family:

| family       | what moves                                                                     |
|--------------|--------------------------------------------------------------------------------|
| approach     | a vehicle closing in: its image grows 3-9 % a frame about a drifting centre     |
| turn         | a tight turn: the yaw rate ramps up to 0.27-0.45 rad/frame and down again, the lamps' spacing foreshortens with the yaw |
| stop_and_go  | car following (intelligent driver model, Treiber, Hennecke & Helbing 2000) behind a leader that brakes to a stop over 8-20 frames, stands and drives off |
| lane_change  | a lateral move of 30-90 px over 12-24 frames (smoothstep) while driving on     |
| entering     | a vehicle driving in from the frame's edge (its lamps cut by the edge at first) |
| crossing     | two vehicles in opposite directions passing each other (their lamps merge and part) |
| shake        | camera shake: straight-driving vehicles and our camera's pitch bounce (period 3-9 frames, 4-12 px) and yaw drift: every light moves together by one global shift |

Disjoint from training (`BENCH_SHAPES` against motion_paths.TRAINING_SHAPES, checked by
`check_disjoint` and tests/unit/test_traffic_paths.py): the turn rates, lane-change widths,
braking ramps, growth rates and the camera's pitch period (against the training swerve's) lie
outside the training ranges, and the other families (IDM, edges, two vehicles, global motion)
have no training counterpart; the highlights are other shapes (lamps 200-600x,
plates 55-70x over saturation against training's 5-50x); the seeds come from their own stream
(`BENCH_SEED`). The scene's frame rate is 10 or 15 fps (the scene library's night_road runs at 10).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

FAMILIES = ("approach", "turn", "stop_and_go", "lane_change", "entering", "crossing", "shake")
#: Seed stream of the benchmark (apart from every training split: train_track 0-2e6, train_data 1e7-1.2e7).
BENCH_SEED = 70_000_000
#: Headlamp and plate highlights, x saturation (the training plate: 5-50x).
HEADLAMP_E = (200.0, 600.0)
PLATE_E = (55.0, 70.0)
#: Shape parameters of the families (low, high), each outside motion_paths.TRAINING_SHAPES' range of
#: the same motion (`check_disjoint`): turn rate (rad/frame) against turn_rad, lane-change width
#: (frames) against width_frames, the leader's braking ramp (frames) against stop_ramp_frames, the
#: approach's growth per frame against growth_per_frame, the camera's pitch period (frames) against
#: the swerve's period_frames (training's only oscillation).
BENCH_SHAPES = {"turn_rad": (0.27, 0.45), "width_frames": (12.0, 24.0), "stop_ramp_frames": (8.0, 20.0),
                "growth_per_frame": (1.03, 1.09), "lane_px": (30.0, 90.0), "shake_px": (4.0, 12.0),
                "shake_period_frames": (3.0, 9.0)}
#: Which training shape each benchmark shape stands against.
_COUNTERPART = {"turn_rad": "turn_rad", "width_frames": "width_frames", "stop_ramp_frames": "stop_ramp_frames",
                "growth_per_frame": "growth_per_frame", "shake_period_frames": "period_frames"}
FRAMES = 12
#: Heights of the lamps' and the plate's centres below the body's centre (x the body's height).
LAMP_Y, PLATE_Y = -0.05, 0.3


def check_disjoint(training: dict) -> list[str]:
    """Benchmark shape ranges that overlap their training counterpart (empty: disjoint)."""
    bad = []
    for ours, theirs in _COUNTERPART.items():
        (a, b), (c, d) = BENCH_SHAPES[ours], training[theirs]
        if a <= d and c <= b:
            bad.append(f"{ours} {BENCH_SHAPES[ours]} overlaps training's {theirs} {training[theirs]}")
    return bad


@dataclass(frozen=True)
class Vehicle:
    """One vehicle's image track: centre (T, 2) px, scale (T,) of its size and lamp spacing,
    foreshortening (T,) of the lamp spacing (|cos| of the yaw turned), body size (w, h) px at
    scale 1, lamps' E (left, right) and plate's E."""

    centre_px: np.ndarray
    scale: np.ndarray
    foreshorten: np.ndarray
    body_px: tuple[float, float]
    lamp_e: tuple[float, float]
    plate_e: float
    body_dn: float


@dataclass(frozen=True)
class TrafficScene:
    """Frames (T, H, W) float32 8-bit (None: not rendered), the vehicles and the camera's
    global shift (T, 2) px."""

    family: str
    speed_px: float
    seed: int
    frames: np.ndarray | None
    vehicles: tuple[Vehicle, ...]
    global_px: np.ndarray
    draws: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- motion
def idm_follower(rng: np.random.Generator, n: int, fps: float) -> np.ndarray:
    """Speeds (m/s, n frames) of a car following (intelligent driver model: a = a_max [1 -
    (v/v0)^4 - (s*/s)^2], s* = s0 + v T + v dv / (2 sqrt(a_max b)); Treiber et al., Phys. Rev.
    E 62, 1805 (2000)) a leader that cruises, brakes to a stop over `stop_ramp_frames`, stands
    and drives off; the window of n frames around the follower's slowest frame."""
    v0, t_head = rng.uniform(8.0, 14.0), rng.uniform(1.0, 1.8)
    a_max, b, s0 = rng.uniform(1.5, 3.0), rng.uniform(2.0, 4.0), 2.0
    ramp = rng.uniform(*BENCH_SHAPES["stop_ramp_frames"])
    stand = rng.uniform(3.0, 10.0)
    total, dt = 240, 1.0 / fps
    t = np.arange(total)
    brake_at = 60.0
    leader_v = np.interp(t, [0, brake_at, brake_at + ramp, brake_at + ramp + stand, brake_at + 2 * ramp + stand + 20],
                         [0.8 * v0, 0.8 * v0, 0.0, 0.0, 0.8 * v0])
    leader_x = np.concatenate([[30.0], 30.0 + np.cumsum(leader_v[1:] * dt)])
    x, v, out = 0.0, 0.8 * v0, []
    for k in range(total):
        gap = max(leader_x[k] - x - 4.5, 0.1)
        s_star = s0 + v * t_head + v * (v - leader_v[k]) / (2 * np.sqrt(a_max * b))
        acc = a_max * (1 - (v / v0) ** 4 - (max(s_star, 0.0) / gap) ** 2)
        v = max(v + acc * dt, 0.0)
        x += v * dt
        out.append(v)
    speeds = np.asarray(out)
    centre = int(np.argmin(speeds[40:]) + 40)
    start = int(np.clip(centre - rng.integers(n // 3, 2 * n // 3), 0, total - n))
    return speeds[start:start + n]


def _heading(rng: np.random.Generator) -> float:
    """A road heading (rad, image axes): within 30 deg of left or right."""
    return float(np.deg2rad(rng.uniform(-30.0, 30.0) + 180.0 * rng.integers(2)))


def _track(speeds: np.ndarray, headings: np.ndarray) -> np.ndarray:
    """Positions (T, 2) px from per-frame speeds (px/frame) and headings (rad): step k moves
    from frame k to k + 1 at the mean of the two frames' velocities."""
    vel = speeds[:, None] * np.stack([np.cos(headings), np.sin(headings)], 1)
    steps = 0.5 * (vel[1:] + vel[:-1])
    return np.concatenate([np.zeros((1, 2)), np.cumsum(steps, 0)])


def family_track(family: str, rng: np.random.Generator, v: float, n: int, fps: float, draws: dict):
    """(centre (n, 2) px relative, scale (n,), foreshorten (n,)) of the family's main vehicle."""
    u = np.arange(n, dtype=np.float64)
    h0 = _heading(rng)
    ones = np.ones(n)
    if family == "approach":
        g = draws["growth_per_frame"] = float(rng.uniform(*BENCH_SHAPES["growth_per_frame"]))
        drift = _track(np.full(n, v * rng.uniform(0.25, 0.6)), np.full(n, h0))
        return drift, g ** u, ones
    if family == "turn":
        w = draws["turn_rad"] = float(rng.uniform(*BENCH_SHAPES["turn_rad"])) * rng.choice([-1.0, 1.0])
        t0, ramp, hold = rng.uniform(2.0, 5.0), rng.uniform(1.0, 3.0), rng.uniform(1.0, 3.0)
        rate = np.interp(u, [t0, t0 + ramp, t0 + ramp + hold, t0 + 2 * ramp + hold], [0.0, w, w, 0.0])
        yaw = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]))])
        return _track(np.full(n, v), h0 + yaw), ones, np.maximum(np.abs(np.cos(yaw)), 0.25)
    if family == "stop_and_go":
        sp = idm_follower(rng, n, fps)
        return _track(sp * v / max(sp.max(), 1e-9), np.full(n, h0)), ones, ones
    if family == "lane_change":
        width = draws["width_frames"] = float(rng.uniform(*BENCH_SHAPES["width_frames"]))
        lane = draws["lane_px"] = float(rng.uniform(*BENCH_SHAPES["lane_px"])) * rng.choice([-1.0, 1.0])
        x = np.clip((u - rng.uniform(0.3, 0.7) * (n - 1)) / width + 0.5, 0, 1)
        side = lane * x * x * (3 - 2 * x)
        base = _track(np.full(n, v), np.full(n, h0))
        return base + side[:, None] * np.array([-np.sin(h0), np.cos(h0)]), ones, ones
    return _track(np.full(n, v), np.full(n, h0)), ones, ones        # entering, crossing, shake


def camera_shift(family: str, rng: np.random.Generator, n: int, draws: dict) -> np.ndarray:
    """(n, 2) px the whole image moves by (the camera's pitch bounce and yaw drift): zero but
    for `shake`. Pitch: a sinusoid of amplitude `shake_px` and period `shake_period_frames`
    (3-9 frames: 1.1-5 Hz at 10-15 fps, the body's pitch and the camera mount's shake over road
    bumps; a car body's ride frequency is 1-1.5 Hz, Gillespie, Fundamentals of Vehicle Dynamics,
    1992, ch. 5); yaw: a random walk of 0.5-2 px a frame (small steering corrections)."""
    if family != "shake":
        return np.zeros((n, 2))
    amp = draws["shake_px"] = float(rng.uniform(*BENCH_SHAPES["shake_px"]))
    period = draws["shake_period_frames"] = float(rng.uniform(*BENCH_SHAPES["shake_period_frames"]))
    u = np.arange(n, dtype=np.float64)
    pitch = amp * np.sin(2 * np.pi * u / period + rng.uniform(0, 2 * np.pi))
    yaw = np.cumsum(rng.normal(0.0, rng.uniform(0.5, 2.0), n))
    return np.stack([yaw - yaw[0], pitch - pitch[0]], 1)


# ----------------------------------------------------------------------------- scenes
def _vehicle(rng, centre, scale, fore, width_px) -> Vehicle:
    return Vehicle(np.asarray(centre, np.float64), np.asarray(scale, np.float64), np.asarray(fore, np.float64),
                   (width_px, 0.45 * width_px),
                   tuple(float(np.exp(rng.uniform(*np.log(HEADLAMP_E)))) for _ in range(2)),
                   float(rng.uniform(*PLATE_E)), float(rng.uniform(25.0, 60.0)))


def _placed(track: np.ndarray, shape, rng, margin: float) -> np.ndarray:
    """`track` moved so its span is centred in the frame, jittered by up to `margin` px."""
    h, w = shape
    mid = (track.max(0) + track.min(0)) / 2
    return track - mid + np.array([w / 2.0, h / 2.0]) + rng.uniform(-margin, margin, 2)


def draw_scene(family: str, speed_px: float, seed: int, shape=(368, 640), frames: int = FRAMES,
               noise_dn: float | None = None, rendered: bool = True) -> TrafficScene:
    """One scene of `family` whose main vehicle moves at (peak) `speed_px` px/frame; rendered
    False: the motion only (frames None, the same draws)."""
    if family not in FAMILIES:
        raise ValueError(f"traffic family {family!r}: choose one of {', '.join(FAMILIES)}")
    rng = np.random.default_rng(seed)
    h, w = shape
    fps = float(rng.choice([10.0, 15.0]))
    draws = {"fps": fps}
    track, scale, fore = family_track(family, rng, float(speed_px), frames, fps, draws)
    width = float(rng.uniform(90.0, 150.0)) / (scale[-1] ** 0.5 if family == "approach" else 1.0)
    if family == "entering":
        d = track[-1] - track[0]
        unit = d / max(np.hypot(*d), 1e-9)
        edge = np.array([w if unit[0] < 0 else 0.0, rng.uniform(0.3, 0.7) * h])
        track = track - track[0] + edge - unit * 0.3 * width
    else:
        track = _placed(track, shape, rng, 20.0)
    vehicles = [_vehicle(rng, track, scale, fore, width)]
    if family == "crossing":
        other = track[::-1].copy() + np.array([0.0, rng.uniform(-12.0, 12.0)])
        vehicles.append(_vehicle(rng, other, scale, fore, float(rng.uniform(90.0, 150.0))))
    if family == "shake":
        extra = _track(np.full(frames, speed_px * rng.uniform(0.3, 0.8)), np.full(frames, _heading(rng)))
        vehicles.append(_vehicle(rng, _placed(extra, shape, rng, 60.0) + np.array([0.0, 0.25 * h]),
                                 np.ones(frames), np.ones(frames), float(rng.uniform(70.0, 110.0))))
    # standing lights: a street lamp high up and a parked car low at one side
    still = np.ones(frames)
    lamp_xy = np.array([rng.uniform(0.1, 0.9) * w, rng.uniform(0.06, 0.14) * h])
    parked = np.array([rng.choice([0.12, 0.88]) * w, rng.uniform(0.82, 0.9) * h])
    vehicles.append(_vehicle(rng, np.tile(lamp_xy, (frames, 1)), 0.35 * still, still, 60.0))
    vehicles.append(_vehicle(rng, np.tile(parked, (frames, 1)), 0.8 * still, still, 80.0))
    shift = camera_shift(family, rng, frames, draws)
    noise = float(rng.uniform(1.0, 2.0)) if noise_dn is None else noise_dn
    imgs = render(vehicles, shift, shape, rng, noise) if rendered else None
    return TrafficScene(family, float(speed_px), seed, imgs, tuple(vehicles), shift, draws)


def _gauss_into(img: np.ndarray, cx: float, cy: float, sx: float, sy: float, amp: float) -> None:
    """Add amp exp(-((x - cx)/sx)^2 - ((y - cy)/sy)^2) to `img` within 3.5 sigma (in place)."""
    h, w = img.shape
    x0, x1 = max(int(cx - 3.5 * sx), 0), min(int(cx + 3.5 * sx) + 2, w)
    y0, y1 = max(int(cy - 3.5 * sy), 0), min(int(cy + 3.5 * sy) + 2, h)
    if x1 <= x0 or y1 <= y0:
        return
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float64)
    img[y0:y1, x0:x1] += amp * np.exp(-((xx - cx) / sx) ** 2 - ((yy - cy) / sy) ** 2)


def render(vehicles, shift: np.ndarray, shape, rng: np.random.Generator, noise_dn: float) -> np.ndarray:
    """8-bit frames (T, H, W) float32: a dark textured road moved by the camera's shift, each
    vehicle's body, plate and lamps at their sub-pixel places, clipped at 255 and rounded."""
    import cv2

    h, w = shape
    n = len(shift)
    road = cv2.GaussianBlur(rng.uniform(0, 1, (h + 64, w + 64)).astype(np.float32), (0, 0), 2.0)
    road = 8.0 + 22.0 * (road - road.min()) / max(float(road.max() - road.min()), 1e-6)
    out = []
    for t in range(n):
        m = np.float32([[1, 0, shift[t, 0] - 32], [0, 1, shift[t, 1] - 32]])
        img = cv2.warpAffine(road, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT).astype(np.float64)
        for veh in vehicles:
            cx, cy = veh.centre_px[t] + shift[t]
            s = veh.scale[t]
            bw, bh = veh.body_px[0] * s * max(veh.foreshorten[t], 0.5), veh.body_px[1] * s
            x0, x1 = int(np.clip(cx - bw / 2, 0, w)), int(np.clip(cx + bw / 2, 0, w))
            y0, y1 = int(np.clip(cy - bh / 2, 0, h)), int(np.clip(cy + bh / 2, 0, h))
            img[y0:y1, x0:x1] = veh.body_dn
            half = 0.36 * veh.body_px[0] * s * veh.foreshorten[t]
            for side, e in zip((-1.0, 1.0), veh.lamp_e):
                _gauss_into(img, cx + side * half, cy + LAMP_Y * bh, 0.07 * veh.body_px[0] * s,
                            0.045 * veh.body_px[0] * s, e * 255.0)
            _gauss_into(img, cx, cy + PLATE_Y * bh, 0.1 * veh.body_px[0] * s * veh.foreshorten[t],
                        0.03 * veh.body_px[0] * s, veh.plate_e * 200.0)
        img = img + rng.normal(0.0, noise_dn, img.shape)
        out.append(np.clip(np.rint(img), 0, 255).astype(np.float32))
    return np.stack(out)


#: The benchmark's speeds (px/frame of the main vehicle) and scenes per family and speed.
SPEEDS_PX = (8.0, 16.0, 24.0, 32.0, 48.0)
SCENES_PER_CELL = 2


def bench_cases(speeds=SPEEDS_PX, per_cell: int = SCENES_PER_CELL, families=FAMILIES) -> list[tuple[str, float, int]]:
    """(family, speed px/frame, seed) of every benchmark scene: seeds BENCH_SEED + 1000 f +
    100 speed index + k, so a family's or speed's scenes keep their seeds when others are added."""
    return [(f, float(v), BENCH_SEED + 1000 * FAMILIES.index(f) + 100 * i + k)
            for f in families for i, v in enumerate(speeds) for k in range(per_cell)]


def light_tracks(scene: TrafficScene) -> list[np.ndarray]:
    """Noise-free image tracks (T, 2) px of every light in the scene (each lamp and plate of
    each vehicle, camera shift included): the chains a perfect tracker would measure."""
    out = []
    for veh in scene.vehicles:
        c = veh.centre_px + scene.global_px
        half = 0.36 * veh.body_px[0] * veh.scale * veh.foreshorten
        bh = veh.body_px[1] * veh.scale
        for dx, dy in ((-half, LAMP_Y * bh), (half, LAMP_Y * bh), (0 * half, PLATE_Y * bh)):
            out.append(c + np.stack([dx, dy], 1))
    return out
