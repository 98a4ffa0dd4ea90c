"""DMD: grayscale mask -> binary bit-plane PWM -> per-mirror time weights over the exposure.

Parameter table (`[dmd]`, `[timing]`):

| key                  | type  | unit | default   | sweepable | meaning |
|----------------------|-------|------|-----------|-----------|---------|
| bits                 | int   | bit  | 8         | yes | B bit-planes, durations t_D 2^b / (2^B - 1) |
| bit_order            | str   | -    | lsb_first | yes | order of the planes inside the window |
| contrast_ratio       | float | -    | 1000      | yes | off-state leakage = 1 / contrast_ratio |
| fill_factor          | float | -    | 0.92      | yes | mirror area fraction (DLP6500 ~0.92) |
| reflectance          | float | -    | 0.88      | yes | aluminium mirror reflectance x window transmission |
| settle_s             | float | s    | 0         | yes | mirror transition time per switch (linear ramp) |
| controller           | str   | -    | ideal     | no  | device limits (DMD_CONTROLLERS): `ideal` none; `dlpc900_dlp6500`, `dlpc900_dlp9000` |
| dmd_window_s         | float | s    | 1/60      | yes | t_D, display window |
| dmd_window_offset_s  | float | s    | 0         | yes | window start from the frame start |
| outside_window       | str   | -    | white     | yes | mirrors all on ("white") or off ("dark") outside the window |

Sources: bit-plane PWM with binary-weighted durations and white fill outside t_D (paper Sec. 7,
Fig. 7; TI DLPC900 programmer's guide, pattern sequences); mirror reset + motion ~4.5 + 8 us
(DLP9500 data, FACTS.md); contrast ratio 1000:1-2000:1 typical (TI application notes).

Device limits (`controller`, FACTS.md; TI DLPC900 datasheet DLPS037 and programmer's guide
DLPU018; TI E2E thread 953168): a bit-plane is shown for at least 105 us (the load-and-flip time
of one 1-bit pattern); TI reaches an 8-bit pattern in 4.046 ms only by gating the *illumination*
during the three shortest planes (dark time after each). A POE-VP camera modulates the scene's
own light, which it cannot gate, so its shortest plane t_D / (2^B - 1) must itself last 105 us:
an 8-bit window needs t_D >= 255 x 105 us = 26.775 ms. The controller stores 400 1-bit patterns
(DLP6500; 480 on the DLP9000); a mask of B planes is shown while the next one loads, so
2 B <= storage. A scene whose timing breaks a limit is a one-line error naming the keys
(`timing_problem`, scene validation); `ideal` (the default) has none, for studies of the optics.

Model: a mirror's on-state level m(t) in [0, 1] is piecewise linear: constant within a plane,
ramping at slope 1/settle_s toward the new state after each plane boundary (a ramp cut short by
the next boundary continues from the level reached). The light reaching the relay is
throughput * (m + (1 - m) / contrast_ratio). The scene radiance L(t) is known at K nodes in
time (`node_times_s`: the exposure's ends and K - 2 equally spaced times between them; its
midpoint for K = 1) and taken as piecewise linear between them, so a mirror at level v collects
sum_j W_j(v) L_j with W_j(v) = int m_v(t) phi_j(t) dt, phi_j the hat function of node j. Because
m depends on the mirror only through its grey level v, these integrals are computed exactly,
once, for every level in closed form (float64 `on_time_table`: Simpson's rule is exact for the
piecewise-quadratic m phi), and each mirror then looks up its level (a DrJit gather): exact for
any schedule, bit order and window offset, and second order in 1/K for every level.
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np

from poevp_optics.camera.registration import RegistrationSpec
from poevp_optics.core.params import param
from poevp_optics.core.registry import Registry
from poevp_optics.core.timing import (Schedule, TimingSpec, node_time_weights_s, node_times_s,  # noqa: F401
                                       switch_times_s)


@dataclass(frozen=True)
class DMDController:
    """Limits of a DMD controller: shortest bit-plane the camera can use (s), 1-bit pattern
    storage, and the vendor's shortest B-bit pattern with illumination gating (s, by B)."""

    min_plane_s: float
    storage_patterns: int
    gated_min_pattern_s: dict


DMD_CONTROLLERS = Registry("DMD controller")
DMD_CONTROLLERS.register("ideal", DMDController(0.0, 1 << 30, {}), source="no device limits")
DMD_CONTROLLERS.register("dlpc900_dlp6500", DMDController(105e-6, 400, {1: 105e-6, 8: 4046e-6}),
                         source="TI DLPC900 (DLPS037, DLPU018), DLP6500: 105 us 1-bit, 4.046 ms gated 8-bit, 400 patterns")
DMD_CONTROLLERS.register("dlpc900_dlp9000", DMDController(105e-6, 480, {1: 105e-6, 8: 4046e-6}),
                         source="TI DLPC900 (DLPS037, DLPU018), DLP9000: 105 us 1-bit, 4.046 ms gated 8-bit, 480 patterns")


@dataclass(frozen=True)
class DMDSpec:
    """[dmd]: micromirror array and its PWM (TI DLP6500 + DLPC900 defaults, FACTS.md)."""

    enabled: bool = param(True)
    bits: int = param(8, min=1, max=16)
    bit_order: str = param("lsb_first", choices=("lsb_first", "msb_first"))
    contrast_ratio: float = param(1000.0, gt=1.0, why="at 1:1 an off mirror passes as much light as an on "
                                  "mirror, so no mask could dim anything")
    fill_factor: float = param(0.92, gt=0, max=1.0)
    reflectance: float = param(0.88, gt=0, max=1.0)
    settle_s: float = param(0.0, min=0, max=1.0)
    pitch_m: float = param(7.56e-6, gt=0, max=1e-3)
    controller: str = param("ideal", choices=DMD_CONTROLLERS)
    registration: RegistrationSpec = param(RegistrationSpec())


def timing_problem(dmd: DMDSpec, timing: TimingSpec) -> tuple[str, str] | None:
    """(key, message) when the controller cannot show this PWM timing (module docstring), else
    None."""
    c = DMD_CONTROLLERS[dmd.controller]
    n = (1 << dmd.bits) - 1
    shortest = timing.dmd_window_s / n
    if shortest < c.min_plane_s * (1 - 1e-12):
        gated = c.gated_min_pattern_s.get(dmd.bits)
        why = (f"; the vendor's {dmd.bits}-bit {gated * 1e3:.3f} ms pattern gates the illumination during "
               "the short planes, which a camera modulating the scene's own light cannot do") if gated else ""
        return ("timing.dmd_window_s",
                f"{dmd.controller} shows a bit-plane for >= {c.min_plane_s * 1e6:.0f} us, but a {dmd.bits}-bit "
                f"window of {timing.dmd_window_s * 1e3:.3f} ms has a shortest plane of {shortest * 1e6:.1f} us "
                f"(t_D / {n}){why}: lengthen timing.dmd_window_s to >= {n * c.min_plane_s * 1e3:.3f} ms or "
                f"lower dmd.bits")
    if 2 * dmd.bits > c.storage_patterns:
        return ("dmd.bits", f"{dmd.controller} stores {c.storage_patterns} 1-bit patterns; showing one "
                f"{dmd.bits}-plane mask while loading the next needs {2 * dmd.bits}")
    return None


def frame_schedule(dmd_spec, timing, frame_start_s: float, fx) -> Schedule:
    """Frame's bit-plane schedule under an exposure choice `fx` (control/exposure_time.py
    FrameExposure: exposure_s, bits, window_s, nominal; None or nominal: the scene's own,
    `Schedule.for_frame`): exposure of fx.exposure_s centred on the scene's exposure, the
    window of fx.window_s centred on it too (= the exposure unless a binary pattern outlasts it),
    fx.bits planes."""
    if fx is None or fx.nominal:
        return Schedule.for_frame(dmd_spec, timing, frame_start_s)
    mid = frame_start_s + timing.exposure_offset_s + 0.5 * timing.exposure_s
    return Schedule(mid - 0.5 * fx.exposure_s, fx.exposure_s, mid - 0.5 * fx.window_s, fx.window_s,
                    timing.outside_window == "white", fx.bits, dmd_spec.bit_order == "msb_first",
                    dmd_spec.settle_s)


def _segments(levels: np.ndarray, sched: Schedule):
    """Piecewise-linear m(t) for each grey level: arrays (V, S) of t0, t1, m0, m1."""
    v = levels.astype(np.int64)
    t_lo = min(sched.exposure_start_s, sched.window_start_s)
    t_hi = max(sched.exposure_start_s + sched.exposure_s, sched.window_start_s + sched.window_s)
    outside = 1.0 if sched.outside_on else 0.0
    events = [(t_lo, np.full(v.shape, outside))]
    for b, t0, _ in sched.plane_intervals():
        shown = sched.planes_from_s <= t0 < sched.planes_until_s
        events.append((t0, ((v >> b) & 1).astype(np.float64) if shown else np.zeros(v.shape)))
    events.append((sched.window_start_s + sched.window_s, np.full(v.shape, outside)))
    events.append((max(t_hi, sched.window_start_s + sched.window_s), np.full(v.shape, outside)))
    t0s, t1s, m0s, m1s = [], [], [], []
    level = np.full(v.shape, outside)
    for (ta, target), (tb, _) in zip(events[:-1], events[1:]):
        span = tb - ta
        if span <= 0:
            continue
        if sched.settle_s <= 0:
            level = target.copy()
            t0s += [np.full(v.shape, ta)]; t1s += [np.full(v.shape, tb)]
            m0s += [level]; m1s += [level]
            continue
        reach = np.abs(target - level) * sched.settle_s        # time to finish the ramp
        t_ramp_end = ta + np.minimum(reach, span)
        step = np.sign(target - level) * (t_ramp_end - ta) / sched.settle_s
        ramp_end_level = level + step
        t0s += [np.full(v.shape, ta), t_ramp_end]
        t1s += [t_ramp_end, np.full(v.shape, tb)]
        m0s += [level, ramp_end_level]
        m1s += [ramp_end_level, ramp_end_level]
        level = ramp_end_level
    return (np.stack(t0s, 1), np.stack(t1s, 1), np.stack(m0s, 1), np.stack(m1s, 1))


def _nodes_rel(sched: "Schedule", nodes) -> np.ndarray:
    """Node times relative to the exposure start (s): an int K means K uniform nodes. Nodes
    given as times must include both ends of the exposure, or reach beyond them on both sides
    (the scene's nodes around a per-frame shortened exposure, control/exposure_time.py)."""
    if np.isscalar(nodes):
        return node_times_s(0.0, sched.exposure_s, int(nodes))
    rel = np.asarray(nodes, dtype=np.float64)
    if rel.ndim != 1 or rel.size < 1 or np.any(np.diff(rel) <= 0):
        raise ValueError("radiance nodes must be a non-empty increasing array of times")
    tol = 1e-9 * sched.exposure_s
    if rel.size > 1 and (rel[0] > tol or rel[-1] < sched.exposure_s - tol):
        raise ValueError("radiance nodes must include both ends of the exposure")
    return rel


def _covers_beyond(sched: "Schedule", rel: np.ndarray) -> bool:
    """True when the nodes reach beyond the exposure (a shortened exposure inside the scene's)."""
    tol = 1e-9 * sched.exposure_s
    return rel.size > 1 and (rel[0] < -tol or rel[-1] > sched.exposure_s + tol)


def node_weights_s(sched: "Schedule", rel: np.ndarray) -> np.ndarray:
    """Integral over the exposure [0, exposure_s] of each node's hat function (s): the
    trapezoid weights (`node_time_weights_s`) when the nodes span the exposure exactly, else
    the hats cut at the exposure's ends (exact: int over [c0, c1] of the linear hat pieces)."""
    if not _covers_beyond(sched, rel):
        return node_time_weights_s(sched.exposure_s, rel)
    lo, hi = rel[:-1], rel[1:]
    h = hi - lo
    c0, c1 = np.clip(0.0, lo, hi), np.clip(sched.exposure_s, lo, hi)
    a = c1 - c0                                            # int 1 dt over the interval's part
    b = 0.5 * ((c1 - lo) ** 2 - (c0 - lo) ** 2)            # int (t - t_j) dt
    w = np.zeros(rel.size)
    w[:-1] += a - b / h
    w[1:] += b / h
    return w


def displayed_levels(levels, mask_bits: int, plane_bits: int) -> np.ndarray:
    """The level each mirror shows when a `mask_bits` mask is displayed with `plane_bits`
    bit-planes: its `plane_bits` most significant bits (the DLPC900 takes a B-bit pattern from
    a bit field of the stored image; DLPU018, pattern display LUT), v >> (mask_bits - plane_bits);
    the mask itself when the depths agree."""
    v = np.asarray(levels)
    shift = mask_bits - plane_bits
    if shift <= 0:
        return v
    return (v.astype(np.int64) >> shift)


#: Cells (levels x segments x intervals) evaluated per block, bounding the memory of the tables.
_BLOCK_CELLS = 1 << 21


def _interval_moments(levels: np.ndarray, sched: Schedule, edges_rel: np.ndarray, shutter: bool = False):
    """Zeroth and first moments of the mirror level m(t) over each interval [e_i, e_i+1]
    (times relative to the exposure start, s): A_i = int m dt and B_i = int m (t - e_i) dt,
    arrays (len(levels), len(edges) - 1), float64. m is piecewise linear, so A is exact by the
    trapezoid rule and B (quadratic integrand) by Simpson's rule. shutter: the sensor integrates
    only over the exposure [0, exposure_s], which intervals may reach beyond (nodes around a
    shortened exposure): each interval is cut to it."""
    levels = np.asarray(levels)
    t0, t1, m0, m1 = _segments(levels, sched)
    t0, t1 = t0 - sched.exposure_start_s, t1 - sched.exposure_start_s
    dur = t1 - t0
    slope = np.divide(m1 - m0, dur, out=np.zeros_like(dur), where=dur > 0)
    n_int = len(edges_rel) - 1
    v_all, s_all = t0.shape
    A = np.empty((v_all, n_int))
    B = np.empty((v_all, n_int))
    step_i = max(1, min(n_int, _BLOCK_CELLS // max(1, v_all * s_all)))
    step_v = max(1, min(v_all, _BLOCK_CELLS // max(1, s_all * step_i)))
    for v0 in range(0, v_all, step_v):
        vs = slice(v0, v0 + step_v)
        a0, a1, am0, asl = (x[vs, :, None] for x in (t0, t1, m0, slope))
        for i0 in range(0, n_int, step_i):
            i1 = min(i0 + step_i, n_int)
            lo = edges_rel[None, None, i0:i1]
            hi = edges_rel[None, None, i0 + 1:i1 + 1]
            if shutter:
                lo_c = np.maximum(lo, 0.0)
                hi_c = np.maximum(np.minimum(hi, sched.exposure_s), lo_c)
                c0, c1 = np.clip(a0, lo_c, hi_c), np.clip(a1, lo_c, hi_c)
            else:
                c0 = np.clip(a0, lo, hi)
                c1 = np.clip(a1, lo, hi)
            w = c1 - c0
            mc0 = am0 + asl * (c0 - a0)
            mc1 = am0 + asl * (c1 - a0)
            A[vs, i0:i1] = np.sum(w * (mc0 + mc1) * 0.5, axis=1)
            mid = 0.5 * (c0 + c1)
            B[vs, i0:i1] = np.sum(
                w / 6.0 * (mc0 * (c0 - lo) + 2.0 * (mc0 + mc1) * (mid - lo) + mc1 * (c1 - lo)), axis=1)
    return A, B


def on_time_table(levels: np.ndarray, sched: Schedule, nodes) -> np.ndarray:
    """Exact on-state time (s) of mirrors at each grey level weighted by each node's hat function:
    W_j(v) = int m_v(t) phi_j(t) dt over the exposure, array (len(levels), K), float64.
    `nodes`: an int K (uniform nodes, `node_times_s`) or node times relative to the exposure
    start (a single node: phi = 1 over the whole exposure).

    With radiance samples L_j at the nodes, the capture integral int m_v(t) L(t) dt is
    sum_j W_j(v) L_j for the piecewise-linear interpolant of L: second order in the node spacing
    for a smooth L(t), however the on-time of a level is placed in time (a midpoint rule on K
    sub-intervals is only first order when a level's few short planes sit off a sub-interval's
    centre). Every W_j >= 0 and sum_j W_j(v) is the exact total on-time.
    """
    rel = _nodes_rel(sched, nodes)
    if rel.size == 1:
        return _interval_moments(levels, sched, np.array([0.0, sched.exposure_s]))[0]
    A, B = _interval_moments(levels, sched, rel, _covers_beyond(sched, rel))
    h = np.diff(rel)[None, :]
    out = np.zeros((A.shape[0], rel.size))
    out[:, :-1] += A - B / h            # falling half of hat j over [t_j, t_j+1]
    out[:, 1:] += B / h                 # rising half of hat j over [t_j-1, t_j]
    return np.maximum(out, 0.0)         # A - B/h >= 0 exactly; drop -1e-18 rounding


def interval_on_time_table(levels: np.ndarray, sched: Schedule, k: int) -> np.ndarray:
    """Exact on-state time (s) of each level in each of K equal sub-intervals of the exposure,
    (len(levels), K): the weights of the midpoint-product rule (each sub-interval's on-time times
    the radiance at its centre), first order in 1/K. Kept for comparisons (benchmarks)."""
    edges = sched.exposure_s * np.arange(k + 1) / k
    edges[-1] = sched.exposure_s
    return _interval_moments(levels, sched, edges)[0]


def throughput_on(dmd: DMDSpec) -> float:
    """Fraction of incident light an on-state mirror sends to the relay: fill x reflectance."""
    return dmd.fill_factor * dmd.reflectance


def transmission_table(levels: np.ndarray, dmd: DMDSpec, sched: Schedule, nodes) -> np.ndarray:
    """Effective exposure time (s) per level and radiance node, with throughput and leakage:
    throughput * (W_j + (w_j - W_j) / contrast_ratio), W from `on_time_table`, w_j the node's
    time weight. `nodes` as in `on_time_table`. Array (len(levels), K), float64."""
    t_on = on_time_table(levels, sched, nodes)
    dt = node_weights_s(sched, _nodes_rel(sched, nodes))[None, :]
    return throughput_on(dmd) * (t_on + (dt - t_on) / dmd.contrast_ratio)


def interval_transmission(levels: np.ndarray, dmd: DMDSpec, sched: Schedule, a: float, b: float) -> np.ndarray:
    """Effective exposure time (s) of each level over an arbitrary interval [a, b] (exact)."""
    edges = np.array([a, b], dtype=np.float64) - sched.exposure_start_s
    on = _interval_moments(np.asarray(levels), sched, edges)[0][:, 0]
    return throughput_on(dmd) * (on + ((b - a) - on) / dmd.contrast_ratio)


def attenuation_floor(dmd: DMDSpec, sched: Schedule) -> dict:
    """Lowest achievable exposure relative to an all-white mask, and what sets it."""
    full = (1 << sched.bits) - 1
    table = transmission_table(np.array([0, 1, full]), dmd, sched, 1)[:, 0]
    zero, one, white = table
    t_on_zero = on_time_table(np.array([0]), sched, 1)[0, 0]
    return {"floor": float(zero / white), "floor_db": float(-20 * np.log10(max(zero / white, 1e-300))),
            "smallest_step": float((one - zero) / white),
            "white_fill_fraction": float(t_on_zero / sched.exposure_s),
            "leakage_fraction": float(1 / dmd.contrast_ratio)}


def attenuation_parts(dmd_spec, sched, min_level: int) -> dict:
    """The darkest usable mask level's exposure relative to white, split into its causes:
    white fill (DMD white outside its window), off-state leakage (1/contrast) and the PWM
    step of `min_level` (the mask bit depth). Exact from the DMD's level table."""
    import dataclasses
    import math

    top = (1 << sched.bits) - 1
    lv = np.array([min_level, top])
    tbl = transmission_table(lv, dmd_spec, sched, 1)[:, 0]
    floor = float(tbl[0] / tbl[1])
    ideal = dataclasses.replace(dmd_spec, contrast_ratio=1e300)
    tbl_ideal = transmission_table(lv, ideal, sched, 1)[:, 0]
    no_leak = float(tbl_ideal[0] / tbl_ideal[1])
    fill = float(on_time_table(np.array([0]), sched, 1)[0, 0] / on_time_table(np.array([top]), sched, 1)[0, 0])
    parts = {"white_fill": fill, "dmd_contrast": max(floor - no_leak, 0.0),
             "mask_bit_depth": max(no_leak - fill, 0.0)}
    return {"floor": floor, "gain_db": float(-20 * math.log10(floor)) if floor > 0 else math.inf,
            "parts": parts, "binding": max(parts, key=parts.get)}


def late_schedules(sched: Schedule, switch_s: float) -> tuple[Schedule, Schedule]:
    """A window in which a late mask takes over at `switch_s` (absolute, s): the DLPC900 latches
    a pattern per bit-plane, so planes starting before the switch show the previous mask, planes
    starting at or after it the new one (TI DLPC900 programmer's guide, pattern sequences).
    Returns (old: its planes and the white/dark fill outside the window, new: its planes only);
    a mirror's on-time is the sum of its old level's on-time in the first and its new level's in
    the second (exact for settle_s = 0; with settle_s > 0 the one ramp at the switch is taken from
    the off state, an error below settle_s per mirror)."""
    import dataclasses

    return (dataclasses.replace(sched, planes_until_s=switch_s),
            dataclasses.replace(sched, planes_from_s=switch_s, outside_on=False))


class DMD:
    """Per-mirror effective exposure of a mask (DrJit gather from the exact level table)."""

    #: Full per-level tables are used up to this many entries (levels x K), else only the
    #: levels present in the mask are tabulated.
    FULL_TABLE_MAX = 1 << 22

    def __init__(self, dmd: DMDSpec, full_table_max: int = FULL_TABLE_MAX):
        """full_table_max: levels x nodes up to which every level is tabulated (Accuracy)."""
        self.spec = dmd
        self.full_table_max = full_table_max
        self.levels = (1 << dmd.bits) - 1
        self._cache = {}

    def _full_table(self, sched: Schedule, rel: np.ndarray):
        """Float32 DrJit table of all levels x K, cached: it depends only on the schedule and the
        nodes relative to the frame start, which are the same for every frame."""
        from drjit.auto import Float

        key = (round(sched.exposure_start_s - sched.window_start_s, 15), sched.exposure_s,
               sched.window_s, sched.outside_on, sched.bits, sched.msb_first, sched.settle_s,
               tuple(np.round(rel / sched.exposure_s, 12)),
               round(sched.planes_from_s - sched.window_start_s, 15),
               round(sched.planes_until_s - sched.window_start_s, 15))
        if key not in self._cache:
            table = transmission_table(self.shown(np.arange(self.levels + 1), sched), self.spec, sched, rel)
            self._cache = {key: (Float(table.T.astype(np.float32).ravel()), table)}
        return self._cache[key]

    def shown(self, levels: np.ndarray, sched: Schedule) -> np.ndarray:
        """The levels the mirrors show under `sched`: the mask's top sched.bits bits when the
        frame's window holds fewer planes than the mask has bits (`displayed_levels`)."""
        return displayed_levels(levels, self.spec.bits, sched.bits)

    def _level_index(self, mask_levels: np.ndarray) -> np.ndarray:
        """Mask levels as uint32 indices (flattened); out-of-range or non-finite is an error."""
        m = np.asarray(mask_levels)
        if m.size and (m.min() < 0 or m.max() > self.levels or not np.all(np.isfinite(m))):
            raise ValueError(f"mask levels must lie in [0, {self.levels}], got "
                             f"[{m.min()}, {m.max()}]")
        return np.rint(m).astype(np.uint32).ravel()

    def table_weights(self, mask_levels: np.ndarray, tables: list[np.ndarray]):
        """Per-mirror weights from arbitrary per-level tables (each (levels + 1,), seconds):
        list of DrJit Floats, one per table (emitter-group bases of flickering lamps)."""
        import drjit as dr
        from drjit.auto import Float, UInt32

        idx = UInt32(self._level_index(mask_levels))
        return [dr.gather(Float, Float(np.asarray(t, np.float32)), idx) for t in tables]

    def exposure_weights(self, mask_levels: np.ndarray, sched: Schedule, nodes):
        """Effective exposure (s) of each mirror for each radiance node (`on_time_table`): list of
        K DrJit Float arrays (flattened mirror grid), plus the per-level table used (float64)."""
        import drjit as dr
        from drjit.auto import Float, UInt32

        mi = self._level_index(mask_levels)
        rel = _nodes_rel(sched, nodes)
        k = rel.size
        if (self.levels + 1) * k <= self.full_table_max:
            flat, table = self._full_table(sched, rel)
            idx = UInt32(mi)
            u = self.levels + 1
            return [dr.gather(Float, flat, idx + j * u) for j in range(k)], table
        uniq, inverse = np.unique(mi, return_inverse=True)
        table = transmission_table(self.shown(uniq, sched), self.spec, sched, rel)        # (U, K)
        idx = UInt32(inverse.astype(np.uint32))
        flat = Float(table.T.astype(np.float32).ravel())               # K blocks of U
        u = len(uniq)
        return [dr.gather(Float, flat, idx + j * u) for j in range(k)], table

    def late_exposure_weights(self, old_levels: np.ndarray, new_levels: np.ndarray, sched: Schedule,
                              nodes, switch_s: float):
        """Effective exposure (s) per mirror and radiance node when the mask changes from
        `old_levels` to `new_levels` at `switch_s` inside the window (`late_schedules`):
        throughput ((W_old + W_new)(1 - 1/CR) + w_j / CR), W the on-time tables of the two parts.
        List of K DrJit Floats and the two per-level tables (float64)."""
        import drjit as dr
        from drjit.auto import Float, UInt32

        sa, sb = late_schedules(sched, switch_s)
        rel = _nodes_rel(sched, nodes)
        levels = self.shown(np.arange(self.levels + 1), sched)
        ta = transmission_table(levels, self.spec, sa, rel)                     # with leakage
        tb = throughput_on(self.spec) * (1 - 1 / self.spec.contrast_ratio) * on_time_table(levels, sb, rel)
        ia, ib = UInt32(self._level_index(old_levels)), UInt32(self._level_index(new_levels))
        u = self.levels + 1
        fa, fb = Float(ta.T.astype(np.float32).ravel()), Float(tb.T.astype(np.float32).ravel())
        w = [dr.gather(Float, fa, ia + j * u) + dr.gather(Float, fb, ib + j * u) for j in range(rel.size)]
        return w, (ta, tb)
