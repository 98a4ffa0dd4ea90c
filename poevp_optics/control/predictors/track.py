"""Region trackers with a longer context: where each saturated region will be one frame on,
from its displacements over the last three frames.

A mask must sit where the highlight will be, and a highlight is a clipped (or, in the
demodulated loop, over-range) region with no texture inside: what matters is where its outline
goes, not the pixels a network would synthesise (pixel losses reward blur, and a blurred
highlight is an unclipped one to the mask law). The two-frame predictors (`flow`, `dmvfn`)
assume constant velocity, so every curved, accelerating, braking or swerving path leaves the
mask behind; these predictors look three displacements back.

Per frame t (history oldest first, up to four frames):
1. **Measure.** Each connected region of frame t at or above `SATURATED` (the mask laws' clip
   marker) of at least `MIN_REGION_PX` pixels is followed back through the history: its
   translation from frame t-1 is the phase-correlation peak of the saturated outlines (flow.py
   `region_shift`: Kuglin & Hines 1975), and it is the same light as the frame t-1 region it
   lands on only when that match is mutual and the areas are alike (region_motion.py
   `match_regions`; a region left new takes back its old place from a twin lamp that took it,
   `reclaim`, or is measured again without the regions already taken, `rematch_left`, and two
   lights that took each other's old place, like lamps crossing, are exchanged where that departs
   less from the motion each had the frame before, `unswap`); that region is followed on to frame t-2 the same way, and so on:
   displacements d_t, d_{t-1}, d_{t-2} (px, x and y), each with its correlation response. A
   weak response or a lost match ends the chain; a region with no match at all is new.
   **Global motion.** Our camera pitches over road bumps and yaws as we steer, and that moves
   every light by one shift. Per frame pair, the shift most matched regions share is the
   global shift g (region_motion.py `global_shift`: a consensus of at least three regions within
   1.5 px spread over a quarter of the frame's height or more, their median; none found: 0). Each region's own motion is its displacements less g
   of the same pair, r = d - g (`RegionTrack.relative`), whatever its chain's length; the
   global chain g_t, g_{t-1}, g_{t-2} is the frame's, from all its regions.
2. **Extrapolate.** d_{t+1} = the region's own motion extrapolated + the global motion
   extrapolated (`closed_form_global`: a pitch bounce is continued as a sinusoid, steady pitch
   by the table below, the yaw by its drift). A new region, or one whose own chain is short,
   thus still moves with the camera. The own motion's next step is a combination of the measured ones,
   r_{t+1} = c_0 r_t + c_1 r_{t-1} + c_2 r_{t-2}: `track` uses the closed forms below; `track_net`
   takes the coefficients from a small trained network (track_net.py) fed only with quantities
   that do not change under rotation or mirroring of the image (lengths and dot products of the
   displacements), so it has no preferred direction by construction. A region whose own chain
   swings back and forth (its displacement changes by more than the acceleration gate twice
   running, `wavering`: the clipped outline of a standing glow, a fog halo or a lamp's wet-road
   reflection, not a vehicle) stands: it moves with the global motion alone, in both predictors.
   A region whose own chain looms (three displacements along one line, each longer, or each
   shorter, than the one before by the pinhole law of a steady closing speed: an oncoming car's
   lamps, or the road's lights as we drive at them) is continued by that law in both predictors
   (`closed_form_looming`). A region whose own chain turns at a steady speed (two turns of one
   sign between its three displacements: a vehicle on a bend or turning at a junction) is
   continued on its arc (`closed_form_turning`): in `track` from 0.05 rad a frame, in `track_net`
   only beyond the fastest turn of its training paths (slower turns, swerves and lane changes
   are the network's).
   A region's growth (linear size ratio frame to frame, from the matched regions' areas) is
   continued when the last two agree (`closed_form_growth`): an approaching light grows about
   its centroid (the shift of a growing region is its centroid's: flow.py `region_matches`).
3. **Move.** Dense DIS flow (flow.py) moves the rest of the frame as `flow` does; each region's
   pixels are forward-splatted by its extrapolated displacement (plus (g - 1) times their offset
   from its centroid when it grows by g), brightest wins, values moved exactly (a clipped pixel
   lands clipped: the clip marker survives the prediction). A region moved whole has its outline
   placed to a fraction of a pixel where the halo around its clip shows where it lies
   (subpixel_outline.py; the values inside are the whole-pixel move's), else moves to the
   nearest pixel; a growing region's spread pixels
   are joined by pasting it scaled (`grow_region`). A region where two or more lights followed
   to frame t-1 ran into one (region_merges.py) moves with them, each pixel with the nearest
   one's extrapolated motion. Any other new region moves by the global motion alone (where
   there is none: it stays where it is).

Closed-form extrapolation (`track`) with the chain length available:

| displacements | model                  | d_{t+1}                              | reference |
|---------------|------------------------|--------------------------------------|-----------|
| 1             | constant velocity      | d_t                                  | - |
| 2             | constant acceleration  | 2 d_t - d_{t-1}                      | Newton forward difference |
| 3             | least-squares constant acceleration over three differences | (4 d_t + d_{t-1} - 2 d_{t-2}) / 3 | quadratic fit of the positions |

The third row fits a quadratic in time to the four positions by least squares (a line through
the three displacements), which halves the noise gain of the two-point form (sqrt(21)/3 = 1.53
against sqrt(5) = 2.24 for equal independent errors) at the price of lagging a changing
acceleration. An acceleration is applied only when consecutive displacements agree on it (the
`track` gate: |d_t - d_{t-1}| <= ACCEL_GATE x max(|d_t|, 1 px)); a sudden reversal beyond it
falls back to the last displacement.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from poevp_optics.control.predictors.base import Predictor
from poevp_optics.control.predictors.region_merges import holders, lost_parts, part_flow
from poevp_optics.control.predictors.subpixel_outline import moved_outline, paint
from poevp_optics.control.predictors.flow import (MIN_REGION_PX, SATURATED, forward_splat, log_8bit, measure_pair,
                                                  region_matches, saturated_components)

#: Longest chain of displacements followed back (four frames of history: the loop keeps four).
MAX_CHAIN = 3
#: Largest change of displacement between frames, relative to |d_t|, still read as acceleration.
ACCEL_GATE = 1.0
#: Shortest displacement (px) whose region's outline is placed to a fraction of a pixel
#: (subpixel_outline.py); a region standing (under forward_splat's 0.5 px) is not moved at all.
SUBPIXEL_MIN_PX = 0.5


#: Per-frame growth ratios within this of 1 are read as no growth (the outline's pixel noise on a
#: region of ~1000 px moves its area by a few per cent).
GROWTH_DEADBAND = 0.01
#: Largest growth (and its inverse, shrink) per frame that is extrapolated.
MAX_GROWTH = 1.25


@dataclass(frozen=True)
class RegionTrack:
    """One saturated region of the last frame and its measured displacements (px, newest
    first: d_t, d_{t-1}, ...), each with its phase-correlation response, and its growth
    (linear size ratio frame to frame, newest first; region_motion.py `RegionMatch.growth`)."""

    label: int                              # the region's label in `region_tracks`' labels
    box: tuple[int, int, int, int]          # (y0, x0, y1, x1) in frame t
    area_px: int
    displacements: tuple[tuple[float, float], ...]
    responses: tuple[float, ...]
    growths: tuple[float, ...] = ()
    #: the frame's global shift per frame pair (px, newest first: g_t, g_{t-1}, ...; one per pair
    #: of the history, whatever this region's own chain; (0, 0) where no global motion was found)
    #: and its response: `global_chain`; the same for every region of a frame
    global_shifts: tuple[tuple[float, float], ...] = ()
    global_responses: tuple[float, ...] = ()
    #: the frame t-1 region this one is the same light as (0: none, a new region)
    prev_label: int = 0

    def relative(self) -> np.ndarray:
        """(len(displacements), 2) px: the region's own displacements less the frame's global
        shift of the same frame pair (its motion relative to the scene's common motion)."""
        d = np.asarray(self.displacements, np.float64).reshape(-1, 2)
        g = np.zeros_like(d)
        k = min(len(d), len(self.global_shifts))
        if k:
            g[:k] = np.asarray(self.global_shifts[:k], np.float64)
        return d - g


def global_chain(pairs) -> tuple[tuple[tuple[float, float], ...], tuple[float, ...]]:
    """(shifts, responses) newest first: each frame pair's global shift (region_motion.py
    `global_shift` over the pair's matched regions: the camera's pitch and yaw, or whatever
    most regions share; (0, 0) where fewer than MIN_GLOBAL_REGIONS agree). pairs: `region_tracks`'
    (labels, stats, matches) per frame pair, newest first."""
    from poevp_optics.control.region_motion import global_shift

    shifts, resp = [], []
    for labels, stats, matches in pairs:
        got = [m for m in matches.values() if m.prev_label]
        g = global_shift([m.shift for m in got], [m.response for m in got],
                         [stats[m.label, 1] + stats[m.label, 3] / 2.0 for m in got], labels.shape[0])
        shifts.append(g.shift)
        resp.append(g.response)
    return tuple(shifts), tuple(resp)


class MeasureCache:
    """The last frames' `saturated_components` and frame pairs' `measure_pair`, keyed on the
    saturated maps' bits (a BLAKE2b digest of the packed map), all they depend on. The loop calls
    a tracker on a history that slides by one frame, so three of its four frames and two of its
    three pairs were measured on the call before; results are the same objects, not recomputed
    (the predictions bit-identical to an empty cache's: tests/unit/test_track.py), read and
    never written. Holds the last `size` entries of each kind (a history's frames)."""

    def __init__(self, size: int = MAX_CHAIN + 1):
        self.size = size
        self.components: dict = {}
        self.pairs: dict = {}

    @staticmethod
    def key(sat: np.ndarray) -> tuple:
        import hashlib

        return sat.shape, hashlib.blake2b(np.packbits(sat).tobytes(), digest_size=16).digest()

    def _keep(self, store: dict, key, make):
        if key in store:
            store[key] = store.pop(key)                  # most recent last
        else:
            store[key] = make()
            while len(store) > self.size:
                store.pop(next(iter(store)))
        return store[key]

    def saturated_components(self, sat: np.ndarray, key) -> tuple:
        return self._keep(self.components, key, lambda: saturated_components(sat))

    def region_matches(self, sats, ccs, keys, prior: dict | None):
        """flow.py `region_matches` of two frames, their `measure_pair` kept."""
        measured = self._keep(self.pairs, tuple(keys), lambda: measure_pair(*sats, *ccs))
        return region_matches(*sats, *ccs, prior, measured=measured)


def region_tracks(history: list[np.ndarray], max_chain: int = MAX_CHAIN,
                  cache: MeasureCache | None = None) -> tuple[list[RegionTrack], np.ndarray]:
    """(tracks, labels): every saturated region of the last frame with its displacement chain
    (module docstring, step 1) and the frame's global chain (`global_chain`), and the last
    frame's region labels (0 = none). cache: the measurements of earlier calls (`MeasureCache`)."""
    cache = cache or MeasureCache()
    sats = [np.asarray(f) >= SATURATED for f in history[-(max_chain + 1):]]
    keys = [cache.key(s) for s in sats]
    cc = [cache.saturated_components(s, k) for s, k in zip(sats, keys)]
    # pairs[j]: frame t-j's regions, each with its shift from frame t-j-1 and its match there;
    # measured oldest first, each pair given the older pair's shifts (region_motion.py `unswap`)
    pairs, prior = [], None
    for j in reversed(range(min(max_chain, len(sats) - 1))):
        a, b = len(sats) - 2 - j, len(sats) - 1 - j
        pair = cache.region_matches((sats[a], sats[b]), (cc[a], cc[b]), (keys[a], keys[b]), prior)
        prior = {k: m.shift for k, m in pair[2].items() if m.prev_label}
        pairs.insert(0, pair)
    gshift, gresp = global_chain(pairs)
    labels, stats = cc[-1][1], cc[-1][2]
    tracks = []
    for k in range(1, len(stats)):
        x, y, bw, bh, area = (int(v) for v in stats[k])
        if area < MIN_REGION_PX:
            continue
        disp, resp, grow, label = [], [], [], k
        for _, _, matches in pairs:
            m = matches.get(label)
            if m is None or not m.prev_label:
                break                                    # new in this frame, or too small to follow
            disp.append(m.shift)
            resp.append(m.response)
            grow.append(m.growth)
            label = m.prev_label
        first = pairs[0][2].get(k) if pairs else None
        tracks.append(RegionTrack(k, (y, x, y + bh, x + bw), area, tuple(disp), tuple(resp), tuple(grow),
                                  gshift, gresp, first.prev_label if first else 0))
    return tracks, labels


def wavering(displacements) -> bool:
    """True when a region's own chain (px, newest first) changes by more than the acceleration
    gate twice running: |d_t - d_{t-1}| > ACCEL_GATE x max(|d_t|, 1 px) and the same between
    d_{t-1} and d_{t-2}. A vehicle cannot jerk back and forth like that (a reversal happens
    once, over a ramp); the outline of a standing glow does, frame after frame (a fog halo or
    a wet road's reflection of a street lamp whose clipped edge flickers with the noise and the
    Monte Carlo samples), and its outline's correlation then reads motion that is not there.
    Such a region stands: it moves with the frame's global motion alone (module docstring)."""
    d = np.asarray(displacements, dtype=np.float64).reshape(-1, 2)
    if len(d) < 3:
        return False
    return bool(np.hypot(*(d[0] - d[1])) > ACCEL_GATE * max(float(np.hypot(*d[0])), 1.0)
                and np.hypot(*(d[1] - d[2])) > ACCEL_GATE * max(float(np.hypot(*d[1])), 1.0))


#: Looming (`closed_form_looming`): the shortest displacement (px) of a chain read as looming, the
#: smallest ratio of consecutive lengths (and its inverse, receding), the largest (the light then
#: reaches the camera 2 / (r - 1) frames on: 1.3 frames at r = 2.5), the least cosine between
#: consecutive directions (5.7 deg), and the largest next ratio extrapolated.
LOOM_MIN_PX = 2.0
LOOM_MIN_RATIO = 1.1
LOOM_MAX_RATIO = 2.5
LOOM_MIN_COS = 0.995
LOOM_NEXT_MAX_RATIO = 2.0
#: The newest ratio agrees with the law's when |ln(r_t / law(r_{t-1}))| <= LOOM_TOL[0] |ln r_t| +
#: LOOM_TOL[1]: the outline correlation's ~0.3 px per displacement moves the ratio of two 10 px
#: displacements by ~4 %, and a constant acceleration departs from the law by more at large ratios.
LOOM_TOL = (0.15, 0.03)


def looming_ratio(r: float) -> float:
    """Next length ratio |d_{t+1}| / |d_t| of a looming light from the newest one, r = |d_t| / |d_{t-1}|.

    A light at a fixed offset from the camera's axis, closing at a steady speed V (Z_t = Z_0 - V t),
    images at x_t = x_F + k / Z_t (pinhole camera; x_F the focus of expansion), so its displacements
    d_t = k V / (Z_t Z_{t-1}) keep one direction and |d_{t+1}| / |d_t| = Z_{t-1} / Z_{t+1} =
    (Z_t + V) / (Z_t - V). With r = |d_t| / |d_{t-1}| = 1 + 2 V / Z_t, that is (r + 1) / (3 - r):
    exact for any k, V and Z_0, receding too (V < 0, r < 1). Hartley & Zisserman, Multiple View
    Geometry, 2nd ed., 2004, sec. 6.1 (the projection); the ratio is ours."""
    return (r + 1.0) / (3.0 - r)


def closed_form_looming(displacements) -> np.ndarray | None:
    """d_{t+1} (px) of a chain d_t, d_{t-1}, d_{t-2} (newest first) that looms, continued by
    `looming_ratio`; None when it does not: fewer than three displacements, one shorter than
    LOOM_MIN_PX, directions apart by more than LOOM_MIN_COS, ratios not both beyond
    LOOM_MIN_RATIO (or both below its inverse) and below LOOM_MAX_RATIO, a newest ratio not above
    the one before, or a newest ratio off the law by more than LOOM_TOL. The law's ratio grows
    frame to frame, law(r) - r = (r - 1)^2 / (3 - r) >= 0, where a constant acceleration's or
    braking's moves down (d_t = v + a t: r_t = 1 + a / (v + a (t - 1))), so a car speeding up or
    braking at a steady rate does not loom, nor does a constant velocity, a start from standing,
    a stop, a turn or a swerve."""
    d = np.asarray(displacements, dtype=np.float64).reshape(-1, 2)
    if len(d) < 3:
        return None
    n = np.hypot(d[:3, 0], d[:3, 1])
    if n.min() < LOOM_MIN_PX:
        return None
    u = d[:3] / n[:, None]
    if min(float(u[0] @ u[1]), float(u[1] @ u[2])) < LOOM_MIN_COS:
        return None
    r_t, r_before = n[0] / n[1], n[1] / n[2]
    closing = min(r_t, r_before) > LOOM_MIN_RATIO and max(r_t, r_before) < LOOM_MAX_RATIO
    opening = max(r_t, r_before) < 1.0 / LOOM_MIN_RATIO
    if not (closing or opening) or r_t <= r_before:
        return None                                    # the law's ratio only grows: law(r) - r = (r - 1)^2 / (3 - r)
    if abs(np.log(r_t / looming_ratio(r_before))) > LOOM_TOL[0] * abs(np.log(r_t)) + LOOM_TOL[1]:
        return None
    return d[0] * min(looming_ratio(r_t), LOOM_NEXT_MAX_RATIO)


#: Turning (`closed_form_turning`): the shortest displacement (px) read, the largest change of
#: length between consecutive displacements (|ln ratio|: a steady speed), and the smallest and
#: largest turn (rad) between consecutive directions: 0.05 rad is the direction noise of a 6 px
#: displacement measured to 0.3 px; above 0.9 rad a frame the chain reads as a reversal or a bad match.
TURN_MIN_PX = 2.0
TURN_MAX_LOG_RATIO = 0.25
TURN_MIN_RAD = 0.05
TURN_MAX_RAD = 0.9


def closed_form_turning(displacements, min_rad: float = TURN_MIN_RAD) -> np.ndarray | None:
    """d_{t+1} (px) of a chain d_t, d_{t-1}, d_{t-2} (newest first) that turns at a steady speed:
    d_t turned on by the newest turn angle (d_{t-1} to d_t), the constant turn rate and velocity
    model (CTRV: a vehicle on an arc images its displacements turning by the yaw rate each frame;
    Schubert, Richter & Wanielik, Comparison and evaluation of advanced motion models for vehicle
    tracking, FUSION 2008). The three-displacement constant-acceleration fit it replaces misses
    the arc by about 5/3 |d| w^2 (w the turn per frame: 4 px at 28 px and 0.35 rad a frame). None when the chain does not
    turn: fewer than three displacements, one shorter than TURN_MIN_PX, lengths changing by more
    than TURN_MAX_LOG_RATIO, or the two turn angles not both of one sign and within
    [min_rad, TURN_MAX_RAD]."""
    d = np.asarray(displacements, dtype=np.float64).reshape(-1, 2)
    if len(d) < 3:
        return None
    n = np.hypot(d[:3, 0], d[:3, 1])
    if n.min() < TURN_MIN_PX or max(abs(np.log(n[0] / n[1])), abs(np.log(n[1] / n[2]))) > TURN_MAX_LOG_RATIO:
        return None
    a = np.arctan2(d[:3, 1], d[:3, 0])
    w_t, w_before = (np.array([a[0] - a[1], a[1] - a[2]]) + np.pi) % (2 * np.pi) - np.pi
    if w_t * w_before <= 0 or min(abs(w_t), abs(w_before)) < min_rad or max(abs(w_t), abs(w_before)) > TURN_MAX_RAD:
        return None
    c, s = np.cos(w_t), np.sin(w_t)
    return np.array([c * d[0, 0] - s * d[0, 1], s * d[0, 0] + c * d[0, 1]])


def closed_form_displacement(displacements) -> np.ndarray:
    """d_{t+1} (px, x and y) from d_t, d_{t-1}, d_{t-2} (newest first) by the table's rows."""
    d = np.asarray(displacements, dtype=np.float64).reshape(-1, 2)
    if len(d) == 0:
        return np.zeros(2)
    if len(d) == 1:
        return d[0]
    scale = max(float(np.hypot(*d[0])), 1.0)
    if np.hypot(*(d[0] - d[1])) > ACCEL_GATE * scale:
        return d[0]                                    # not one acceleration: a reversal or a bad match
    if len(d) == 2:
        return 2 * d[0] - d[1]
    if np.hypot(*(d[1] - d[2])) > ACCEL_GATE * max(float(np.hypot(*d[1])), 1.0):
        return 2 * d[0] - d[1]
    return (4 * d[0] + d[1] - 2 * d[2]) / 3.0


#: Largest harmonic coefficient c = 2 cos(2 pi / P) read as an oscillation of the global motion:
#: P <= 12 frames (a body pitch of 0.8-1.25 Hz and faster at 10-15 fps; a car's ride frequency is
#: 1-1.5 Hz, Gillespie, Fundamentals of Vehicle Dynamics, 1992, ch. 5). Above it the chain is read
#: as steady motion (c = 2: constant velocity or acceleration) and `closed_form_displacement` runs.
HARMONIC_MAX_C = 2.0 * float(np.cos(2.0 * np.pi / 12.0))
#: Regularisation (px^2) of the harmonic fit: the global shift's measurement noise (~0.2 px, the
#: median of the agreeing regions' outline correlations) squared; a middle displacement near it
#: holds no oscillation to fit (c shrinks toward 0), a steady 1 px a frame still reads c = 1.9.
HARMONIC_RIDGE_PX2 = 0.05


#: Student's t of the yaw chain's mean above which it is read as a steady yaw (a bend) rather
#: than steering corrections about none (`closed_form_global`): 2 (two-sided p 0.18 with 2 degrees
#: of freedom, three shifts).
YAW_DRIFT_T = 2.0


def closed_form_global(shifts) -> np.ndarray:
    """Next global shift (px, x and y) from the frame's global chain g_t, g_{t-1}, g_{t-2} (newest
    first); shorter chains take `closed_form_displacement`'s row.

    Vertical (the camera pitching about its horizontal axis: a body bounce over road bumps, the
    suspension's ride mode): harmonic linear prediction, g_{t+1} = c g_t - g_{t-1}, exact for a
    sampled sinusoid of any phase with c = 2 cos(2 pi / period) (the second-order recurrence of a
    sinusoid; Prony's method with one mode), c fitted to the three displacements by least squares,
    c = (g_t + g_{t-2}) g_{t-1} / (g_{t-1}^2 + HARMONIC_RIDGE_PX2), and limited to [-2, 2]. Where
    c exceeds HARMONIC_MAX_C the axis is not oscillating and takes `closed_form_displacement`'s
    row (its acceleration gate included).

    Horizontal (the camera yawing as we steer): no spring mode holds the yaw, so it does not
    bounce; the heading is a random walk (the driver's corrections, which the past frames do not
    show) about a steady turn rate (a bend). The best forecast of a random walk's next step is its
    drift (Box, Jenkins & Reinsel, Time Series Analysis, 4th ed., 2008, sec. 4.3: the random walk
    with drift); the drift is the chain's mean where it stands out of the corrections' spread
    (Student's t = |mean| / (s / sqrt 3) > YAW_DRIFT_T), else none: 0. A harmonic or linear
    extrapolation of corrections amplifies them (its error is 1.5-3 times theirs).
    """
    g = np.asarray(shifts, dtype=np.float64).reshape(-1, 2)
    out = closed_form_displacement(g)
    if len(g) < 3:
        return out
    y = g[:, 1]
    c = float(np.clip((y[0] + y[2]) * y[1] / (y[1] ** 2 + HARMONIC_RIDGE_PX2), -2.0, 2.0))
    if c <= HARMONIC_MAX_C:
        out[1] = c * y[0] - y[1]
    x = g[:3, 0]
    mean, spread = float(x.mean()), float(x.std(ddof=1)) / np.sqrt(3.0)
    out[0] = mean if abs(mean) > YAW_DRIFT_T * spread else 0.0
    return out


def closed_form_growth(growths) -> float:
    """Next frame's growth (linear size ratio) from the measured ones (newest first): constant
    growth, the geometric mean of the last two, when both grow or both shrink beyond
    GROWTH_DEADBAND; else 1 (one ratio, or ratios that disagree: outline noise, not growth).
    Limited to [1 / MAX_GROWTH, MAX_GROWTH]."""
    g = np.asarray(growths[:2], dtype=np.float64)
    if len(g) < 2 or not (np.all(g > 1 + GROWTH_DEADBAND) or np.all(g < 1 - GROWTH_DEADBAND)):
        return 1.0
    return float(np.clip(np.sqrt(g[0] * g[1]), 1.0 / MAX_GROWTH, MAX_GROWTH))


def grow_region(out: np.ndarray, frame: np.ndarray, region: np.ndarray, box, d, growth: float) -> None:
    """Paste the region's pixels of `frame` (`region`: bool in `box` (y0, x0, y1, x1)) into
    `out`, scaled by `growth` about its centroid and moved by d (px), brightest wins (in place):
    the forward splat of a growing region leaves holes between its spread pixels; this fills them
    with the region's own values (nearest neighbour: a clipped pixel lands clipped)."""
    y0, x0, y1, x1 = box
    h, w = out.shape
    ys, xs = np.nonzero(region)
    cy, cx = ys.mean() + y0, xs.mean() + x0
    ny0, nx0 = int(np.floor(cy + d[1] - growth * (cy - y0))) - 1, int(np.floor(cx + d[0] - growth * (cx - x0))) - 1
    ny1, nx1 = int(np.ceil(cy + d[1] + growth * (y1 - cy))) + 1, int(np.ceil(cx + d[0] + growth * (x1 - cx))) + 1
    ny0, nx0, ny1, nx1 = max(ny0, 0), max(nx0, 0), min(ny1, h), min(nx1, w)
    if ny1 <= ny0 or nx1 <= nx0:
        return
    crop = np.where(region, frame[y0:y1, x0:x1], 0.0).astype(np.float32)
    # crop pixel x lands at g (x + x0 - cx) + cx + dx, i.e. g x + (g x0 + (1 - g) cx + dx - nx0) in the output box
    m = np.float32([[growth, 0, growth * x0 + (1 - growth) * cx + d[0] - nx0],
                    [0, growth, growth * y0 + (1 - growth) * cy + d[1] - ny0]])
    moved = cv2.warpAffine(crop, m, (nx1 - nx0, ny1 - ny0), flags=cv2.INTER_NEAREST, borderValue=0)
    np.maximum(out[ny0:ny1, nx0:nx1], moved, out=out[ny0:ny1, nx0:nx1])


class RegionTracker(Predictor):
    """`track`: DIS flow for the frame, a closed-form extrapolated displacement per saturated
    region (module docstring). Subclasses replace `own_motion`."""

    name = "track"
    #: Smallest turn per frame (rad) continued on its arc (`closed_form_turning`).
    turn_min_rad = TURN_MIN_RAD
    needs_frames = 2              # works from two frames (constant velocity), better with four
    min_input_px = 12             # OpenCV's DIS refuses frames narrower or lower than 12 px

    def __init__(self, preset: int = cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST):
        self.dis = cv2.DISOpticalFlow_create(preset)
        self.cache = MeasureCache()

    def own_motion(self, tracks: list[RegionTrack]) -> list[np.ndarray]:
        """Each region's own next displacement (px), relative to the frame's global motion: its
        relative chain extrapolated by the closed forms (module docstring, step 2)."""
        return [closed_form_displacement(t.relative()) for t in tracks]

    def own_steps(self, tracks: list[RegionTrack]) -> list[np.ndarray]:
        """Each region's own next displacement (px, relative to the global motion): the looming
        law where its relative chain looms (`closed_form_looming`), the steady turn where it
        turns (`closed_form_turning`), else `own_motion`."""
        out = []
        for t, d in zip(tracks, self.own_motion(tracks)):
            rel = t.relative()
            law = closed_form_looming(rel)
            if law is None:
                law = closed_form_turning(rel, self.turn_min_rad)
            out.append(d if law is None else law)
        return out

    def next_displacement(self, tracks: list[RegionTrack]) -> list[np.ndarray]:
        """d_{t+1} (px) per track: its own motion (`own_steps`) plus the global motion
        extrapolated (module docstring, step 2); a new region (no chain) or a wavering one
        (`wavering`) moves with the global motion alone."""
        if not tracks:
            return []
        g = closed_form_global(tracks[0].global_shifts)
        return [g if wavering(t.relative()) else d + g for t, d in zip(tracks, self.own_steps(tracks))]

    def __call__(self, history):
        frames = [np.asarray(f, dtype=np.float32) for f in history[-(MAX_CHAIN + 1):]]
        p8, c8 = log_8bit(frames[-2], frames[-1])
        flow = self.dis.calc(p8, c8, None)
        tracks, labels = region_tracks(frames, cache=self.cache)
        parts, part_steps = self.merged_parts(frames, tracks, labels)
        grown, moved = [], []
        for tr, d in zip(tracks, self.next_displacement(tracks)):
            y0, x0, y1, x1 = tr.box
            inside = labels[y0:y1, x0:x1] == tr.label
            g = closed_form_growth(tr.growths)
            if tr.label in parts:                      # two or more lights that ran into one
                flow[y0:y1, x0:x1, 0][inside], flow[y0:y1, x0:x1, 1][inside] = \
                    part_flow(inside, tr.box, parts[tr.label], part_steps[tr.label])
                continue
            if g != 1.0:                               # each pixel moves by d + (g - 1)(p - centroid)
                ys, xs = np.nonzero(inside)
                flow[y0:y1, x0:x1, 0][inside] = d[0] + (g - 1) * (xs - xs.mean())
                flow[y0:y1, x0:x1, 1][inside] = d[1] + (g - 1) * (ys - ys.mean())
                grown.append((inside, tr.box, d, g))
                continue
            flow[y0:y1, x0:x1, 0][inside] = d[0]
            flow[y0:y1, x0:x1, 1][inside] = d[1]
            outline = moved_outline(frames[-1], inside, tr.box, d) if np.hypot(*d) >= SUBPIXEL_MIN_PX else None
            if outline is not None:                    # its outline placed to a fraction of a pixel
                moved.append(outline)
        out = forward_splat(frames[-1], flow)
        for outline in moved:
            paint(out, outline)
        for inside, box, d, g in grown:
            if g > 1.0:
                grow_region(out, frames[-1], inside, box, d, g)
        return out

    def merged_parts(self, frames, tracks, labels) -> tuple[dict, dict]:
        """({region label: its parts}, {label: each part's next step (px)}): the lights followed
        to frame t-1 that ran into one region of frame t (region_merges.py)."""
        if len(frames) < 3 or not holders(tracks):
            return {}, {}                              # no region can hold parts: frame t-1 is not read again
        before, before_labels = region_tracks(frames[:-1], cache=self.cache)
        shifts = tracks[0].global_shifts
        parts = lost_parts(tracks, labels, before, before_labels, lambda followed: self.step_to_last(followed, shifts))
        steps = {k: self.next_displacement([p.track for p in ps]) for k, ps in parts.items()}
        return parts, steps

    def step_to_last(self, followed: list[RegionTrack], global_shifts) -> list[np.ndarray]:
        """Each frame t-1 track's step to frame t (px): its own motion extrapolated (`own_steps`;
        none where its chain wavers) plus the global shift g_t measured between the two frames
        (the newest of frame t's `global_shifts`; none where there is no chain)."""
        g_t = np.asarray(global_shifts[0] if global_shifts else (0.0, 0.0), np.float64)
        return [(np.zeros(2) if wavering(b.relative()) else np.asarray(d, np.float64)) + g_t
                for b, d in zip(followed, self.own_steps(followed))]

    def describe(self) -> dict:
        return {"name": self.name, "context_frames": MAX_CHAIN + 1}
