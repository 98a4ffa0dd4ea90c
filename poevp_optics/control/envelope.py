"""The mask's smooth upper envelope (masks.py's module docstring): one sigma over the whole frame
(`smooth_envelope`), or each bright region's body and its brighter parts apart
(`body_envelope`, `mask.envelope = "region_body"`).

Why apart. The fixed envelope dilates the demand by R = ceil(3 smooth_px) before its blur, so
every mirror within R of a region's brightest part takes that part's dimming. That covers a
prediction that misses the region's outline by up to R, but it also spreads the brightest part's
dimming over the rest of the region. Where part of a plate is lit and the rest is in a shadow
(a nearer car cutting one of our two lamps off it: the lit part 2.3x the shaded one, the
shadow's edge standing still in the image while the plate slides under it), the whole plate is
dimmed for its lit part, and when the lit part leaves, the plate's white (its brightest tenth)
falls under the band: 2.3x is more than a 40-90 % band holds (2.25x). A plate's white is read on
its brightest tenth, so a mask that dims each part of the plate for itself loses at most a part.

`body_envelope`, per 8-connected region of mirrors whose demand reaches saturation with the
all-white mask:
- its body level b is the median demand of its mirrors within BODY_SPAN (3x) of its peak: a
  plate's shaded part counts (2.3x below its lit part), the road a lamp lights does not;
- the demand capped at b takes the fixed envelope (sigma smooth_px): the region's outline keeps
  the whole radius R at its body's level, whatever the prediction's miss;
- its mirrors above b take the envelope the region's own last miss m asks for: m is the largest
  distance (mirrors, Euclidean) from one of the region's captured mirrors to the nearest mirror
  the last mask was computed as bright for, and sigma = m / 2 within [floor, smooth_px]
  (`region_sigma`, measured after each capture; a region of the next mask takes the largest
  sigma of the last capture's regions it overlaps, smooth_px where it overlaps none: nothing
  measured of it). The dilation's radius 3 sigma = 1.5 m then ends sigma beyond a mirror m
  away, and the blur still gives that mirror Phi(1) = 84 % of the part's dimming: 1.19x over
  the aim at most, inside the 1.5x the band leaves above it (0.9 / 0.6). (`predictor_error`'s
  sigma = m, for the whole frame, gives it Phi(2) = 98 %, and spreads the part's dimming twice
  as far.) A region whose prediction held to a mirror or two keeps its lit part's dimming on its
  lit part; one that outran its prediction by 2 smooth_px or more gets the fixed envelope back.
The envelope is the larger of the two, >= the demand on every mirror (each is >= its own part):
no mirror whose demand is known is under-attenuated. Where nothing was measured yet, or every
region's sigma reaches smooth_px (its miss 2 smooth_px), it is the fixed envelope bit for bit. What it gives up: a
brighter part that the prediction misplaces by more than its region's last miss lands under the
body's dimming, over-exposed by at most its ratio to the body.

The exposure controller's carry radius (exposure_control.py) stays ceil(3 smooth_px).
"""

from __future__ import annotations

import numpy as np


def smooth_envelope(frame: np.ndarray, smooth_px: float) -> np.ndarray:
    """Smooth upper envelope (>= frame): dilation of radius ceil(3 sigma), then a Gaussian of
    sigma = smooth_px truncated at that radius (masks.py's module docstring)."""
    import cv2

    if smooth_px <= 0:
        return np.asarray(frame, dtype=np.float32)
    f = np.asarray(frame, dtype=np.float32)        # float32: 2x faster in OpenCV, 1e-7 relative
    r = int(np.ceil(3 * smooth_px))
    size = 2 * r + 1
    square = np.ones((size, size), np.uint8)        # covers the square blur window exactly
    dil = cv2.dilate(f, square, borderType=cv2.BORDER_REPLICATE)
    env = cv2.GaussianBlur(dil, (size, size), sigmaX=smooth_px, borderType=cv2.BORDER_REPLICATE)
    # float32 kernel weights sum to 1 within a few ulp: lift by 1e-6 to keep env >= frame
    return env * np.float32(1 + 1e-6)


#: How far below its peak a region's mirrors count towards its body (x): 3, above the 2.3x of a
#: plate with one of our two lamps cut off it, far below a lamp's core over the road it lights.
BODY_SPAN = 3.0


def _regions(bright: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """8-connected regions of `bright`: (count incl. background 0, labels int32, stats as cv2's
    connectedComponentsWithStats: x, y, w, h, area per label)."""
    import cv2

    n, labels, stats, _ = cv2.connectedComponentsWithStats(np.asarray(bright, np.uint8), connectivity=8)
    return n, labels, stats


def region_sigma(aimed: np.ndarray, captured: np.ndarray, smooth_px: float, floor: float) -> np.ndarray:
    """float32 map on the grid of `captured`: on each region of `captured` (bool), the sigma its
    miss beyond `aimed` (bool, the mirrors the mask was computed as bright for) asks for, half
    the miss within [min(floor, smooth_px), smooth_px] (module docstring); NaN where nothing was
    captured bright."""
    import cv2

    captured = np.asarray(captured, dtype=bool)
    aimed = np.asarray(aimed, dtype=bool)
    out = np.full(captured.shape, np.nan, np.float32)
    if not captured.any():
        return out
    if not aimed.any():
        out[captured] = float(smooth_px)
        return out
    dist = cv2.distanceTransform((~aimed).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    n, labels, _ = _regions(captured)
    miss = np.zeros(n, np.float64)
    np.maximum.at(miss, labels[captured], dist[captured].astype(np.float64))
    out[captured] = np.clip(miss / 2, min(floor, float(smooth_px)), float(smooth_px))[labels[captured]]
    return out


def region_radii(sigma: np.ndarray | None) -> list[int] | None:
    """The smallest and largest radius ceil(3 sigma), mirrors, over the regions of the last
    capture (for the report); None before any region was measured."""
    if sigma is None or not np.isfinite(sigma).any():
        return None
    s = sigma[np.isfinite(sigma)]
    return [int(np.ceil(3 * float(s.min()))), int(np.ceil(3 * float(s.max())))]


def _body_levels(d: np.ndarray, bright: np.ndarray, n: int, labels: np.ndarray) -> np.ndarray:
    """Per region label (0: none), the median demand of its mirrors within BODY_SPAN of its peak."""
    peak = np.zeros(n)
    np.maximum.at(peak, labels[bright], d[bright])
    near = bright & (d * BODY_SPAN >= peak[labels])
    lab, vals = labels[near], d[near]
    order = np.lexsort((vals, lab))                    # by region, then demand
    lab_s, val_s = lab[order], vals[order]
    start = np.searchsorted(lab_s, np.arange(1, n))
    count = np.bincount(lab_s, minlength=n)[1:]
    body = np.zeros(n)
    body[1:] = val_s[start + (count - 1) // 2]         # the median (lower middle)
    return body


def body_envelope(demand: np.ndarray, bright: np.ndarray, sigma_last: np.ndarray | None,
                  smooth_px: float) -> np.ndarray:
    """The envelope of `demand` (module docstring): the regions of `bright` (bool, same grid)
    split into body and brighter parts, the brighter parts at the largest finite `sigma_last`
    their region overlaps (smooth_px where none; the fixed envelope where `sigma_last` is None).
    float32, as `smooth_envelope`."""
    d = np.asarray(demand, dtype=np.float64)
    bright = np.asarray(bright, dtype=bool)
    if sigma_last is None or not bright.any() or smooth_px <= 0:
        return smooth_envelope(d, smooth_px)
    n, labels, stats = _regions(bright)
    sigma = np.full(n, -1.0)
    known = np.where(np.isfinite(sigma_last), sigma_last, -1.0).astype(np.float64)
    np.maximum.at(sigma, labels[bright], known[bright])
    narrow = (sigma >= 0) & (sigma < smooth_px)
    narrow[0] = False
    if not narrow.any():
        return smooth_envelope(d, smooth_px)
    body = _body_levels(d, bright, n, labels)
    split = narrow[labels] & (d > body[labels])        # the brighter parts of the narrow regions
    env = smooth_envelope(np.where(split, body[labels], d), smooth_px)
    h, w = d.shape
    for k in np.nonzero(narrow)[0]:
        r = 2 * int(np.ceil(3 * sigma[k]))      # the dilation's radius, then the blur's
        x, y, bw, bh = (int(v) for v in stats[k, :4])
        y0, y1, x0, x1 = max(y - r, 0), min(y + bh + r, h), max(x - r, 0), min(x + bw + r, w)
        part = np.where(split[y0:y1, x0:x1] & (labels[y0:y1, x0:x1] == k), d[y0:y1, x0:x1], 0.0)
        env[y0:y1, x0:x1] = np.maximum(env[y0:y1, x0:x1], smooth_envelope(part, float(sigma[k])))
    return env
