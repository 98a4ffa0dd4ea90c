"""Where each bright region of the demand map will be one frame on: constant box velocity.

The exposure controller (exposure_control.py) carries a region's demand to the next frame by a
grey dilation of radius R = ceil(3 smooth_px). A highlight whose image moves or grows faster
than R per frame leaves that carried region, and where the predictor also lags (it extrapolates
a few pixels of a 24 px step) the mirrors in front of it are white: on night_road's last frame
(9.7 m, 10 fps, 184x320) the plate's bottom edge moves 24 px in one frame (7, 8, 11, 16, 24 px
over frames 16-20: the plate drops and grows as 1/distance), the dmvfn_lite prediction puts the
plate ~4 px lower than the frame before, and the lower third of the plate clips (22 % of its
box) behind levels 6-255.

`extrapolate` moves each bright region (a connected component of demand >= `level`) on by the
affine map, per axis, that took its bounding box from the previous frame to this one
(x' = a x + b: the growth a and shift b of a box under constant velocity in position and
size; a is limited to [1/2, 2]), and resamples its demand into that box. A region of this frame
is matched to a previous region only when the match is mutual and their areas are alike
(`match_regions`, with no shift: the previous region it overlaps most, which no other region of
this frame overlaps better); one without such a match (new, split off, or moved more than its own
size) is not moved. The box-extrapolation of tracked regions is the constant-velocity
model of a Kalman box tracker's prediction step (SORT: Bewley et al., ICIP 2016, box centre and
scale with constant velocity), here without the filter: the last two frames set the motion.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

#: Largest growth (and shrink, its inverse) of a region's box per frame that is extrapolated.
MAX_GROWTH = 2.0
#: Largest ratio of two regions' areas (px) that may be one region in consecutive frames: a
#: light growing 25 % a frame in size grows 1.56x in area; two lights merging double it.
MAX_AREA_RATIO = 2.0
#: Claims on one previous region whose overlaps (IoU) lie this close are a tie, settled by the
#: smaller shift (a light appearing beside a standing one is new: the standing one keeps its match).
IOU_TIE = 0.1
#: A region whose claim lost tries the shifts of this many matched regions nearest it ...
RETRY_NEIGHBOURS = 3
#: ... and takes one that moves it back onto an unclaimed region with at least this IoU.
RETRY_IOU = 0.5
#: A second look (`rematch_left`) matches only regions whose linear size changed by at most this
#: factor: a light's own growth (25 % a frame at most, track.py MAX_GROWTH), not a piece split off
#: a merged pair or two lights merged (their area nearly doubles or halves).
REMATCH_GROWTH = 1.25
#: Two matched regions exchange their earlier regions when that leaves this fraction or less of
#: their summed shifts (`unswap`): a clear gain, not a tie of two like readings.
SWAP_FRAC = 0.8
#: Two regions' shifts agree (one vehicle's lights) within this (px) or this fraction of the
#: shift, whichever is larger (a growing car's lamps part: their shifts differ by the growth times
#: their spacing).
AGREE_PX, AGREE_FRAC = 1.5, 0.15
#: Matched regions whose shifts lie within this of a candidate shift (px, Euclidean) agree with it:
#: a few times the outline correlation's spread on one light (0.1-0.5 px), well under one lamp's size.
GLOBAL_TOL_PX = 1.5
#: Fewest matched regions that must agree on one shift for it to be the frame's global motion ...
MIN_GLOBAL_REGIONS = 3
#: ... and the least height (fraction of the frame's) their centres must span: the camera's pitch
#: and yaw move lights at every height together (a street lamp high up, a parked car low), whereas
#: one car's lamps and plate span 0.16 of its width (lamps 0.05 above, plate 0.3 below the body's
#: middle, body 0.45 wide as high: analysis/traffic_paths.py), under a quarter of the frame's
#: height unless the car fills the frame. One car alone is not the camera's motion.
GLOBAL_SPAN = 0.25


def components(bright: np.ndarray):
    """(labels, stats) of the 8-connected regions of `bright`; stats rows: x, y, w, h, area."""
    import cv2

    _, labels, stats, _ = cv2.connectedComponentsWithStats(bright.astype(np.uint8), connectivity=8)
    return labels, stats


@dataclass(frozen=True)
class RegionMatch:
    """A region of the later frame (its label) and the region of the earlier frame it is the
    same light as (`prev_label`, 0 = none: a new region), with the measured shift (px, from the
    earlier frame to the later) and its correlation response (1 where no correlation is made);
    `growth`: the linear size ratio sqrt(area later / area earlier) of a matched pair, 1 where
    either region touches the frame's edge (its visible area is not its size) or unmatched."""

    label: int
    prev_label: int
    shift: tuple[float, float]
    response: float
    growth: float = 1.0


def _touches_edge(stat, shape) -> bool:
    x, y, w, h = (int(v) for v in stat[:4])
    return x == 0 or y == 0 or x + w >= shape[1] or y + h >= shape[0]


def _claim(k: int, dx: float, dy: float, labels, stats, prev_labels, prev_stats) -> tuple[int, float]:
    """(earlier region, IoU) that later region k, moved back by (dx, dy), overlaps most; (0, 0)
    where it overlaps none or leaves the frame."""
    h, w = labels.shape
    x, y, bw, bh, area = (int(v) for v in stats[k])
    ox, oy = x - int(round(dx)), y - int(round(dy))
    y0, x0, y1, x1 = max(oy, 0), max(ox, 0), min(oy + bh, h), min(ox + bw, w)      # clipped to the frame
    if y1 <= y0 or x1 <= x0:
        return 0, 0.0
    moved = (labels[y:y + bh, x:x + bw] == k)[y0 - oy:y1 - oy, x0 - ox:x1 - ox]
    under = prev_labels[y0:y1, x0:x1][moved]
    under = under[under > 0]
    if under.size == 0:
        return 0, 0.0
    per_label = np.bincount(under)                  # np.unique's ids and counts, without a sort
    ids = np.flatnonzero(per_label)
    counts = per_label[ids]
    iou = counts / (area + prev_stats[ids, 4] - counts)
    return int(ids[np.argmax(iou)]), float(iou.max())


def _pair(k: int, j: int, stats, prev_stats, shape) -> float | None:
    """Growth (linear size ratio) of later region k against earlier region j when their areas
    are alike (1 when either is cut by the frame's edge: its visible area changes as it enters
    or leaves), None when they are not."""
    if _touches_edge(stats[k], shape) or _touches_edge(prev_stats[j], shape):
        return 1.0
    a, b = float(stats[k, 4]), float(prev_stats[j, 4])
    return float(np.sqrt(a / b)) if max(a, b) <= MAX_AREA_RATIO * min(a, b) else None


def _light_pair(k: int, j: int, stats, prev_stats, shape) -> float | None:
    """`_pair`'s growth where it is a light's own (within `REMATCH_GROWTH`), else None: the
    second looks (`reclaim`, `rematch_left`, `unswap`) never take a split-off piece or a merge."""
    g = _pair(k, j, stats, prev_stats, shape)
    return g if g is not None and 1.0 / REMATCH_GROWTH <= g <= REMATCH_GROWTH else None


def match_regions(prev_labels: np.ndarray, prev_stats: np.ndarray, labels: np.ndarray, stats: np.ndarray,
                  shifts: dict[int, tuple[float, float, float]], min_response: float = 0.0) -> dict[int, RegionMatch]:
    """Mutual matching of the later frame's regions (`labels`, `stats` from `components`)
    with the earlier frame's. shifts: {label: (dx, dy, response)} of every later region to be
    matched (px, the earlier frame's region maps onto the later one by +shift).

    Each later region, moved back by its shift, claims the earlier region it overlaps most (IoU
    of the moved-back region with it). An earlier region claimed more than once keeps the claim
    of the highest IoU, ties (within `IOU_TIE`) going to the shift that more of the claimant's
    `RETRY_NEIGHBOURS` nearest regions share (`AGREE_PX`, `AGREE_FRAC`: a car's lamps and
    plate move together; a lamp of a pair whose speed is half their spacing correlates as well
    with its twin, at a shift its neighbours do not have), then to the smaller shift. A claim
    stands when
    it won, its response is at least `min_response`, and the two areas differ by at most
    `MAX_AREA_RATIO` (not checked for a region cut by the frame's edge: its visible area changes
    as it enters or leaves). A region left without a match (its claim lost, or its shift moved
    it back onto nothing: the outline correlation of one lamp of a pair may land on its twin)
    tries the shifts of the matched regions nearest it (a car's lamps move together) and is
    matched by one that moves it back onto an unclaimed region of alike area with IoU >=
    `RETRY_IOU`. Every other region is new (prev_label 0)."""
    shape = labels.shape
    claims: dict[int, list[tuple[float, float, int]]] = {}
    best: dict[int, int] = {}
    for k, (dx, dy, resp) in shifts.items():
        j, iou = _claim(k, dx, dy, labels, stats, prev_labels, prev_stats) if resp >= min_response else (0, 0.0)
        if j:
            best[k] = j
            claims.setdefault(j, []).append((iou, float(np.hypot(dx, dy)), k))
    out = {k: RegionMatch(k, 0, (float(dx), float(dy)), float(resp)) for k, (dx, dy, resp) in shifts.items()}
    measured = {k: np.array(v[:2], np.float64) for k, v in shifts.items() if v[2] >= min_response}
    centre = lambda st: np.array([st[0] + st[2] / 2.0, st[1] + st[3] / 2.0])

    keys = list(measured)                      # the measured regions, in `shifts` order
    index = {q: i for i, q in enumerate(keys)}
    cents = np.array([centre(stats[q]) for q in keys], np.float64).reshape(-1, 2)
    vecs = np.array([measured[q] for q in keys], np.float64).reshape(-1, 2)
    supports: dict[int, int] = {}

    def nearest(points: np.ndarray, c: np.ndarray) -> np.ndarray:
        """Indices of `points` by distance from c (stable: equal distances keep their order)."""
        return np.argsort(np.hypot(points[:, 0] - c[0], points[:, 1] - c[1]), kind="stable")

    def support(k: int) -> int:
        """How many of the RETRY_NEIGHBOURS regions nearest k share its shift (its own vehicle's
        lights, not a far one's that happens to move by the twin's offset). Once per region:
        O(n log n) each, so a frame of many small clipped speckles stays cheap."""
        if k not in supports:
            i = index[k]
            s = vecs[i]
            tol = max(AGREE_PX, AGREE_FRAC * float(np.hypot(*s)))
            order = nearest(cents, cents[i])
            near = order[order != i][:RETRY_NEIGHBOURS]
            supports[k] = int(np.count_nonzero(np.hypot(vecs[near, 0] - s[0], vecs[near, 1] - s[1]) <= tol))
        return supports[k]

    winners = {}                               # earlier region -> the later region whose claim stands
    for j, cl in claims.items():
        top = max(c[0] for c in cl)
        tied = [c for c in cl if c[0] >= top - IOU_TIE]
        winners[j] = min(tied, key=lambda c: (-support(c[2]) if len(tied) > 1 else 0, c[1], -c[0]))[2]
    taken = set()
    for k, j in best.items():
        winner = winners[j]
        growth = _pair(k, j, stats, prev_stats, shape)
        if winner == k and growth is not None:
            out[k] = replace(out[k], prev_label=j, growth=growth)
            taken.add(j)
    matched = [m for m in out.values() if m.prev_label]
    matched_cents = np.array([centre(stats[m.label]) for m in matched], np.float64).reshape(-1, 2)
    for k in [k for k in shifts if not out[k].prev_label]:
        for m in (matched[i] for i in nearest(matched_cents, centre(stats[k]))[:RETRY_NEIGHBOURS]):
            j, iou = _claim(k, *m.shift, labels, stats, prev_labels, prev_stats)
            growth = _pair(k, j, stats, prev_stats, shape) if j and j not in taken and iou >= RETRY_IOU else None
            if growth is not None:
                out[k] = replace(out[k], prev_label=j, shift=m.shift, growth=growth)
                taken.add(j)
                break
    return out


def unswap(matches: dict[int, RegionMatch], prev_labels: np.ndarray, prev_stats: np.ndarray, labels: np.ndarray,
           stats: np.ndarray, remeasure=None, prior: dict | None = None) -> dict[int, RegionMatch]:
    """Undo swapped identities: two matched regions k1 <- j1, k2 <- j2 are exchanged to
    k1 <- j2, k2 <- j1 when that departs less in all from the motion each earlier region had
    (`prior`: {earlier label: its shift (dx, dy) px from the frame before}; none known: standing),
    the sum of the two departures' lengths (box centres) falling to at most SWAP_FRAC of the
    matched pair's, and each exchanged pair is a light's own (`_light_pair`) and overlaps with
    IoU >= `RETRY_IOU` when moved back. Like lights (a car's two lamps, two cars' lamps
    crossing) correlate as well with each other's old place as with their own, and two regions
    can each take the other's, a mutual match that is wrong for both. Lights that move together
    never gain by the exchange (|v - s| + |v + s| >= 2 |v| for a common departure v and spacing
    s), so it changes nothing there; it is the nearest-neighbour assignment of the pair under a
    constant-velocity prediction (the association step of a tracker: predict, then match). An
    exchanged region's shift is `remeasure(k, only=j)` (its correlation with earlier region j
    alone: (dx, dy, response)) when given, else its old one plus the offset between the two
    earlier regions' box centres. Pairs are looked for only among regions departing more than
    1 px from their prior motion (a frame of standing speckles costs nothing)."""
    shape = labels.shape
    centre = lambda st: np.array([st[0] + st[2] / 2.0, st[1] + st[3] / 2.0])
    prior = prior or {}
    before = lambda j: np.asarray(prior.get(j, (0.0, 0.0)), np.float64)
    departs = lambda m: float(np.hypot(*(np.asarray(m.shift) - before(m.prev_label))))
    moving = [m for m in matches.values() if m.prev_label and departs(m) > 1.0]
    if len(moving) < 2:
        return matches
    out = dict(matches)
    cur = np.array([centre(stats[m.label]) for m in moving])
    prv = np.array([centre(prev_stats[m.prev_label]) for m in moving])
    ahead = prv + np.array([before(m.prev_label) for m in moving])          # where each earlier region was headed
    own = np.hypot(*(cur - ahead).T)                                         # |c_k - p_k - v_k|
    cross = np.hypot(*(cur[:, None, :] - ahead[None, :, :]).transpose(2, 0, 1))  # |c_k - p_j - v_j|
    done: set[int] = set()
    for a, b in zip(*np.nonzero(cross < own[:, None])):
        if a == b or a in done or b in done:
            continue
        swapped, kept = cross[a, b] + cross[b, a], own[a] + own[b]
        if swapped > SWAP_FRAC * kept:
            continue
        ma, mb = out[moving[a].label], out[moving[b].label]
        new = []
        for m, j, dp in ((ma, mb.prev_label, prv[a] - prv[b]), (mb, ma.prev_label, prv[b] - prv[a])):
            shift, resp = (m.shift[0] + float(dp[0]), m.shift[1] + float(dp[1])), m.response
            if remeasure is not None:
                dx, dy, resp = remeasure(m.label, only=j)
                shift = (float(dx), float(dy))
            got, iou = _claim(m.label, *shift, labels, stats, prev_labels, prev_stats)
            growth = _light_pair(m.label, j, stats, prev_stats, shape) if got == j and iou >= RETRY_IOU else None
            if growth is None:
                break
            new.append(replace(m, prev_label=j, shift=shift, response=float(resp), growth=growth))
        if len(new) == 2:
            out[ma.label], out[mb.label] = new
            done.update((a, b))
    return out


def reclaim(prev_labels: np.ndarray, prev_stats: np.ndarray, labels: np.ndarray, stats: np.ndarray,
            matches: dict[int, RegionMatch], remeasure=None) -> dict[int, RegionMatch]:
    """A region left new whose nearest matched regions' shift (one of `RETRY_NEIGHBOURS`, as in
    `match_regions`' retry) moves it back onto an earlier region that another region took, with
    IoU >= `RETRY_IOU` and alike areas, takes it over when that shift is under SWAP_FRAC of the
    holder's: the holder then tries its own neighbours' shifts onto a free earlier region (and is
    new where none fits). A lamp of a pair whose correlation peaked on its twin's old place (a
    growing car's lamps part, and the outlines of two sizes correlate off their peak) holds the
    twin's match, and the twin, moving with the car, is left without one. The taken-over
    region's shift is `remeasure(k, only=j)` when given (its correlation with j alone)."""
    shape = labels.shape
    centre = lambda st: np.array([st[0] + st[2] / 2.0, st[1] + st[3] / 2.0])
    out = dict(matches)
    holder = {m.prev_label: k for k, m in out.items() if m.prev_label}

    def neighbour_claims(k):
        """(shift, earlier region, IoU) of k moved back by each of its nearest matched regions' shifts."""
        got = [m for m in out.values() if m.prev_label and m.label != k]
        if not got:
            return []
        c = np.array([centre(stats[m.label]) for m in got])
        d = np.hypot(*(c - centre(stats[k])).T)
        res = []
        for i in np.argsort(d, kind="stable")[:RETRY_NEIGHBOURS]:
            j, iou = _claim(k, *got[i].shift, labels, stats, prev_labels, prev_stats)
            res.append((got[i].shift, j, iou))
        return res

    def take(k, j, shift):
        resp = out[k].response
        if remeasure is not None:
            dx, dy, resp = remeasure(k, only=j)
            shift = (float(dx), float(dy))
        out[k] = replace(out[k], prev_label=j, shift=shift, response=float(resp),
                         growth=_light_pair(k, j, stats, prev_stats, shape))
        holder[j] = k

    for k in [k for k, m in matches.items() if not m.prev_label]:
        for shift, j, iou in neighbour_claims(k):
            h = holder.get(j)
            if (h is None or h == k or iou < RETRY_IOU or _light_pair(k, j, stats, prev_stats, shape) is None
                    or np.hypot(*shift) >= SWAP_FRAC * np.hypot(*out[h].shift)):
                continue
            out[h] = replace(out[h], prev_label=0, growth=1.0)
            take(k, j, shift)
            for s2, j2, iou2 in neighbour_claims(h):
                if (j2 and j2 not in holder and iou2 >= RETRY_IOU
                        and _light_pair(h, j2, stats, prev_stats, shape) is not None):
                    take(h, j2, s2)
                    break
            break
    return out


def rematch_left(prev_labels: np.ndarray, prev_stats: np.ndarray, labels: np.ndarray, stats: np.ndarray,
                 matches: dict[int, RegionMatch], remeasure, min_response: float = 0.0) -> dict[int, RegionMatch]:
    """Second look for the regions `match_regions` left new: each is measured again against the
    earlier frame without its taken regions (`remeasure(k, taken)` -> (dx, dy, response), the
    earlier regions `taken` by a match hidden) and matched when that shift moves it back onto a
    region no other match took, of alike area, with IoU >= `RETRY_IOU`. Two like lights crossing
    (one vehicle's lamp passing above another's) both lie in one correlation window, and a
    region's correlation can land on the other's old place, which that light's own match keeps;
    hidden, only the region's own old place is left to find. A light that appeared beside a
    standing one finds nothing (the standing one's old place is taken) and stays new. Returns
    `matches` with the found ones replaced (the others as they were); `unswap` then undoes a
    found match that took the old place of a light whose own match went astray."""
    taken = {m.prev_label for m in matches.values() if m.prev_label}
    left = [k for k, m in matches.items() if not m.prev_label]
    if not left or len(taken) + 1 >= len(prev_stats):      # no earlier region left free
        return matches
    out = dict(matches)
    shape = labels.shape
    for k in left:
        dx, dy, resp = remeasure(k, hidden=frozenset(taken))
        if resp < min_response:
            continue
        j, iou = _claim(k, dx, dy, labels, stats, prev_labels, prev_stats)
        growth = _light_pair(k, j, stats, prev_stats, shape) if j and j not in taken and iou >= RETRY_IOU else None
        if growth is not None:
            out[k] = replace(out[k], prev_label=j, shift=(float(dx), float(dy)), response=float(resp), growth=growth)
            taken.add(j)
    return out


@dataclass(frozen=True)
class GlobalShift:
    """The shift (px, x and y, earlier frame to later) that the most matched regions share, the
    number that share it (`support`, 0: no global motion found, shift 0) and their median
    correlation response."""

    shift: tuple[float, float]
    support: int
    response: float


def global_shift(shifts, responses=None, centres_y=None, height: float | None = None,
                 tol_px: float = GLOBAL_TOL_PX, min_regions: int = MIN_GLOBAL_REGIONS) -> GlobalShift:
    """The frame's global motion from its matched regions' shifts ((N, 2) px): a consensus (as
    RANSAC's, Fischler & Bolles 1981, with every region's shift tried as the model): each shift
    gathers the regions within `tol_px` of it; the largest gathering (ties: the one whose shift
    is smallest, a standing scene) that holds at least `min_regions` regions, and whose centres
    (`centres_y`, px, when given) span at least GLOBAL_SPAN x `height`, gives the per-axis median
    of its members' shifts. None such: no global motion (shift 0, support 0). The camera's own
    pitch and yaw move every light by one shift, so the standing lights and the lights of
    vehicles that move with the traffic agree on it; a lone independent mover does not pull it
    (the median of the agreeing set, not the mean of all), nor is one car's set of lights taken
    for it (too short a span)."""
    s = np.asarray(shifts, dtype=np.float64).reshape(-1, 2)
    if len(s) < min_regions:
        return GlobalShift((0.0, 0.0), 0, 0.0)
    near = np.hypot(*(s[:, None, :] - s[None, :, :]).transpose(2, 0, 1)) <= tol_px
    count = near.sum(1)
    ys = None if centres_y is None else np.asarray(centres_y, np.float64)
    spread = lambda i: ys is None or float(np.ptp(ys[near[i]])) >= GLOBAL_SPAN * float(height)
    order = sorted(range(len(s)), key=lambda i: (-count[i], float(np.hypot(*s[i]))))
    best = next((i for i in order if count[i] >= min_regions and spread(i)), None)
    if best is None:
        return GlobalShift((0.0, 0.0), 0, 0.0)
    members = near[best]
    g = np.median(s[members], axis=0)
    resp = float(np.median(np.asarray(responses, np.float64)[members])) if responses is not None else 1.0
    return GlobalShift((float(g[0]), float(g[1])), int(count[best]), resp)


def _axis_map(p0: float, pn: float, c0: float, cn: float) -> tuple[float, float]:
    """(a, b) of x' = a x + b taking the interval [p0, p0 + pn) onto [c0, c0 + cn), a limited
    to [1 / MAX_GROWTH, MAX_GROWTH]."""
    a = float(np.clip(cn / pn, 1.0 / MAX_GROWTH, MAX_GROWTH))
    return a, (c0 + cn / 2.0) - a * (p0 + pn / 2.0)


def extrapolate(prev: np.ndarray, cur: np.ndarray, level: float) -> np.ndarray:
    """`cur` with each region of demand >= `level` moved on one frame (module docstring), 0
    elsewhere; same units as `cur` (e-). prev, cur: demand maps of two consecutive frames."""
    import cv2

    cur = np.asarray(cur)
    out = np.zeros(cur.shape, np.float32)
    lp, sp = components(np.asarray(prev) >= level)
    lc, sc = components(cur >= level)
    h, w = cur.shape
    matches = match_regions(lp, sp, lc, sc, {k: (0.0, 0.0, 1.0) for k in range(1, len(sc))})
    for k in range(1, len(sc)):
        if not matches[k].prev_label:
            continue
        px, py, pw, ph = sp[matches[k].prev_label, :4].astype(np.float64)
        cx, cy, cw, ch = sc[k, :4].astype(np.float64)
        ax, bx = _axis_map(px, pw, cx, cw)
        ay, by = _axis_map(py, ph, cy, ch)
        nw, nh = max(1, int(round(ax * cw))), max(1, int(round(ay * ch)))
        nx = int(round(ax * (cx + cw / 2.0) + bx - nw / 2.0))
        ny = int(round(ay * (cy + ch / 2.0) + by - nh / 2.0))
        box = (slice(int(cy), int(cy + ch)), slice(int(cx), int(cx + cw)))
        crop = np.where(lc[box] == k, cur[box], 0.0).astype(np.float32)      # region k within its box
        moved = cv2.resize(crop, (nw, nh), interpolation=cv2.INTER_NEAREST)
        y0, x0, y1, x1 = max(ny, 0), max(nx, 0), min(ny + nh, h), min(nx + nw, w)
        if y1 <= y0 or x1 <= x0:
            continue
        out[y0:y1, x0:x1] = np.maximum(out[y0:y1, x0:x1], moved[y0 - ny:y1 - ny, x0 - nx:x1 - nx])
    return out
