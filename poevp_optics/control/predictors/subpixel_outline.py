"""A moving highlight's clipped outline placed to a fraction of a pixel.

A region trackers' prediction moves each saturated region by its extrapolated displacement d,
and rounding d to whole pixels misplaces the outline by up to half a pixel on each axis: on a
headlamp's clipped ellipse of 40 x 26 px that alone costs the mask a few per cent of its IoU,
whatever the motion model. The pixels just outside the clip tell where the outline really is:
near its clip level a lamp's image falls off smoothly, so its log brightness is close to linear
across the outline, ln I(p) = ln I(q) - s |p - q| over a pixel or two (a Gaussian spot
A exp(-r^2 / w^2) clipped at T has slope s = 2 sqrt(ln(A / T)) / w there).

`moved_outline` fits s to the unclipped halo around the region (log brightness against the
distance to the region, least squares), carries each clipped pixel's log brightness on from its
nearest unclipped neighbour at that slope (above the clip; pixels already above the 8-bit clip,
as in the demodulated loop, keep their own; where that neighbour is too dark for the slope, a
sharp edge such as a plate's border or a character's stroke, the crossing is put halfway, as
rounding puts it), shifts that log image by d with bilinear interpolation, and takes the pixels
at or above the clip level as the moved outline. For a log-linear edge this places the clip
crossing exactly for any fractional d; bilinear interpolation of a linear function is exact.
Where the halo cannot tell (fewer than `MIN_HALO_PX` lamp-dominated pixels, or no fall-off) it
returns None and the caller rounds.

Only the outline moves by the fraction. `paint` corrects the whole-pixel move the caller has
already made (forward_splat): it clips the outline's pixels that move left unclipped and
unclips the move's pixels beyond the outline; every pixel clipped by both keeps the value the
whole-pixel move carried. In the demodulated loop those values are the measured brightness
above the clip, which the pixel-wise mask law follows mirror by mirror over a plate's
characters. A character's stroke is a sharp edge, not the smooth fall-off the outline rule
reads, and interpolating it by a fraction of a pixel spreads it over two mirrors: on a plate
under 10x our beams (benchmarks/loop_alpr.py, heldout_receding) that cost the closed loop two
of fourteen reads.

The approach is ours; the clip-crossing reading is edge localisation from the intensity profile,
as in sub-pixel edge detectors (Devernay, A non-maxima suppression method for edge detection
with sub-pixel accuracy, INRIA RR-2724, 1995).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from poevp_optics.control.predictors.flow import SATURATED, landing_px

#: The clip level (8-bit DN) the outline is taken at: the mask laws' clip marker.
CLIP_LEVEL = SATURATED
#: Values up to this (DN) are the 8-bit clip marker, not a measured brightness.
CLIP_MARKER_MAX = 255.5
#: Halo read around the region: unclipped pixels within this distance (px) of it and at least
#: `HALO_MIN_DN` bright (where 1-2 DN of read noise moves the log by under 15 %). A floor of a
#: quarter of full scale keeps only the nearest ring, whose slope is then read over too short a
#: distance, and leaves more clipped pixels undimmed on the held-out traffic.
HALO_RING_PX = 3.5
HALO_MIN_DN = 12.0
MIN_HALO_PX = 6
#: Least log-brightness fall-off (per px) read as an edge; below it the halo is flat (a glow) and
#: the outline is rounded instead.
MIN_SLOPE = 0.05
#: Margin (px) of the window read around the region's box.
MARGIN_PX = 4


@dataclass(frozen=True)
class MovedOutline:
    """The moved region in a window (y0, x0) of the frame: its clipped pixels placed to a fraction
    of a pixel (bool), where the whole-pixel move puts the region (bool), and the interpolated
    brightness (DN: at least the clip marker 255 on the clipped pixels, where the source held
    values above it their interpolation; below the clip level elsewhere)."""

    y0: int
    x0: int
    clipped: np.ndarray
    rounded: np.ndarray
    values: np.ndarray


def halo_slope(log_crop: np.ndarray, region: np.ndarray, crop: np.ndarray) -> float | None:
    """Log-brightness fall-off (per px) of the unclipped halo around `region` (least squares of
    ln I against the distance to the region); None where too few halo pixels or no fall-off."""
    dist = cv2.distanceTransform((~region).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    halo = (crop < CLIP_LEVEL) & (dist > 0) & (dist <= HALO_RING_PX) & (crop >= HALO_MIN_DN)
    if int(halo.sum()) < MIN_HALO_PX:
        return None
    x, y = dist[halo].astype(np.float64), log_crop[halo]
    var = float(((x - x.mean()) ** 2).sum())
    if var <= 1e-9:
        return None
    s = -float(((x - x.mean()) * (y - y.mean())).sum()) / var
    return s if s >= MIN_SLOPE else None


def extrapolated_log(log_crop: np.ndarray, region: np.ndarray, marker: np.ndarray, slope: float) -> np.ndarray:
    """The crop's log brightness with each clip-marker pixel p of `region` carried on from its
    nearest pixel q outside the region at `slope` per px. Where q is too dark for that (the clip
    level would lie beyond p: a sharp edge, like a plate's border or a character's stroke, not a
    fall-off), p mirrors q about the clip level, which puts the crossing halfway between them, as
    rounding would."""
    _, lab = cv2.distanceTransformWithLabels(region.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5,
                                             labelType=cv2.DIST_LABEL_PIXEL)
    zy, zx = np.nonzero(~region)
    index = np.zeros(int(lab.max()) + 1, np.int64)
    index[lab[~region]] = np.arange(zy.size)     # OpenCV labels the zero pixels in scan order
    ry, rx = np.nonzero(region & marker)
    near = index[lab[ry, rx]]
    qy, qx = zy[near], zx[near]
    lq, dist = log_crop[qy, qx], np.hypot(ry - qy, rx - qx)
    smooth = lq + slope * dist
    sharp = 2.0 * np.log(CLIP_LEVEL) - lq + slope * (dist - 1.0)
    out = log_crop.copy()
    out[ry, rx] = np.maximum(np.where(np.log(CLIP_LEVEL) - lq <= slope, smooth, sharp), np.log(CLIP_LEVEL) + 1e-3)
    return out


def moved_outline(frame: np.ndarray, inside: np.ndarray, box, d) -> MovedOutline | None:
    """The region `inside` (bool over `box` = (y0, x0, y1, x1) of `frame`, 8-bit DN) moved by
    d = (dx, dy) px with its outline placed to a fraction of a pixel (module docstring); None
    where the halo cannot tell or the region has no pixel outside the frame's clip."""
    h, w = frame.shape
    y0, x0, y1, x1 = box
    a0, b0, a1, b1 = max(y0 - MARGIN_PX, 0), max(x0 - MARGIN_PX, 0), min(y1 + MARGIN_PX, h), min(x1 + MARGIN_PX, w)
    crop = np.asarray(frame[a0:a1, b0:b1], np.float64)
    region = np.zeros(crop.shape, bool)
    region[y0 - a0:y1 - a0, x0 - b0:x1 - b0] = inside
    if region.all():
        return None
    log_crop = np.log(np.maximum(crop, 0.5))
    slope = halo_slope(log_crop, region, crop)
    if slope is None:
        return None
    marker = (crop >= CLIP_LEVEL) & (crop <= CLIP_MARKER_MAX)
    log_x = extrapolated_log(log_crop, region, marker, slope)
    iy, ix = int(np.floor(d[1])), int(np.floor(d[0]))
    shift = np.float32([[1, 0, d[0] - ix], [0, 1, d[1] - iy]])
    size = (crop.shape[1], crop.shape[0])
    moved = cv2.warpAffine(log_x.astype(np.float32), shift, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    own = cv2.warpAffine(np.where(marker, np.log(255.0), log_crop).astype(np.float32), shift, size,
                         flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    near = cv2.warpAffine(region.astype(np.uint8), shift, size, flags=cv2.INTER_LINEAR) > 0
    near = cv2.dilate(near.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    clipped = near & (moved >= np.log(CLIP_LEVEL))
    values = np.where(clipped, np.maximum(np.exp(own), 255.0), np.minimum(np.exp(moved), CLIP_LEVEL - 0.5))
    return MovedOutline(a0 + iy, b0 + ix, clipped, rounded_footprint(region, (a0, b0), (a0 + iy, b0 + ix), d),
                        values.astype(np.float32))


def rounded_footprint(region: np.ndarray, origin, window, d) -> np.ndarray:
    """Where forward_splat's whole-pixel move puts `region` (bool over a crop at `origin` (y, x)
    of the frame), in the same-sized crop at `window`: each pixel lands where the splat's own
    rounding puts it (flow.py `landing_px`)."""
    ry, rx = np.nonzero(region)
    ty = landing_px(ry + origin[0], d[1]) - window[0]
    tx = landing_px(rx + origin[1], d[0]) - window[1]
    ok = (ty >= 0) & (ty < region.shape[0]) & (tx >= 0) & (tx < region.shape[1])
    out = np.zeros(region.shape, bool)
    out[ty[ok], tx[ok]] = True
    return out


def paint(out: np.ndarray, moved: MovedOutline) -> None:
    """Correct the whole-pixel move already in `out` (in place) to `moved`'s outline, cut at the
    frame's edges: the outline's pixels the move left under the clip take their interpolated
    brightness, the move's clipped pixels beyond the outline take theirs (under the clip), and
    every other pixel keeps the value the move carried."""
    h, w = out.shape
    ch, cw = moved.clipped.shape
    c0, d0 = max(moved.y0, 0), max(moved.x0, 0)
    c1, d1 = min(moved.y0 + ch, h), min(moved.x0 + cw, w)
    if c1 <= c0 or d1 <= d0:
        return
    window = np.s_[c0 - moved.y0:c1 - moved.y0, d0 - moved.x0:d1 - moved.x0]
    sel, foot, vals = moved.clipped[window], moved.rounded[window], moved.values[window]
    view = out[c0:c1, d0:d1]
    change = (sel & (view < CLIP_LEVEL)) | (foot & ~sel & (view >= CLIP_LEVEL))
    view[change] = vals[change]
