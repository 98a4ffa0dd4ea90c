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
| dmd_window_s         | float | s    | 1/60      | yes | t_D, display window |
| dmd_window_offset_s  | float | s    | 0         | yes | window start from the frame start |
| outside_window       | str   | -    | white     | yes | mirrors all on ("white") or off ("dark") outside the window |

Sources: bit-plane PWM with binary-weighted durations and white fill outside t_D (paper Sec. 7,
Fig. 7; TI DLPC900 programmer's guide, pattern sequences); mirror reset + motion ~4.5 + 8 us
(DLP9500 data, FACTS.md); contrast ratio 1000:1-2000:1 typical (TI application notes).

Model: a mirror's on-state level m(t) in [0, 1] is piecewise linear: constant within a plane,
ramping at slope 1/settle_s toward the new state after each plane boundary (a ramp cut short by
the next boundary continues from the level reached). The light reaching the relay is
throughput * (m + (1 - m) / contrast_ratio). Because m depends on the mirror only through its
grey level v, the time integral of m over each of the K sub-intervals of the exposure is computed
exactly, once, for every level v in closed form (float64 `weight_table`), and each mirror then
looks up its level (a DrJit gather): exact for any schedule, bit order and window offset.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import DMDSpec, TimingSpec


@dataclass(frozen=True)
class Schedule:
    """Absolute times (s) of the exposure and display window of one frame."""

    exposure_start_s: float
    exposure_s: float
    window_start_s: float
    window_s: float
    outside_on: bool
    bits: int
    msb_first: bool
    settle_s: float

    @classmethod
    def for_frame(cls, dmd: DMDSpec, timing: TimingSpec, frame_start_s: float) -> "Schedule":
        return cls(frame_start_s + timing.exposure_offset_s, timing.exposure_s,
                   frame_start_s + timing.dmd_window_offset_s, timing.dmd_window_s,
                   timing.outside_window == "white", dmd.bits, dmd.bit_order == "msb_first",
                   dmd.settle_s)

    def plane_intervals(self) -> list[tuple[int, float, float]]:
        """(bit, start_s, end_s) of each bit-plane, in display order."""
        n = (1 << self.bits) - 1
        order = range(self.bits - 1, -1, -1) if self.msb_first else range(self.bits)
        out, t = [], self.window_start_s
        for b in order:
            d = self.window_s * (1 << b) / n
            out.append((b, t, t + d))
            t += d
        return out


def _segments(levels: np.ndarray, sched: Schedule):
    """Piecewise-linear m(t) for each grey level: arrays (V, S) of t0, t1, m0, m1."""
    v = levels.astype(np.int64)
    t_lo = min(sched.exposure_start_s, sched.window_start_s)
    t_hi = max(sched.exposure_start_s + sched.exposure_s, sched.window_start_s + sched.window_s)
    outside = 1.0 if sched.outside_on else 0.0
    events = [(t_lo, np.full(v.shape, outside))]
    for b, t0, _ in sched.plane_intervals():
        events.append((t0, ((v >> b) & 1).astype(np.float64)))
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


def _cumulative(u: np.ndarray, seg) -> np.ndarray:
    """Integral of m(t) from -inf to each time u (K+1,), per level: (V, K+1)."""
    t0, t1, m0, m1 = (a[:, :, None] for a in seg)
    c = np.clip(u[None, None, :], t0, t1)
    dur = t1 - t0
    slope = np.divide(m1 - m0, dur, out=np.zeros_like(dur), where=dur > 0)
    mc = m0 + slope * (c - t0)
    return np.sum((c - t0) * (m0 + mc) * 0.5, axis=1)


def on_time_table(levels: np.ndarray, sched: Schedule, k: int) -> np.ndarray:
    """Exact on-state time (s) of mirrors at each grey level in each of K equal sub-intervals
    of the exposure: array (len(levels), k), float64."""
    u = sched.exposure_start_s + np.arange(k + 1) * (sched.exposure_s / k)
    u[-1] = sched.exposure_start_s + sched.exposure_s
    cum = _cumulative(u, _segments(np.asarray(levels), sched))
    return np.diff(cum, axis=1)


def throughput_on(dmd: DMDSpec) -> float:
    """Fraction of incident light an on-state mirror sends to the relay: fill x reflectance."""
    return dmd.fill_factor * dmd.reflectance


def transmission_table(levels: np.ndarray, dmd: DMDSpec, sched: Schedule, k: int) -> np.ndarray:
    """Effective exposure time (s) per level and sub-interval, with throughput and leakage:
    throughput * (t_on + (dt - t_on) / contrast_ratio). Array (len(levels), k), float64."""
    t_on = on_time_table(levels, sched, k)
    dt = sched.exposure_s / k
    return throughput_on(dmd) * (t_on + (dt - t_on) / dmd.contrast_ratio)


def interval_transmission(levels: np.ndarray, dmd: DMDSpec, sched: Schedule, a: float, b: float) -> np.ndarray:
    """Effective exposure time (s) of each level over an arbitrary interval [a, b] (exact)."""
    c = _cumulative(np.array([a, b], dtype=np.float64), _segments(np.asarray(levels), sched))
    on = c[:, 1] - c[:, 0]
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


class DMD:
    """Per-mirror effective exposure of a mask (DrJit gather from the exact level table)."""

    #: Full per-level tables are used up to this many entries (levels x K), else only the
    #: levels present in the mask are tabulated.
    FULL_TABLE_MAX = 1 << 22

    def __init__(self, dmd: DMDSpec):
        self.spec = dmd
        self.levels = (1 << dmd.bits) - 1
        self._cache = {}

    def _full_table(self, sched: Schedule, k: int):
        """Float32 DrJit table of all levels x K, cached: it depends only on the schedule
        relative to the frame start, which is the same for every frame."""
        from drjit.auto import Float

        key = (round(sched.exposure_start_s - sched.window_start_s, 15), sched.exposure_s,
               sched.window_s, sched.outside_on, sched.bits, sched.msb_first, sched.settle_s, k)
        if key not in self._cache:
            table = transmission_table(np.arange(self.levels + 1), self.spec, sched, k)
            self._cache = {key: (Float(table.T.astype(np.float32).ravel()), table)}
        return self._cache[key]

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

    def exposure_weights(self, mask_levels: np.ndarray, sched: Schedule, k: int):
        """Effective exposure (s) of each mirror in each sub-interval: list of K DrJit Float
        arrays (flattened mirror grid), plus the per-level table used (float64)."""
        import drjit as dr
        from drjit.auto import Float, UInt32

        mi = self._level_index(mask_levels)
        if (self.levels + 1) * k <= self.FULL_TABLE_MAX:
            flat, table = self._full_table(sched, k)
            idx = UInt32(mi)
            u = self.levels + 1
            return [dr.gather(Float, flat, idx + j * u) for j in range(k)], table
        uniq, inverse = np.unique(mi, return_inverse=True)
        table = transmission_table(uniq, self.spec, sched, k)          # (U, K)
        idx = UInt32(inverse.astype(np.uint32))
        flat = Float(table.T.astype(np.float32).ravel())               # K blocks of U
        u = len(uniq)
        return [dr.gather(Float, flat, idx + j * u) for j in range(k)], table


def registration_taps(reg, mirror_shape: tuple[int, int], sensor_shape: tuple[int, int],
                      oversample: int = 4) -> tuple[np.ndarray, np.ndarray] | None:
    """Area-weighted resampling of the mirror grid onto the sensor grid, or None for 1:1.

    The affine map takes mirror coordinates m (pixel centres at integers + 0.5) to sensor
    coordinates s = scale R(rotation) (m - c_m) + c_s + offset_px, about the grid centres.
    Each sensor pixel is split into oversample^2 sub-areas, mapped back to the mirror grid and
    assigned to the mirror they land in: the sensor pixel sees the area average of the DMD-plane
    radiance over its footprint (radiance is conserved through the relay), exact to
    1/oversample^2 of a pixel's area. Sub-areas landing off the mirror array get weight 0.
    Returns (indices (N, oversample^2) into the flattened mirror grid, weights (N, oversample^2)).
    """
    if (reg.scale == 1.0 and reg.rotation_deg == 0.0 and tuple(reg.offset_px) == (0.0, 0.0)
            and tuple(mirror_shape) == tuple(sensor_shape)):
        return None
    hs, ws = sensor_shape
    hm, wm = mirror_shape
    o = (np.arange(oversample) + 0.5) / oversample
    sy, sx = np.meshgrid(np.arange(hs), np.arange(ws), indexing="ij")
    py = (sy[..., None, None] + o[None, None, :, None]).reshape(hs * ws, -1)
    px = (sx[..., None, None] + o[None, None, None, :]).reshape(hs * ws, -1)
    th = np.deg2rad(reg.rotation_deg)
    # inverse map: m = R(-theta) (s - c_s - offset) / scale + c_m   (offset_px = [dx, dy])
    dx = px - ws / 2 - reg.offset_px[0]
    dy = py - hs / 2 - reg.offset_px[1]
    mx = (np.cos(th) * dx + np.sin(th) * dy) / reg.scale + wm / 2
    my = (-np.sin(th) * dx + np.cos(th) * dy) / reg.scale + hm / 2
    ix, iy = np.floor(mx).astype(np.int64), np.floor(my).astype(np.int64)
    inside = (ix >= 0) & (ix < wm) & (iy >= 0) & (iy < hm)
    idx = np.where(inside, iy * wm + ix, 0)
    weights = inside.astype(np.float64) / oversample ** 2
    return idx, weights


def apply_registration(image_flat, taps):
    """Resample a flattened DrJit Float mirror-plane image with `registration_taps`."""
    import drjit as dr
    from drjit.auto import Float, UInt32

    idx, w = taps
    out = None
    for j in range(idx.shape[1]):
        v = dr.gather(Float, image_flat, UInt32(idx[:, j].astype(np.uint32))) * Float(w[:, j].astype(np.float32))
        out = v if out is None else out + v
    return out
