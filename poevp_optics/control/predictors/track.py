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
   `match_regions`); that region is followed on to frame t-2 the same way, and so on:
   displacements d_t, d_{t-1}, d_{t-2} (px, x and y), each with its correlation response. A
   weak response or a lost match ends the chain; a region with no match at all is new and is
   predicted where it is.
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
from poevp_optics.control.predictors.flow import MIN_REGION_PX, SATURATED, forward_splat, log_8bit, region_matches
from poevp_optics.control.region_motion import components

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


def region_tracks(history: list[np.ndarray], max_chain: int = MAX_CHAIN) -> tuple[list[RegionTrack], np.ndarray]:
    """(tracks, labels): every saturated region of the last frame with its displacement chain
    (module docstring, step 1), and the last frame's region labels (0 = none)."""
    sats = [np.asarray(f) >= SATURATED for f in history]
    # pairs[j]: frame t-j's regions, each with its shift from frame t-j-1 and its match there
    pairs = [region_matches(sats[-2 - j], sats[-1 - j]) for j in range(min(max_chain, len(history) - 1))]
    if pairs:
        labels, stats, _ = pairs[0]
    else:
        labels, stats = components(sats[-1])
    tracks = []
    for k in range(1, len(stats)):
        x, y, bw, bh, area = (int(v) for v in stats[k])
        if area < MIN_REGION_PX:
            continue
        disp, resp, label = [], [], k
        for _, _, matches in pairs:
            m = matches.get(label)
            if m is None or not m.prev_label:
                break                                    # new in this frame, or too small to follow
            disp.append(m.shift)
            resp.append(m.response)
            label = m.prev_label
        tracks.append(RegionTrack(k, (y, x, y + bh, x + bw), area, tuple(disp), tuple(resp)))
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
                d = (0.0, 0.0)                         # new (no match back): predicted where it is
            y0, x0, y1, x1 = tr.box
            inside = labels[y0:y1, x0:x1] == tr.label
            flow[y0:y1, x0:x1, 0][inside] = d[0]
            flow[y0:y1, x0:x1, 1][inside] = d[1]
        return forward_splat(frames[-1], flow)

    def describe(self) -> dict:
        return {"name": self.name, "context_frames": MAX_CHAIN + 1}
