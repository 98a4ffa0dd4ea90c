"""Traffic: vehicles that follow each other by the Intelligent Driver Model, stop at a stop line
(a toll barrier, a junction's red light) and start again when it opens, change lanes along a
smooth lateral path, and meet oncoming traffic; each vehicle's pose over time drives its
[vehicle.<id>] parts through its [motion.<id>] entry.

A [motion.<id>] entry with `kind = "traffic"` names its vehicle (`vehicle = "<id>"`) and gives its
velocity at the start of the simulation in `velocity_m_per_s` (only the component along the
vehicle's heading counts); the loader replaces it by the `keyframes` motion of that vehicle's
simulated path from t = 0 on (offsets from the XML pose, sampled every `step_s`; positions between samples are
linear in time, off by a dt^2 / 8 <= 0.3 mm at a = 1 m s-2 and dt = 0.05 s). The [vehicle]'s
`position_m` is where it stands when the simulation starts (t = -warmup_s); the camera stands.

[traffic] keys (`TrafficSpec`):

| key                     | type  | unit   | default | meaning |
|-------------------------|-------|--------|---------|---------|
| seed                    | int   | -      | 0       | seed of each vehicle's desired speed draw |
| desired_speed_m_per_s   | float | m s-1  | 13.89   | IDM v0 of the vehicles driving away from us (50 km/h) |
| oncoming_speed_m_per_s  | float | m s-1  | 13.89   | IDM v0 of the oncoming vehicles (heading 180 deg) |
| speed_spread            | float | -      | 0.05    | relative standard deviation of each vehicle's v0 (normal, seeded) |
| time_headway_s          | float | s      | 1.6     | IDM T (Treiber et al. 2000, Table I) |
| min_gap_m               | float | m      | 2.0     | IDM s0, the gap standing in a queue |
| max_accel_m_per_s2      | float | m s-2  | 0.73    | IDM a |
| comfort_decel_m_per_s2  | float | m s-2  | 1.67    | IDM b |
| accel_exponent          | float | -      | 4.0     | IDM delta |
| stop_line_m             | float | m      | -1      | z of the stop line (barrier, red light) across the lanes driving away from us; -1: none |
| release_s               | float | s      | 0.0     | time the stop line opens (barrier up, green) |
| warmup_s                | float | s      | 0.0     | simulated before t = 0 (the [vehicle] positions are at t = -warmup_s, rounded up to whole steps) |
| step_s                  | float | s      | 0.05    | integration step (ballistic update) and keyframe spacing |
| lane_width_m            | float | m      | 3.5     | vehicles whose lateral positions differ by less than half of it share a lane |
| lane_change_vehicle     | str   | -      | ""      | the [vehicle.<id>] that changes lane ("" none) |
| lane_change_to_x_m      | float | m      | 0.0     | its lateral position after the change |
| lane_change_start_s     | float | s      | 0.0     | earliest start; it starts at the first step where MOBIL's safety criterion holds |
| lane_change_duration_s  | float | s      | 4.6     | duration of the lateral move (mean measured by Toledo and Zohar 2007) |
| safe_decel_m_per_s2     | float | m s-2  | 4.0     | MOBIL b_safe: the new follower may have to brake at most this hard |

Model (`idm_accel`): a [1 - (v/v0)^delta - (s*(v, dv)/s)^2], s* = s0 + max(0, v T + v dv / (2
sqrt(a b))), dv = v - v_leader, s the bumper-to-bumper gap (Treiber, Hennecke and Helbing 2000,
Phys. Rev. E 62, 1805, Eq. 2-3; their Table I gives the defaults above, v0 there 120 km/h). At
equilibrium (dv = 0, acceleration 0) the gap is s_e(v) = (s0 + v T) / sqrt(1 - (v/v0)^delta).
The stop line acts as a standing leader of zero length until `release_s`, for vehicles whose front
has not passed it. Integration: the ballistic update v' = max(0, v + a dt), x' = x + v dt + a dt^2
/ 2 (stopping within the step where v + a dt < 0), which Treiber and Kanagaraj (2015, Physica A
419, 183) recommend for car-following models. Lane change: the lateral position follows the
minimum-jerk profile x0 + (x1 - x0)(10 u^3 - 15 u^4 + 6 u^5), u = t / duration (Flash and Hogan
1985, J. Neurosci. 5, 1688), starting once MOBIL's safety criterion holds (Kesting, Treiber and
Helbing 2007, Transp. Res. Rec. 1999, 86: the new follower's IDM deceleration stays below
b_safe); while it moves the vehicle occupies both lanes (its leaders and followers in both see it).
Vehicles turn no yaw along the lateral move (a 3.5 m change over 4.6 s at 10 m/s is a 6 deg
heading at most).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from poevp_optics.core.params import param

KMH = 1.0 / 3.6


@dataclass(frozen=True)
class TrafficSpec:
    """[traffic]: Intelligent Driver Model traffic (module table)."""

    seed: int = param(0, min=0, max=2**31 - 1)
    desired_speed_m_per_s: float = param(50 * KMH, gt=0.0, max=100.0)
    oncoming_speed_m_per_s: float = param(50 * KMH, gt=0.0, max=100.0)
    speed_spread: float = param(0.05, min=0.0, max=0.3)
    time_headway_s: float = param(1.6, gt=0.0, max=10.0)
    min_gap_m: float = param(2.0, gt=0.0, max=50.0)
    max_accel_m_per_s2: float = param(0.73, gt=0.0, max=10.0)
    comfort_decel_m_per_s2: float = param(1.67, gt=0.0, max=10.0)
    accel_exponent: float = param(4.0, gt=0.0, max=20.0)
    stop_line_m: float = param(-1.0, unset=-1.0, min=0.0, max=1e4)
    release_s: float = param(0.0, min=-1e4, max=1e4)
    warmup_s: float = param(0.0, min=0.0, max=600.0)
    step_s: float = param(0.05, gt=0.0, max=1.0)
    lane_width_m: float = param(3.5, gt=0.0, max=10.0)
    lane_change_vehicle: str = param("")
    lane_change_to_x_m: float = param(0.0, min=-1e4, max=1e4)
    lane_change_start_s: float = param(0.0, min=-1e4, max=1e4)
    lane_change_duration_s: float = param(4.6, gt=0.0, max=30.0)
    safe_decel_m_per_s2: float = param(4.0, gt=0.0, max=20.0)


@dataclass(frozen=True)
class IdmParams:
    """One driver's IDM parameters (SI): v0 desired speed, T time headway, s0 minimum gap, a
    maximum acceleration, b comfortable deceleration, delta the acceleration exponent."""

    v0: float
    T: float
    s0: float
    a: float
    b: float
    delta: float


def idm_accel(v, gap, dv, p: IdmParams):
    """IDM acceleration (m s-2) at speed v (m/s), bumper-to-bumper gap (m; inf: free road) and
    approach rate dv = v - v_leader (m/s) (Treiber et al. 2000, Eq. 2-3)."""
    v, gap, dv = np.asarray(v, float), np.asarray(gap, float), np.asarray(dv, float)
    s_star = p.s0 + np.maximum(0.0, v * p.T + v * dv / (2.0 * math.sqrt(p.a * p.b)))
    with np.errstate(divide="ignore"):
        inter = np.where(np.isfinite(gap), (s_star / np.maximum(gap, 1e-3)) ** 2, 0.0)
    return p.a * (1.0 - (v / p.v0) ** p.delta - inter)


def equilibrium_gap(v, p: IdmParams):
    """The IDM's steady-state gap s_e(v) = (s0 + v T) / sqrt(1 - (v/v0)^delta) (m), v < v0."""
    v = np.asarray(v, float)
    return (p.s0 + v * p.T) / np.sqrt(1.0 - (v / p.v0) ** p.delta)


def ballistic_step(s, v, acc, dt):
    """(s', v') after dt under constant acceleration `acc`, stopping where v + acc dt < 0
    (Treiber and Kanagaraj 2015)."""
    v_new = v + acc * dt
    stop = v_new < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        ds = np.where(stop, np.where(acc < 0, -v * v / (2.0 * np.where(acc < 0, acc, -1.0)), 0.0),
                      v * dt + 0.5 * acc * dt * dt)
    return s + ds, np.maximum(v_new, 0.0)


def min_jerk(u):
    """The minimum-jerk profile 10 u^3 - 15 u^4 + 6 u^5 on [0, 1] (0 before, 1 after)."""
    u = np.clip(np.asarray(u, float), 0.0, 1.0)
    return u ** 3 * (10.0 - 15.0 * u + 6.0 * u * u)


@dataclass(frozen=True)
class Agent:
    """A simulated vehicle: its id, direction (+1 away from us along +z, -1 toward us), length
    (m), start: rear-face longitudinal coordinate along its direction (m), lateral x (m), speed
    (m/s)."""

    ident: str
    direction: int
    length_m: float
    s0_m: float
    x0_m: float
    v0_m_per_s: float


@dataclass
class TrafficResult:
    """Simulated paths: times (N,) s from -warmup_s; per agent (n, N) arrays: longitudinal rear
    position s (m, along its direction), speed v (m/s), acceleration (m s-2), lateral x (m);
    the agents, their IDM parameters, and the lane change's start time (None: none)."""

    times_s: np.ndarray
    s: np.ndarray
    v: np.ndarray
    acc: np.ndarray
    x: np.ndarray
    agents: list
    params: list
    lane_change_start_s: float | None = None

    def index(self, ident: str) -> int:
        return [a.ident for a in self.agents].index(ident)

    def gaps_m(self) -> np.ndarray:
        """(n, N) bumper-to-bumper gap of each agent to its nearest leader in the same direction
        whose lateral position is within half a lane (inf: none), from the paths."""
        n, N = self.s.shape
        out = np.full((n, N), np.inf)
        for i, a in enumerate(self.agents):
            for j, b in enumerate(self.agents):
                if i == j or a.direction != b.direction:
                    continue
                same = np.abs(self.x[i] - self.x[j]) < 0.5 * LANE_OVERLAP_M
                ahead = self.s[j] > self.s[i]
                gap = np.where(same & ahead, self.s[j] - (self.s[i] + a.length_m), np.inf)
                out[i] = np.minimum(out[i], gap)
        return out


#: Lateral distance (m) below which two vehicles' bodies overlap side by side (2 x a half width
#: of a 2.55 m bus, the EU width limit): used by `gaps_m` to check paths for collisions.
LANE_OVERLAP_M = 2.55


def driver_params(spec: TrafficSpec, agents: list[Agent]) -> list[IdmParams]:
    """Each agent's IDM parameters: the spec's, with v0 drawn as v0 (1 + speed_spread N(0, 1))
    (clipped to 0.5-1.5 v0) from `seed`, in the agents' order."""
    rng = np.random.default_rng(spec.seed)
    out = []
    for a in agents:
        base = spec.desired_speed_m_per_s if a.direction > 0 else spec.oncoming_speed_m_per_s
        f = float(np.clip(1.0 + spec.speed_spread * rng.standard_normal(), 0.5, 1.5))
        out.append(IdmParams(base * f, spec.time_headway_s, spec.min_gap_m, spec.max_accel_m_per_s2,
                             spec.comfort_decel_m_per_s2, spec.accel_exponent))
    return out


def _lanes_of(x_now: float, x_target: float | None, width: float) -> set:
    out = {round(x_now / width)}
    if x_target is not None:
        out.add(round(x_target / width))
    return out


def simulate(spec: TrafficSpec, agents: list[Agent], end_s: float) -> TrafficResult:
    """Run the traffic from t = -warmup_s (rounded up to whole steps, so t = 0 is a sample) to
    `end_s` (s) with step `step_s` (module docstring).
    Vehicles of one direction whose lanes (x / lane_width rounded; two lanes during a change)
    meet follow each other; the stop line holds the vehicles driving away from us until
    release_s."""
    dt = spec.step_s
    before = int(math.ceil(spec.warmup_s / dt - 1e-9))      # whole steps: t = 0 is a sample
    after = int(math.ceil(end_s / dt - 1e-9))
    steps = before + after
    times = dt * np.arange(-before, after + 1)
    n = len(agents)
    params = driver_params(spec, agents)
    s = np.array([a.s0_m for a in agents], float)
    v = np.array([a.v0_m_per_s for a in agents], float)
    x = np.array([a.x0_m for a in agents], float)
    S, V, A, X = (np.zeros((n, steps + 1)) for _ in range(4))
    lc = next((i for i, a in enumerate(agents) if a.ident == spec.lane_change_vehicle), None)
    lc_start, lc_from = None, None
    stop_s = spec.stop_line_m if spec.stop_line_m >= 0 else None

    def accel_all(t, s, v, x, moving):
        """IDM accelerations of every agent at time t; `moving`: the agent changing lane (both lanes)."""
        lanes = [_lanes_of(x[i], spec.lane_change_to_x_m if i == moving else None, spec.lane_width_m)
                 for i in range(n)]
        acc = np.empty(n)
        for i, a in enumerate(agents):
            gap, vl = math.inf, 0.0
            for j, b in enumerate(agents):
                if j == i or b.direction != a.direction or not (lanes[i] & lanes[j]) or s[j] <= s[i]:
                    continue
                g = s[j] - (s[i] + a.length_m)
                if g < gap:
                    gap, vl = g, v[j]
            if stop_s is not None and a.direction > 0 and t < spec.release_s and s[i] + a.length_m <= stop_s + 1e-6:
                g = stop_s - (s[i] + a.length_m)
                if g < gap:
                    gap, vl = g, 0.0
            acc[i] = float(idm_accel(v[i], gap, v[i] - vl, params[i]))
        return acc

    def safe_to_change(s, v, x):
        """MOBIL's safety criterion for agent `lc` moving into the target lane now."""
        trial = x.copy()
        trial[lc] = spec.lane_change_to_x_m
        target = round(spec.lane_change_to_x_m / spec.lane_width_m)
        a = agents[lc]
        for j, b in enumerate(agents):
            if j == lc or b.direction != a.direction or round(x[j] / spec.lane_width_m) != target:
                continue
            if s[j] <= s[lc]:                     # the new follower
                gap = s[lc] - (s[j] + b.length_m)
                if gap <= 0 or idm_accel(v[j], gap, v[j] - v[lc], params[j]) < -spec.safe_decel_m_per_s2:
                    return False
            elif s[j] - (s[lc] + a.length_m) <= 0:   # overlaps the new leader
                return False
        return True

    for k, t in enumerate(times):
        moving = None
        if lc is not None:
            if lc_start is None and t >= spec.lane_change_start_s - 1e-9 and safe_to_change(s, v, x):
                lc_start, lc_from = t, x[lc]
            if lc_start is not None:
                u = (t - lc_start) / spec.lane_change_duration_s
                x[lc] = lc_from + (spec.lane_change_to_x_m - lc_from) * float(min_jerk(u))
                if u < 1.0:
                    moving = lc
        acc = accel_all(t, s, v, x, moving)
        S[:, k], V[:, k], A[:, k], X[:, k] = s, v, acc, x
        if k < steps:
            s, v = ballistic_step(s, v, acc, dt)
    return TrafficResult(times, S, V, A, X, list(agents), params, lc_start)


def agents_of(vehicles, motions) -> tuple[list[Agent], dict[str, str]]:
    """The agents of the [motion] entries of kind "traffic" ({motion id: vehicle id} as well):
    direction from the vehicle's heading (0: +1, 180: -1), rear position along it, initial speed
    the velocity's component along it. ValueError(key, message) on a vehicle that is not
    there or whose heading is neither 0 nor 180 degrees."""
    from poevp_optics.sources.vehicles import shape_of

    agents, owner = [], {}
    for mid, m in motions.items():
        if m.kind != "traffic":
            continue
        vid = m.vehicle
        if vid not in vehicles:
            raise TrafficError(f"motion.{mid}.vehicle", f"{vid!r} names no [vehicle.<id>] "
                               f"(vehicles: {', '.join(vehicles) or 'none'})")
        if vid in owner.values():
            raise TrafficError(f"motion.{mid}.vehicle", f"{vid!r} is moved by another [motion] entry already")
        veh = vehicles[vid]
        h = veh.heading_deg % 360.0
        if not (abs(h) < 1e-9 or abs(h - 180.0) < 1e-9):
            raise TrafficError(f"vehicle.{vid}.heading_deg", f"traffic drives along the road: heading 0 "
                               f"(away from us) or 180 (toward us), got {veh.heading_deg:g}")
        d = 1 if abs(h) < 1e-9 else -1
        x, z = veh.position_m
        agents.append(Agent(vid, d, shape_of(veh).length_m, d * z, x, max(0.0, d * m.velocity_m_per_s[2])))
        owner[mid] = vid
    return agents, owner


class TrafficError(ValueError):
    """A traffic input that does not work; `key` names the scene key."""

    def __init__(self, key: str, msg: str):
        super().__init__(msg)
        self.key = key


def traffic_motions(spec: TrafficSpec, vehicles, motions, end_s: float) -> dict:
    """`motions` with each kind = "traffic" entry replaced by the `keyframes` motion of its
    vehicle's simulated path from t = -warmup_s to end_s (module docstring); others unchanged.
    TrafficError(key, message) on bad input."""
    import dataclasses

    agents, owner = agents_of(vehicles, motions)
    if not agents:
        return dict(motions)
    if spec.lane_change_vehicle and spec.lane_change_vehicle not in [a.ident for a in agents]:
        raise TrafficError("traffic.lane_change_vehicle", f"{spec.lane_change_vehicle!r} is no vehicle moved by "
                           "traffic (a [motion] entry of kind 'traffic' with vehicle = that id)")
    res = simulate(spec, agents, end_s)
    out = dict(motions)
    keep = res.times_s >= -1e-9                    # the run's span: t = 0 on
    for mid, vid in owner.items():
        i = res.index(vid)
        a = agents[i]
        offs = np.stack([res.x[i] - a.x0_m, np.zeros_like(res.x[i]), a.direction * (res.s[i] - a.s0_m)], axis=1)[keep]
        out[mid] = dataclasses.replace(motions[mid], kind="keyframes", velocity_m_per_s=(0.0, 0.0, 0.0),
                                       times_s=tuple(max(0.0, float(t)) for t in res.times_s[keep]),
                                       offsets_m=tuple(tuple(float(c) for c in o) for o in offs), vehicle="")
    return out


def resolve_scene_traffic(ctx, spec: TrafficSpec, vehicles, motions, timing):
    """The scene loader's step: `traffic_motions` over the run (t up to (frames + 1) / fps),
    a TrafficError as `ctx.fail` (one line naming the file and the key)."""
    from types import MappingProxyType

    for mid, m in motions.items():
        if m.vehicle and m.kind != "traffic":
            raise ctx.fail(f"motion.{mid}.vehicle", f"only kind = 'traffic' takes a vehicle (this entry is {m.kind!r})")
    if not any(m.kind == "traffic" for m in motions.values()):
        return motions
    try:
        return MappingProxyType(traffic_motions(spec, vehicles, motions, (timing.frames + 1) / timing.fps))
    except TrafficError as e:
        raise ctx.fail(e.key, str(e)) from None
