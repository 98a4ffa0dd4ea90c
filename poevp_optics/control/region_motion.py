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
is matched to the previous region it overlaps most; one without overlap (new, or moved more than
its own size) is not moved. The box-extrapolation of tracked regions is the constant-velocity
model of a Kalman box tracker's prediction step (SORT: Bewley et al., ICIP 2016, box centre and
scale with constant velocity), here without the filter: the last two frames set the motion.
"""

from __future__ import annotations

import numpy as np

#: Largest growth (and shrink, its inverse) of a region's box per frame that is extrapolated.
MAX_GROWTH = 2.0


def _components(bright: np.ndarray):
    """(labels, stats) of the 8-connected regions of `bright`; stats rows: x, y, w, h, area."""
    import cv2

    _, labels, stats, _ = cv2.connectedComponentsWithStats(bright.astype(np.uint8), connectivity=8)
    return labels, stats


def _axis_map(p0: float, pn: float, c0: float, cn: float) -> tuple[float, float]:
    """(a, b) of x' = a x + b taking the interval [p0, p0 + pn) onto [c0, c0 + cn), a limited
    to [1 / MAX_GROWTH, MAX_GROWTH]."""
    a = float(np.clip(cn / pn, 1.0 / MAX_GROWTH, MAX_GROWTH))
    return a, (c0 + cn / 2.0) - a * (p0 + pn / 2.0)


def extrapolate(prev: np.ndarray, cur: np.ndarray, level: float) -> np.ndarray:
    """`cur` with each region of demand >= `level` moved on one frame (module docstring), 0
    elsewhere; same units as `cur` (e-). prev, cur: demand maps of two consecutive frames."""
    import cv2

    out = np.zeros(cur.shape, np.float32)
    lp, sp = _components(np.asarray(prev) >= level)
    lc, sc = _components(np.asarray(cur) >= level)
    h, w = cur.shape
    for k in range(1, len(sc)):
        region = lc == k
        ids, counts = np.unique(lp[region], return_counts=True)
        counts, ids = counts[ids > 0], ids[ids > 0]
        if ids.size == 0:
            continue
        px, py, pw, ph = sp[ids[np.argmax(counts)], :4].astype(np.float64)
        cx, cy, cw, ch = sc[k, :4].astype(np.float64)
        ax, bx = _axis_map(px, pw, cx, cw)
        ay, by = _axis_map(py, ph, cy, ch)
        nw, nh = max(1, int(round(ax * cw))), max(1, int(round(ay * ch)))
        nx = int(round(ax * (cx + cw / 2.0) + bx - nw / 2.0))
        ny = int(round(ay * (cy + ch / 2.0) + by - nh / 2.0))
        box = (slice(int(cy), int(cy + ch)), slice(int(cx), int(cx + cw)))
        crop = np.where(region[box], np.asarray(cur)[box], 0.0).astype(np.float32)
        moved = cv2.resize(crop, (nw, nh), interpolation=cv2.INTER_NEAREST)
        y0, x0, y1, x1 = max(ny, 0), max(nx, 0), min(ny + nh, h), min(nx + nw, w)
        if y1 <= y0 or x1 <= x0:
            continue
        out[y0:y1, x0:x1] = np.maximum(out[y0:y1, x0:x1], moved[y0 - ny:y1 - ny, x0 - nx:x1 - nx])
    return out
