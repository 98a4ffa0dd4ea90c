"""Classical motion extrapolation: DIS optical flow, then a forward splat one frame ahead.

Flow from frame t-1 to frame t (OpenCV DIS, ultrafast preset: Kroeger et al., "Fast Optical
Flow using Dense Inverse Search", ECCV 2016) is assumed constant for one more frame. Every pixel
of frame t is pushed along its flow; where several land on one pixel the brightest wins (a
highlight must never be predicted dimmer than it is), and pixels nothing lands on keep frame t
(holding the old value is the safe choice for the mask: it errs toward dimming).
"""

from __future__ import annotations

import cv2
import numpy as np

from poevp_optics.control.predictors.base import Predictor


class FlowExtrapolation(Predictor):
    name = "flow"
    min_input_px = 12             # OpenCV's DIS refuses frames narrower or lower than 12 px

    def __init__(self, preset: int = cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST):
        self.dis = cv2.DISOpticalFlow_create(preset)

    def __call__(self, history):
        prev = np.clip(history[-2], 0, 255).astype(np.uint8)
        cur = np.asarray(history[-1], dtype=np.float32)
        flow = self.dis.calc(prev, np.clip(cur, 0, 255).astype(np.uint8), None)
        return forward_splat(cur, flow)


def forward_splat(frame: np.ndarray, flow: np.ndarray, min_value: float = 128.0,
                  min_motion_px: float = 0.5) -> np.ndarray:
    """Move bright (>= min_value) moving (|flow| >= min_motion_px) pixels by `flow` (px, (H, W,
    2) as x, y); brightest wins on collisions; every other pixel keeps its value (hold)."""
    h, w = frame.shape
    moving = (frame >= min_value) & ((flow[..., 0] ** 2 + flow[..., 1] ** 2) >= min_motion_px ** 2)
    ys, xs = np.nonzero(moving)
    out = np.array(frame, dtype=np.float32, copy=True)
    if ys.size == 0:
        return out
    tx = np.rint(xs + flow[ys, xs, 0]).astype(np.int64)
    ty = np.rint(ys + flow[ys, xs, 1]).astype(np.int64)
    inside = (tx >= 0) & (tx < w) & (ty >= 0) & (ty < h)
    vals = frame[ys, xs][inside]
    dest = (ty * w + tx)[inside]
    # pixels the highlight leaves and nothing lands on show background: estimate it by a grey
    # erosion reaching past the trailing edge (radius: the largest displacement + 1 px)
    radius = int(np.ceil(np.sqrt((flow[ys, xs] ** 2).sum(-1)).max())) + 1
    k = 2 * radius + 1
    background = cv2.erode(out, np.ones((k, k), np.uint8), borderType=cv2.BORDER_REPLICATE)
    flat = out.ravel()
    src = ys * w + xs
    flat[src] = background.ravel()[src]
    order = np.argsort(vals, kind="stable")              # ascending: brightest written last
    flat[dest[order]] = vals[order]
    return out
