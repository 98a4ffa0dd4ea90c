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
   `region_shift`: Kuglin & Hines 1975), its footprint in frame t-1 is frame t-1's saturated map
   near the region shifted back, and so on: displacements d_t, d_{t-1}, d_{t-2} (px, x and y),
   each with its correlation response (weak responses end the chain).
2. **Extrapolate.** The next displacement is a combination of the measured ones,
   d_{t+1} = c_0 d_t + c_1 d_{t-1} + c_2 d_{t-2}: `track` uses the closed forms below; `track_net`
   takes the coefficients from a small trained network (track_net.py) fed only with quantities
   that do not change under rotation or mirroring of the image (lengths and dot products of the
   displacements), so it has no preferred direction by construction.
3. **Move.** Dense DIS flow (flow.py) moves the rest of the frame as `flow` does; each region's
   pixels are forward-splatted by its extrapolated displacement, brightest wins, values moved
   exactly (a clipped pixel lands clipped: the clip marker survives the prediction).

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
from poevp_optics.control.predictors.flow import (MIN_REGION_PX, MIN_RESPONSE, SATURATED, SEARCH_PX,
                                                  forward_splat, log_8bit, outline, region_shift)

#: Longest chain of displacements followed back (four frames of history: the loop keeps four).
MAX_CHAIN = 3
#: Largest change of displacement between frames, relative to |d_t|, still read as acceleration.
ACCEL_GATE = 1.0


@dataclass(frozen=True)
class RegionTrack:
    """One saturated region of the last frame and its measured displacements (px, newest
    first: d_t, d_{t-1}, ...), each with its phase-correlation response."""

    label: int                              # the region's label in `region_tracks`' labels
    box: tuple[int, int, int, int]          # (y0, x0, y1, x1) in frame t
    area_px: int
    displacements: tuple[tuple[float, float], ...]
    responses: tuple[float, ...]


def _shifted(mask: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """`mask` (bool) translated by (dx, dy) px, rounded to whole pixels, zero-filled."""
    h, w = mask.shape
    m = np.float32([[1, 0, round(dx)], [0, 1, round(dy)]])
    return cv2.warpAffine(mask.astype(np.uint8), m, (w, h), flags=cv2.INTER_NEAREST, borderValue=0) > 0


def region_tracks(history: list[np.ndarray], max_chain: int = MAX_CHAIN) -> tuple[list[RegionTrack], np.ndarray]:
    """(tracks, labels): every saturated region of the last frame with its displacement chain
    (module docstring, step 1), and the last frame's region labels (0 = none)."""
    sats = [np.asarray(f) >= SATURATED for f in history]
    outlines = [outline(s) for s in sats[:-1]]
    n, labels, stats, _ = cv2.connectedComponentsWithStats(sats[-1].astype(np.uint8), connectivity=8)
    tracks = []
    grow = np.ones((5, 5), np.uint8)
    for k in range(1, n):
        x, y, bw, bh, area = (int(v) for v in stats[k])
        if area < MIN_REGION_PX:
            continue
        region = labels == k
        box = (y, x, y + bh, x + bw)
        disp, resp = [], []
        cur, cur_box = region, box
        for j in range(min(max_chain, len(history) - 1)):
            prev_outline = outlines[-1 - j]
            margin = SEARCH_PX + max(cur_box[2] - cur_box[0], cur_box[3] - cur_box[1])
            dx, dy, r = region_shift(prev_outline, cur, cur_box, margin)
            if r < MIN_RESPONSE:
                break
            disp.append((dx, dy))
            resp.append(r)
            # the region's footprint one frame back: that frame's saturated pixels near it
            back = cv2.dilate(_shifted(cur, -dx, -dy).astype(np.uint8), grow) > 0
            cur = back & sats[-2 - j]
            if cur.sum() < MIN_REGION_PX:
                break
            ys, xs = np.nonzero(cur)
            cur_box = (int(ys.min()), int(xs.min()), int(ys.max()) + 1, int(xs.max()) + 1)
        tracks.append(RegionTrack(k, box, area, tuple(disp), tuple(resp)))
    return tracks, labels


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


class RegionTracker(Predictor):
    """`track`: DIS flow for the frame, a closed-form extrapolated displacement per saturated
    region (module docstring). Subclasses replace `next_displacement`."""

    name = "track"
    needs_frames = 2              # works from two frames (constant velocity), better with four
    min_input_px = 12             # OpenCV's DIS refuses frames narrower or lower than 12 px

    def __init__(self, preset: int = cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST):
        self.dis = cv2.DISOpticalFlow_create(preset)

    def next_displacement(self, tracks: list[RegionTrack]) -> list[np.ndarray]:
        return [closed_form_displacement(t.displacements) for t in tracks]

    def __call__(self, history):
        frames = [np.asarray(f, dtype=np.float32) for f in history[-(MAX_CHAIN + 1):]]
        p8, c8 = log_8bit(frames[-2], frames[-1])
        flow = self.dis.calc(p8, c8, None)
        tracks, labels = region_tracks(frames)
        for tr, d in zip(tracks, self.next_displacement(tracks)):
            if not tr.displacements:
                continue                               # no match back: DIS's flow moves it
            y0, x0, y1, x1 = tr.box
            inside = labels[y0:y1, x0:x1] == tr.label
            flow[y0:y1, x0:x1, 0][inside] = d[0]
            flow[y0:y1, x0:x1, 1][inside] = d[1]
        return forward_splat(frames[-1], flow)

    def describe(self) -> dict:
        return {"name": self.name, "context_frames": MAX_CHAIN + 1}
