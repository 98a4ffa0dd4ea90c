"""Classical motion extrapolation: DIS optical flow, a translation per saturated region, then a
forward splat one frame ahead.

Flow from frame t-1 to frame t (OpenCV DIS, ultrafast preset: Kroeger et al., "Fast Optical
Flow using Dense Inverse Search", ECCV 2016) is assumed constant for one more frame. Every pixel
of frame t is pushed along its flow; where several land on one pixel the brightest wins (a
highlight must never be predicted dimmer than it is), and pixels nothing lands on keep frame t
(holding the old value is the safe choice for the mask: it errs toward dimming).

Two things DIS cannot see (issue 20, benchmarks/results/predictor_alignment.md):
- **Saturated regions.** A clipped region is one flat value: no texture, so DIS finds motion only
  at its outline and the splat left a 24 px/frame highlight 10-32 px behind. Each connected region
  at or above `SATURATED` (8-bit scale) in frame t gets one translation, the peak of the phase
  correlation of its outline with frame t-1's saturated outline (Kuglin & Hines 1975; OpenCV
  `phaseCorrelate`, no taper: outlines on the frame's edge are dropped, since they do not move
  with a region the frame cuts, so the maps are zero at the window's edge), searched over a window
  of the region's box grown by `SEARCH_PX` + the region's own size (a shift up to half the window
  is found, whatever the speed); that translation replaces DIS's flow inside the region when
  the region and the frame t-1 region it lands on are each other's match and alike in area
  (region_motion.py `match_regions`); a region with no such match is new (a light switched on,
  or appearing beside another) and is predicted where it is.
- **Values above 255** (the `demodulated` loop mode's unclipped estimates). DIS takes 8-bit
  frames: both frames are mapped by one log curve, 255 ln(1 + x) / ln(1 + max), when either
  exceeds 255 (radiance ratios become differences: a plate 200x over its surround keeps its
  texture); frames within 0-255 go in as they are.
"""

from __future__ import annotations

import cv2
import numpy as np

from poevp_optics.control.predictors.base import Predictor

#: 8-bit value from which a pixel counts as saturated (the mask laws' clip marker, masks.py).
SATURATED = 254.5
#: Smallest saturated region (px) given its own translation (smaller ones keep DIS's flow).
MIN_REGION_PX = 16
#: Search margin (px) around a region's box, beyond the region's own size.
SEARCH_PX = 32
#: Smallest normalised phase-correlation peak accepted (below: the region keeps DIS's flow).
MIN_RESPONSE = 0.05
#: Size change (linear ratio - 1) of a matched region beyond which its shift is its centroid's.
GROWTH_SHIFT = 0.02
#: ... and at most this (or its inverse): a larger change in one frame is a split or a merge (two
#: lamps of a crossing car parting), whose centroid moves by half the pieces' spacing, not with the
#: light; its outline correlation is kept. A light grows at most 25 % a frame (track.py MAX_GROWTH).
CENTROID_GROWTH_MAX = 1.3


class FlowExtrapolation(Predictor):
    name = "flow"
    min_input_px = 12             # OpenCV's DIS refuses frames narrower or lower than 12 px

    def __init__(self, preset: int = cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST):
        self.dis = cv2.DISOpticalFlow_create(preset)

    def __call__(self, history):
        prev = np.asarray(history[-2], dtype=np.float32)
        cur = np.asarray(history[-1], dtype=np.float32)
        p8, c8 = log_8bit(prev, cur)
        flow = self.dis.calc(p8, c8, None)
        region_translations(prev >= SATURATED, cur >= SATURATED, flow)
        return forward_splat(cur, flow)


def log_8bit(*frames: np.ndarray) -> list[np.ndarray]:
    """uint8 frames for DIS: as they are when all lie within 0-255, else one shared log curve
    255 ln(1 + x) / ln(1 + max) (module docstring)."""
    top = max(float(np.nanmax(f)) for f in frames)
    if top <= 255.0:
        return [np.clip(f, 0, 255).astype(np.uint8) for f in frames]
    k = 255.0 / np.log1p(top)
    return [np.clip(np.rint(k * np.log1p(np.maximum(f, 0))), 0, 255).astype(np.uint8) for f in frames]


def outline(sat: np.ndarray) -> np.ndarray:
    """The inner outline (1 px) of a saturated map, float32 (phase correlation in float32 is 5x
    faster than in float64 and equal to 1e-7 px), without the pixels on the image's border: a
    region cut by the frame's edge has an edge there that does not move with it."""
    m = np.asarray(sat, dtype=np.uint8)
    edge = (m > cv2.erode(m, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE)).astype(np.float32)
    edge[[0, -1], :] = 0.0
    edge[:, [0, -1]] = 0.0
    return edge


def region_shift(prev_outline: np.ndarray, cur_sat: np.ndarray, box, margin_px: int,
                 label: int | None = None) -> tuple[float, float, float]:
    """(dx, dy, response): the translation (px) taking frame t-1's saturated outline
    (`outline` of its saturated map) onto `cur_sat`'s (one region of frame t, box (y0, x0, y1,
    x1)), by phase correlation of the outlines over the box grown by `margin_px`. label: then
    `cur_sat` is frame t's region labels and the region is `label`'s. The outline is taken in
    the window only (the same as the whole frame's there: the window reaches `margin_px` past
    the region, or ends at the frame's edge)."""
    h, w = cur_sat.shape
    y0, x0, y1, x1 = box
    ya, yb = max(0, y0 - margin_px), min(h, y1 + margin_px)
    xa, xb = max(0, x0 - margin_px), min(w, x1 + margin_px)
    a = prev_outline[ya:yb, xa:xb]
    win = cur_sat[ya:yb, xa:xb]
    # the region reaches the window's border only where that is the frame's: outline() there
    # replicates and clears the border as it does on the whole frame
    b = outline(win == label if label is not None else win)
    if a.sum() == 0 or b.sum() == 0 or min(a.shape) < 2:
        return 0.0, 0.0, 0.0
    (dx, dy), resp = cv2.phaseCorrelate(a, b)
    return float(dx), float(dy), float(resp)


def saturated_components(sat: np.ndarray) -> tuple:
    """(n, labels, stats, centroids, outline) of a saturated map's 8-connected regions, laid out
    as cv2.connectedComponentsWithStats' (n counts the background, label 0; stats rows x, y, w,
    h, area; centroids x, y), and its `outline`: what `region_matches` reads of a frame
    (computed once per frame by `track`). SciPy's labelling, single-threaded: OpenCV's
    parallel one waited 4-10 ms a call for its second thread on this loaded 2-core machine."""
    from scipy import ndimage

    m = np.asarray(sat, bool)
    labels = np.empty(m.shape, np.int32)
    k = ndimage.label(m, structure=np.ones((3, 3), bool), output=labels)
    ys, xs = flat_nonzero(m)
    lab = labels[ys, xs]
    area = np.bincount(lab, minlength=k + 1)
    stats = np.zeros((k + 1, 5), np.int32)
    cents = np.zeros((k + 1, 2))
    if k:                                    # boxes: each label's pixels sorted together
        order = np.argsort(lab, kind="stable")
        starts = np.searchsorted(lab[order], np.arange(1, k + 1))
        ysr, xsr = ys[order], xs[order]
        y0, x0 = np.minimum.reduceat(ysr, starts), np.minimum.reduceat(xsr, starts)
        stats[1:, 0], stats[1:, 1] = x0, y0
        stats[1:, 2] = np.maximum.reduceat(xsr, starts) + 1 - x0
        stats[1:, 3] = np.maximum.reduceat(ysr, starts) + 1 - y0
    stats[:, 4] = area
    with np.errstate(invalid="ignore", divide="ignore"):
        cents[:, 0] = np.bincount(lab, weights=xs, minlength=k + 1) / area
        cents[:, 1] = np.bincount(lab, weights=ys, minlength=k + 1) / area
    return k + 1, labels, stats, cents, outline(m)


def region_matches(prev_sat: np.ndarray, cur_sat: np.ndarray, prev_cc: tuple | None = None,
                   cur_cc: tuple | None = None, prior: dict | None = None, measured: tuple | None = None):
    """(labels, stats, matches) of frame t's saturated regions: each region of at least
    `MIN_REGION_PX` with its translation from frame t-1 and its match there (`measure_pair`),
    two matches that took each other's earlier region exchanged where that moves them less
    (region_motion.py `unswap`). A matched region that grew or shrank by more than
    `GROWTH_SHIFT` (and at most `CENTROID_GROWTH_MAX`) takes the shift of its centroid instead:
    outlines of two sizes correlate at either edge (+-3 px on a lamp growing 10 %), the centroid
    of a light growing about its centre stays put. labels, stats: cv2.connectedComponentsWithStats
    of `cur_sat`. prev_cc, cur_cc: the frames' `saturated_components` when already computed.
    prior: {frame t-1 label: its shift from frame t-2} where known (`unswap`'s constant-velocity
    prediction). measured: `measure_pair`'s result for these frames when already computed (it
    does not depend on `prior`; it is read, not changed)."""
    from dataclasses import replace

    from poevp_optics.control.region_motion import unswap

    labels, stats, cents, prev_labels, prev_stats, prev_cents, matches, remeasure = \
        measured or measure_pair(prev_sat, cur_sat, prev_cc, cur_cc)
    matches = dict(unswap(matches, prev_labels, prev_stats, labels, stats, remeasure, prior))
    for k, m in matches.items():
        if m.prev_label and abs(m.growth - 1.0) > GROWTH_SHIFT and \
                1.0 / CENTROID_GROWTH_MAX <= m.growth <= CENTROID_GROWTH_MAX:
            matches[k] = replace(m, shift=tuple(float(v) for v in cents[k] - prev_cents[m.prev_label]))
    return labels, stats, matches


def measure_pair(prev_sat: np.ndarray, cur_sat: np.ndarray, prev_cc: tuple | None = None,
                 cur_cc: tuple | None = None) -> tuple:
    """What `region_matches` reads of two frames before `unswap`: (labels, stats, centroids of
    frame t; labels, stats, centroids of frame t-1; matches; remeasure). Each region of at least
    `MIN_REGION_PX` gets its translation from frame t-1 (`region_shift`) and its match there
    (region_motion.py `match_regions`: mutual, areas alike, response >= `MIN_RESPONSE`; a region
    without one is new). A region left new takes over the earlier region its neighbours' shift
    puts it on from a holder that moved much further (`reclaim`: a lamp whose twin took its old
    place), and is measured again with the earlier regions already taken hidden
    (`rematch_left`: two like lights crossing). remeasure(k, hidden, only): region k's shift
    against frame t-1's outline without its `hidden` regions, or of region `only` alone."""
    from poevp_optics.control.region_motion import match_regions, reclaim, rematch_left

    n, labels, stats, cents, _ = cur_cc or saturated_components(cur_sat)
    _, prev_labels, prev_stats, prev_cents, prev_outline = prev_cc or saturated_components(prev_sat)
    shifts = {}
    for k in range(1, n):
        x, y, bw, bh, area = (int(v) for v in stats[k])
        if area >= MIN_REGION_PX:
            shifts[k] = region_shift(prev_outline, labels, (y, x, y + bh, x + bw), SEARCH_PX + max(bw, bh), label=k)
    matches = match_regions(prev_labels, prev_stats, labels, stats, shifts, MIN_RESPONSE)

    def remeasure(k, hidden=frozenset(), only=None):
        x, y, bw, bh, _ = (int(v) for v in stats[k])
        keep = prev_labels == only if only is not None else ~np.isin(prev_labels, list(hidden))
        return region_shift(prev_outline * keep, labels, (y, x, y + bh, x + bw), SEARCH_PX + max(bw, bh), label=k)

    matches = reclaim(prev_labels, prev_stats, labels, stats, matches, remeasure)
    matches = rematch_left(prev_labels, prev_stats, labels, stats, matches, remeasure, MIN_RESPONSE)
    return labels, stats, cents, prev_labels, prev_stats, prev_cents, matches, remeasure


def region_translations(prev_sat: np.ndarray, cur_sat: np.ndarray, flow: np.ndarray) -> list[tuple]:
    """Overwrite `flow` (H, W, 2; x, y) inside each saturated region of frame t with the region's
    translation from frame t-1 (module docstring), or with zero where the region has no match
    in frame t-1 (new: predicted where it is); returns [(box, dx, dy, response, matched)]."""
    labels, stats, matches = region_matches(prev_sat, cur_sat)
    out = []
    for k, m in matches.items():
        x, y, bw, bh, _ = (int(v) for v in stats[k])
        inside = labels == k
        flow[inside] = m.shift if m.prev_label else (0.0, 0.0)
        out.append(((y, x, y + bh, x + bw), *m.shift, m.response, bool(m.prev_label)))
    return out


def flat_nonzero(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, columns) of a 2-D mask's set pixels in raster order, as `np.nonzero` gives them:
    from the flat indices (for a bool mask 5-10x faster than the 2-D search)."""
    return np.divmod(np.flatnonzero(mask), mask.shape[1])


def landing_px(pos: np.ndarray, shift) -> np.ndarray:
    """The whole pixel (int64) a pixel at `pos` (px, integer) lands on when moved by `shift` (px,
    taken at float32, as a flow field holds it; rounded to the nearest pixel, halves up). Halves
    round one way for every pixel: rounding them to even would land a region moved by 2.5 px
    striped, its columns 4, 5, 6, 7 on 6, 8, 8, 10."""
    return np.floor(pos + np.asarray(shift, np.float32) + 0.5).astype(np.int64)


def forward_splat(frame: np.ndarray, flow: np.ndarray, min_value: float = 128.0,
                  min_motion_px: float = 0.5) -> np.ndarray:
    """Move bright (>= min_value) moving (|flow| >= min_motion_px) pixels by `flow` (px, (H, W,
    2) as x, y); every other pixel keeps its value (hold). Brightest wins where pixels land
    together and where one lands on a pixel that stays: a standing clipped light is not eaten
    by its own halo's pixels carried in by the dense flow (a fog glow whose clipped region
    stands while the flow reads its wavering edge as motion), nor by a dimmer light passing."""
    h, w = frame.shape
    bright = np.flatnonzero(frame >= min_value)          # the flow is read there only
    fx, fy = flow[..., 0].ravel()[bright], flow[..., 1].ravel()[bright]
    mag2 = fx ** 2 + fy ** 2
    keep = mag2 >= min_motion_px ** 2
    ys, xs = np.divmod(bright[keep], w)
    out = np.array(frame, dtype=np.float32, copy=True)
    if ys.size == 0:
        return out
    fx, fy = fx[keep], fy[keep]
    tx, ty = landing_px(xs, fx), landing_px(ys, fy)
    inside = (tx >= 0) & (tx < w) & (ty >= 0) & (ty < h)
    vals = frame[ys, xs][inside]
    dest = (ty * w + tx)[inside]
    # pixels the highlight leaves and nothing lands on show background: estimate it by a grey
    # erosion reaching past the trailing edge (radius: the largest displacement + 1 px)
    radius = int(np.ceil(np.sqrt(mag2[keep]).max())) + 1
    k = 2 * radius + 1
    # eroded over the moving pixels' box grown by the radius only: the same values there (the
    # window of each reaches no further, and the box ends at the frame's edge or inside it)
    ya, yb = max(0, int(ys.min()) - radius), min(h, int(ys.max()) + radius + 1)
    xa, xb = max(0, int(xs.min()) - radius), min(w, int(xs.max()) + radius + 1)
    background = cv2.erode(out[ya:yb, xa:xb], np.ones((k, k), np.uint8), borderType=cv2.BORDER_REPLICATE)
    out[ys, xs] = background[ys - ya, xs - xa]
    flat = out.ravel()
    np.maximum.at(flat, dest, vals)
    return out
