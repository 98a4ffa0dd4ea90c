"""Regions the trackers could not follow back one frame, moved with the lights they came from.

A region of frame t with no match in frame t-1 (track.py step 1: the match must be mutual and the
areas alike) is new. Most new regions are not new lights: two lights whose outlines ran into one
(the lamps of two cars passing each other, a turning car's lamp pair closing up as it
foreshortens), a light split into pieces (the same lamps parting), or a light whose outline
changed more than a match allows (a lamp coming in past the frame's edge). Each such region
covers frame t-1 regions that lost their match: lights the trackers followed up to frame t-1 and
that are nowhere in frame t on their own. Where two lights of like size merge, the merged
outline may still match one of them (its area under twice that light's): a matched region whose
area grew by `MERGE_AREA_GAIN` or more holds the other, lost, light as well, and its one measured
shift is the merged outline's, neither light's.

Per lost frame t-1 region with a chain (its displacements to t-1): its step to frame t is its own
motion extrapolated as the predictor extrapolates any region's (`RegionTracker.own_motion`,
standing where its chain wavers) plus the frame's measured global shift g_t. Its pixels moved by
that step land on frame t's regions; a new region (or a matched one that grew as above) on which
at least `PART_OVERLAP` of them land holds it as a part. Every frame t region that holds a lost
light is moved by its parts (the lost ones and any followed light that lands on it too), not by
its own shift. A part's chain at frame t is (its predicted step, its measured ones), and the
predictor extrapolates that chain one frame on like any other (`RegionTracker.next_displacement`).
The region's pixels each move with the part whose predicted centroid at frame t is nearest (a
merged pair parts as its lights move on; a split light's pieces each move as the light did). A
new region that holds no part is a light switched on, or one the trackers had not followed: it
moves with the global motion alone.

A track with no detection of its own carried on by its prediction is the missed-detection case
of track association (Bar-Shalom, Daum & Huang, "The probabilistic data association filter",
IEEE Control Systems 29(6), 2009); the pixels split by the nearest predicted centre is a Voronoi
partition.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

#: Fraction of a lost region's moved pixels that must land on a region for it to be a part.
PART_OVERLAP = 0.25
#: Least area ratio (frame t over t-1) of a region that kept its match for it to hold a lost light:
#: a merge adds the other light's area; a light's outline alone changes its area by a few per cent
#: (track.py GROWTH_DEADBAND), and a wet road's standing glints, touching and parting, by less
#: than this (a region held for less moved them with lights that were not theirs).
MERGE_AREA_GAIN = 1.3


@dataclass(frozen=True)
class Part:
    """A light followed to frame t-1 inside a frame t region that holds a lost one: its
    predicted centroid at frame t (px, x and y) and its chain at frame t (track.py `RegionTrack`,
    newest first: the predicted step, then its measured displacements)."""

    centre: np.ndarray
    track: object


def lost_parts(tracks, labels: np.ndarray, before, before_labels: np.ndarray, steps) -> dict[int, list[Part]]:
    """{label of a frame t region that holds a lost light: its parts} (module docstring). tracks,
    labels: frame t's `region_tracks`; before, before_labels: frame t-1's (the history less its
    last frame); steps(followed): each frame t-1 track's predicted step to frame t (px, x and y;
    track.py `RegionTracker.step_to_last`)."""
    claimed = {t.prev_label for t in tracks if t.prev_label}
    followed = [b for b in before if b.displacements]
    if not any(b.label not in claimed for b in followed):
        return {}
    ours = {t.label for t in tracks}
    h, w = labels.shape
    found: dict[int, list[tuple[Part, bool]]] = {}
    for b, step in zip(followed, steps(followed)):
        step = np.asarray(step, np.float64)
        y0, x0, y1, x1 = b.box
        ys, xs = np.nonzero(before_labels[y0:y1, x0:x1] == b.label)
        ys, xs = ys + y0 + int(round(step[1])), xs + x0 + int(round(step[0]))
        seen = (ys >= 0) & (ys < h) & (xs >= 0) & (xs < w)
        if not seen.any():
            continue                                   # it left the frame
        hits = np.bincount(labels[ys[seen], xs[seen]].ravel(), minlength=int(labels.max()) + 1)
        centre = np.array([xs.mean(), ys.mean()]) + (step - np.round(step))
        chain = replace(b, displacements=(tuple(step), *b.displacements[:2]),
                        responses=(b.responses[0], *b.responses[:2]), growths=(),
                        global_shifts=tracks[0].global_shifts, global_responses=tracks[0].global_responses)
        for k in np.nonzero(hits[1:] >= PART_OVERLAP * len(ys))[0] + 1:
            if int(k) in ours:
                found.setdefault(int(k), []).append((Part(centre, chain), b.label not in claimed))
    held = {t.label for t in tracks if not t.displacements or (t.growths and t.growths[0] ** 2 >= MERGE_AREA_GAIN)}
    return {k: [p for p, _ in got] for k, got in found.items() if k in held and any(lost for _, lost in got)}


def part_flow(inside: np.ndarray, box, parts: list[Part], steps: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) displacement (px) of each pixel of a region that holds parts (`inside`: bool in
    `box` (y0, x0, y1, x1)): the next step of the part whose predicted centre is nearest (module
    docstring)."""
    y0, x0 = box[0], box[1]
    ys, xs = np.nonzero(inside)
    centres = np.array([p.centre for p in parts])
    near = np.argmin((xs[:, None] + x0 - centres[None, :, 0]) ** 2 + (ys[:, None] + y0 - centres[None, :, 1]) ** 2, 1)
    d = np.asarray(steps, np.float64)[near]
    return d[:, 0], d[:, 1]
