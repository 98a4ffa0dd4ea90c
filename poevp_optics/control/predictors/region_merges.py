"""Regions where two or more lights' outlines ran into one, moved with the lights they came from.

A region of frame t with no match in frame t-1 (track.py step 1: the match must be mutual and the
areas alike) is new. Where two lights' clipped outlines run into one (the lamps of two cars
passing each other, a turning car's lamp pair closing up as it foreshortens), the merged region
is new, and the lights the trackers followed up to frame t-1 are nowhere in frame t on their own:
they lost their match. Where the two are of like size, the merged outline may still match one of
them (its area under twice that light's): a matched region whose area grew by `MERGE_AREA_GAIN`
or more is taken as a merge too, and its one measured shift is the merged outline's, neither
light's.

Per frame t-1 region with a chain (its displacements to t-1): its step to frame t is its own
motion extrapolated as the predictor extrapolates any region's (`RegionTracker.own_motion`,
standing where its chain wavers) plus the frame's measured global shift g_t. Its pixels moved by
that step land on frame t's regions; a region on which at least `PART_OVERLAP` of them land holds
it as a part. A new region (or a matched one that grew as above) that holds two parts or more, at
least one of them lost, and whose parts' areas sum to `PARTS_AREA_FRAC` of its own or more, is
moved by its parts, not by its own shift: each pixel with the part whose predicted centroid at
frame t is nearest (the merged pair parts as its lights move on). A part's chain at frame t is
(its predicted step, its measured ones), and the predictor extrapolates that chain one frame on
like any other (`RegionTracker.next_displacement`).

A region that holds one lost light only is left as it was (new: it moves with the global motion
alone). Its light lost its match on its own, and the chain that failed is not one to carry on: a
lit road surface clipped under 10x beams (160 000 px at 640x368) lost its match and read 35 px a
frame from its outline's correlation, and carried on by that chain it moved 82 px in one frame
and took the mask off the plate. A light split in two, each piece holding that one light, stays
where it is too.

A track with no detection of its own carried on by its prediction is the missed-detection case
of track association (Bar-Shalom, Daum & Huang, "The probabilistic data association filter",
IEEE Control Systems 29(6), 2009); the pixels split by the nearest predicted centre is a Voronoi
partition.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

#: Fraction of a followed region's moved pixels that must land on a region for it to be a part.
PART_OVERLAP = 0.25
#: Least area ratio (frame t over t-1) of a region that kept its match for it to hold a lost light:
#: a merge adds the other light's area; a light's outline alone changes its area by a few per cent
#: (track.py GROWTH_DEADBAND), and a wet road's standing glints, touching and parting, by less
#: than this (a region held for less moved them with lights that were not theirs).
MERGE_AREA_GAIN = 1.3
#: Least share of a region's area that its parts' areas (frame t-1) must sum to for it to move with
#: them: merged lights overlap, so their outline is smaller than their areas' sum; a region far
#: larger than its parts is a glow or a lit surface that took lights in, not lights that met.
PARTS_AREA_FRAC = 0.5


@dataclass(frozen=True)
class Part:
    """A light followed to frame t-1 inside a frame t region that holds a lost one: its
    predicted centroid at frame t (px, x and y) and its chain at frame t (track.py `RegionTrack`,
    newest first: the predicted step, then its measured displacements)."""

    centre: np.ndarray
    track: object


def holders(tracks) -> set[int]:
    """Labels of the frame t regions that may hold parts (module docstring): the new ones, and the
    matched ones whose area grew by `MERGE_AREA_GAIN` or more (empty: no region can hold parts)."""
    return {t.label for t in tracks if not t.displacements or (t.growths and t.growths[0] ** 2 >= MERGE_AREA_GAIN)}


def lost_parts(tracks, labels: np.ndarray, before, before_labels: np.ndarray, steps) -> dict[int, list[Part]]:
    """{label of a frame t region that holds a lost light: its parts} (module docstring). tracks,
    labels: frame t's `region_tracks`; before, before_labels: frame t-1's (the history less its
    last frame); steps(followed): each frame t-1 track's predicted step to frame t (px, x and y;
    track.py `RegionTracker.step_to_last`)."""
    claimed = {t.prev_label for t in tracks if t.prev_label}
    followed = [b for b in before if b.displacements]
    held = holders(tracks)
    if not held or not any(b.label not in claimed for b in followed):
        return {}
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
            if int(k) in held:
                found.setdefault(int(k), []).append((Part(centre, chain), b.label not in claimed))
    area = {t.label: t.area_px for t in tracks}
    return {k: [p for p, _ in got] for k, got in found.items()
            if any(lost for _, lost in got) and len(got) >= 2
            and sum(p.track.area_px for p, _ in got) >= PARTS_AREA_FRAC * area[k]}


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
