"""Image-space motion paths and a synthetic highlight sequence on them, for training and
scoring predictors on motion of known truth (benchmarks/predictor_motion.py, the `track_net`
training set).

Paths give the highlight's centre (px) at time u (frames); v is the speed (px/frame) at u = 0,
theta the heading (deg, 0 = right, 90 = down: image axes):

| kind         | centre(u)                                                                 |
|--------------|---------------------------------------------------------------------------|
| straight     | v u e(theta)                                                              |
| curved       | arc of constant turn rate w (rad/frame): heading theta + w u, speed v      |
| accelerating | (v u + a u^2 / 2) e(theta), a = +v / (frames - 1) (speed doubles)         |
| braking      | (v u - a u^2 / 2) e(theta) until the stop, then held (a = v / (frames - 1))|
| swerve       | v u e(theta) + A sin(2 pi u / P) n(theta), P = `period_frames`, A = v P / (4 pi) |
| lane_change  | v u e(theta) + L s(u) n(theta), s a smoothstep `width_frames` wide centred at the event, L = `lane_per_v` v |
| reversal     | speed +v, from the event on ramped linearly to -v over `ramp_frames`        |
| stop         | speed v, ramped linearly to 0 over `ramp_frames` ending at the event, then standing |
| go           | standing until the event, then ramped linearly to v over `ramp_frames`      |
| standing     | no motion (a parked car's lamp, a street light)                            |

The event is at u = `event_frac` (frames - 1). e(theta) is the heading's unit vector, n(theta)
its normal. Defaults (`PathSpec`): event at the middle frame, a 2-frame reversal ramp, a 6-frame
lane change of 2 v, a 16-frame swerve, no growth; the training set (apps/train/train_track.py) draws each
from `TRAINING_SHAPES`, and the held-out traffic benchmark (analysis/traffic_paths.py) uses
another generator whose shapes lie outside these ranges.

The sequence: a textured car body (grey, 0.35 x the frame's width) carrying a white plate whose
light is E times over saturation in a Gaussian highlight (paper Eq. 3, H = O (E G + 1), G peak 1),
on a textured road, each frame rendered by an exact sub-pixel translation (and scaling, when the
car grows) of the HDR layer, clipped at 255 and rounded as an 8-bit camera would (no noise
unless `noise_dn` > 0).

The default swerve's period, 16 frames, is 0.53 s at 30 fps: a hard evasive swerve (a lane
change and back takes 2-4 s on the road); its peak lateral speed is v / 2. The default lane
change moves one lane (2 v px) in 6 frames (0.2 s at 30 fps, again harder than the road's 1-3 s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The default swerve's period (frames): module docstring.
SWERVE_PERIOD_FRAMES = 16.0
KINDS = ("straight", "curved", "accelerating", "braking", "swerve", "lane_change", "reversal", "stop", "go",
         "standing")
#: Ranges the training set draws the shape parameters from (apps/train/train_track.py
#: `random_path`): (low, high) per `PathSpec` field. The held-out traffic generator's shapes lie
#: outside them (analysis/traffic_paths.py, tests/unit/test_traffic_paths.py).
TRAINING_SHAPES = {"turn_rad": (0.04, 0.25), "event_frac": (0.3, 0.7), "reversal_ramp_frames": (2.5, 8.0),
                   "stop_ramp_frames": (0.25, 6.0), "width_frames": (3.0, 10.0), "lane_per_v": (1.0, 3.0),
                   "period_frames": (10.0, 24.0), "growth_per_frame": (0.95, 1.025)}


@dataclass(frozen=True)
class PathSpec:
    """One image-space path: kind, speed v (px/frame), heading (deg), frames, and the kinds'
    shape parameters (module docstring): turn rate (curved, rad/frame), the event's place as a
    fraction of the path (reversal, stop, go, lane change), the ramp of a reversal, stop or go
    (frames), a lane change's width (frames) and offset (x v), a swerve's period (frames); and
    the car's growth per frame (size ratio, any kind: 1 keeps its size; the size is 1 at the
    middle frame)."""

    kind: str
    speed_px: float
    heading_deg: float = 0.0
    frames: int = 8
    turn_rad: float = 0.15
    event_frac: float = 0.5
    ramp_frames: float = 2.0
    width_frames: float = 6.0
    lane_per_v: float = 2.0
    period_frames: float = SWERVE_PERIOD_FRAMES
    growth_per_frame: float = 1.0

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"motion kind {self.kind!r}: choose one of {', '.join(KINDS)}")
        if min(self.ramp_frames, self.width_frames, self.period_frames, self.growth_per_frame) <= 0:
            raise ValueError(f"{self}: ramp_frames, width_frames, period_frames and growth_per_frame must be > 0")


def _integrated(u: np.ndarray, knots_u, knots_v, n: float) -> np.ndarray:
    """Distance (px) travelled by time u with a speed piecewise linear through (knots_u,
    knots_v) (px/frame, held beyond the ends), from u = 0: trapezoidal on a fine grid."""
    fine = np.linspace(-1.0, n + 2.0, 4001)
    vel = np.interp(fine, knots_u, knots_v)
    pos = np.concatenate([[0.0], np.cumsum((vel[1:] + vel[:-1]) / 2 * np.diff(fine))])
    return np.interp(u, fine, pos) - np.interp(0.0, fine, pos)


def centres(path: PathSpec, u: np.ndarray) -> np.ndarray:
    """(len(u), 2) centre offsets (px, x and y) at times u (frames from the first)."""
    u = np.asarray(u, dtype=np.float64)
    th = np.deg2rad(path.heading_deg)
    e = np.array([np.cos(th), np.sin(th)])
    nrm = np.array([-np.sin(th), np.cos(th)])
    v, n = float(path.speed_px), max(path.frames - 1, 1)
    k = path.kind
    ev, r = path.event_frac * n, path.ramp_frames
    q = 0 * u
    if k == "straight":
        s = v * u
    elif k == "curved":
        w = path.turn_rad if path.turn_rad != 0 else 1e-9
        s, q = v * np.sin(w * u) / w, v * (1 - np.cos(w * u)) / w
    elif k == "accelerating":
        a = v / n
        s = v * u + a * u * u / 2
    elif k == "braking":
        a = v / n
        um = np.minimum(u, v / a)
        s = v * um - a * um * um / 2
    elif k == "swerve":
        period = path.period_frames
        amp = v * period / (2 * np.pi) / 2
        s, q = v * u, amp * np.sin(2 * np.pi * u / period)
    elif k == "lane_change":
        x = np.clip((u - ev) / path.width_frames + 0.5, 0, 1)
        s, q = v * u, path.lane_per_v * v * (x * x * (3 - 2 * x))
    elif k == "reversal":
        s = _integrated(u, [ev, ev + r], [v, -v], n)
    elif k == "stop":
        s = _integrated(u, [ev - r, ev], [v, 0.0], n)
    elif k == "go":
        s = _integrated(u, [ev, ev + r], [0.0, v], n)
    else:                                              # standing
        s = 0 * u
    return s[:, None] * e[None] + q[:, None] * nrm[None]


def _texture(rng: np.random.Generator, h: int, w: int, lo: float, hi: float, blur: float) -> np.ndarray:
    import cv2

    t = rng.uniform(0, 1, (h, w)).astype(np.float32)
    t = cv2.GaussianBlur(t, (0, 0), blur)
    t = (t - t.min()) / max(float(t.max() - t.min()), 1e-6)
    return lo + (hi - lo) * t


@dataclass(frozen=True)
class HighlightSequence:
    """8-bit frames (T, H, W) float32 and the true highlight centre per frame (T, 2), px."""

    frames: np.ndarray
    centre_px: np.ndarray
    path: PathSpec


def render_sequence(path: PathSpec, shape=(368, 640), e_over: float = 9.0, text: str = "KA 7391",
                    seed: int = 0, noise_dn: float = 0.0) -> HighlightSequence:
    """Frames of the module docstring's car and plate moving along `path`, centred so the
    whole path stays in the frame."""
    import cv2

    rng = np.random.default_rng(seed)
    h, w = shape
    road = _texture(rng, h, w, 15.0, 45.0, 2.0)
    cw, ch = int(0.35 * w), int(0.35 * w * 0.55)
    body = _texture(rng, ch, cw, 60.0, 120.0, 1.5)
    pw, ph = int(cw * 0.45), int(cw * 0.45 * 0.22)
    plate8 = np.full((ph, pw), 200, np.uint8)
    scale = ph / 40.0
    (tw, th_), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, max(1, int(2 * scale)))
    cv2.putText(plate8, text, ((pw - tw) // 2, (ph + th_) // 2), cv2.FONT_HERSHEY_SIMPLEX, scale, 40,
                max(1, int(2 * scale)), cv2.LINE_AA)
    plate = plate8.astype(np.float32)
    yy, xx = np.mgrid[0:ph, 0:pw].astype(np.float32)
    g = np.exp(-(((xx - pw / 2) / (0.35 * pw)) ** 2 + ((yy - ph / 2) / (0.9 * ph)) ** 2))
    py0, px0 = int(0.62 * ch), (cw - pw) // 2
    body[py0:py0 + ph, px0:px0 + pw] = plate * (e_over * g + 1.0)
    alpha = np.zeros((ch, cw), np.float32)
    alpha[:] = 1.0
    u = np.arange(path.frames, dtype=np.float64)
    c = centres(path, u)
    span = (c.max(0) + c.min(0)) / 2
    c = c - span + np.array([w / 2.0, h / 2.0])
    size = path.growth_per_frame ** (u - (path.frames - 1) / 2.0)
    frames = []
    for (cx, cy), sz in zip(c, size):
        m = np.float32([[sz, 0, cx - sz * cw / 2.0], [0, sz, cy - sz * ch / 2.0]])
        layer = cv2.warpAffine(body, m, (w, h), flags=cv2.INTER_LINEAR, borderValue=0)
        cover = cv2.warpAffine(alpha, m, (w, h), flags=cv2.INTER_LINEAR, borderValue=0)
        img = road * (1 - cover) + layer
        if noise_dn > 0:
            img = img + rng.normal(0, noise_dn, img.shape)
        frames.append(np.clip(np.rint(img), 0, 255).astype(np.float32))
    plate_c = c + size[:, None] * np.array([0.0, (py0 + ph / 2.0) - ch / 2.0])
    return HighlightSequence(np.stack(frames), plate_c, path)


def saturated_centroid(img: np.ndarray, near: np.ndarray | None = None, radius: float = 80.0,
                       level: float = 254.5) -> np.ndarray:
    """(x, y) centroid (px) of the pixels >= `level`, within `radius` of `near` when given;
    NaN when there are none."""
    m = np.asarray(img) >= level
    ys, xs = np.nonzero(m)
    if near is not None and xs.size:
        keep = (xs - near[0]) ** 2 + (ys - near[1]) ** 2 <= radius ** 2
        xs, ys = xs[keep], ys[keep]
    if xs.size == 0:
        return np.array([np.nan, np.nan])
    return np.array([xs.mean(), ys.mean()])
