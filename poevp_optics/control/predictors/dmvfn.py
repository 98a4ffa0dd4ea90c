"""DMVFN: dynamic multi-scale voxel flow network (Hu et al., "A Dynamic Multi-Scale Voxel Flow
Network for Video Prediction", CVPR 2023), written from the paper's description.

A prediction of x_{t+1} from (x_{t-1}, x_t) is a voxel flow: two backward flows (from t+1 into
t and into t-1) and a blend mask; x_{t+1} = m warp(x_t, f_t) + (1 - m) warp(x_{t-1}, f_{t-1}).
A chain of multi-scale voxel flow blocks (MVFB) refines flow and mask: block i sees both frames,
both frames warped by the current estimate, the flow and the mask, at 1/s_i resolution, and adds
a residual. The full model has 9 blocks, s = [4, 4, 4, 2, 2, 2, 1, 1, 1], widths 160/80/44, and a
routing module that picks which blocks run for a given input; the original samples that choice
at random even at inference, ours thresholds the routing probabilities at 0.5 (deterministic).

`dmvfn_lite` (ours): the same blocks on single-channel frames at quarter resolution, 3 blocks of
widths 64/48/32 with s = [4, 2, 1], no routing; its flow is upsampled x4 to warp the
full-resolution frames. Torch code pairs functions with thin modules (STYLE.md 3). The settings
(`DMVFNConfig`, `FULL`, `LITE`) live in dmvfn_config.py, readable without torch.

A saturated region that stands still in both input frames is held where it is
(`standing_regions`): the network warps a clipped region it sees standing by up to 4 px.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from poevp_optics.core.weights import (WeightsError, load_state, read_weights_file, weights_identity,
                                       write_weights_file)
from poevp_optics.control.predictors.base import Predictor
from poevp_optics.control.predictors.flow import SATURATED
from poevp_optics.core.paths import shipped_weights
from poevp_optics.control.predictors.dmvfn_config import FULL, LITE, DMVFNConfig
from poevp_optics.core import runtime

runtime.torch_threads()          # the run's thread count, where it was set before torch loaded


def backward_warp(img: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """Sample `img` (N, C, H, W) at pixel + flow (N, 2, H, W; x, y in px), bilinear, border."""
    n, _, h, w = img.shape
    ys, xs = torch.meshgrid(torch.arange(h, dtype=img.dtype, device=img.device),
                            torch.arange(w, dtype=img.dtype, device=img.device), indexing="ij")
    gx = (xs[None] + flow[:, 0]) * (2.0 / max(w - 1, 1)) - 1.0
    gy = (ys[None] + flow[:, 1]) * (2.0 / max(h - 1, 1)) - 1.0
    grid = torch.stack((gx, gy), dim=-1)
    return F.grid_sample(img, grid, mode="bilinear", padding_mode="border", align_corners=True)


def _conv(cin, cout, stride=1):
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1), nn.PReLU(cout))


class MVFB(nn.Module):
    """Multi-scale voxel flow block: residual flow (4 ch) and mask (1 ch) at 1/scale."""

    def __init__(self, in_ch: int, width: int, depth: int, scale: int):
        super().__init__()
        self.scale = scale
        self.encode = nn.Sequential(_conv(in_ch, width // 2, 2), _conv(width // 2, width, 2))
        self.body = nn.Sequential(*[_conv(width, width) for _ in range(depth)])
        self.decode = nn.ConvTranspose2d(width, 5, 4, 2, 1)

    def forward(self, x: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        s = self.scale
        if s != 1:
            x = F.interpolate(x, scale_factor=1 / s, mode="bilinear", align_corners=False)
        feat = self.encode(x)
        feat = feat + self.body(feat)
        out = self.decode(feat)
        out = F.interpolate(out, size=(h, w), mode="bilinear", align_corners=False)
        return torch.cat((out[:, :4] * (2 * s), out[:, 4:5]), 1)   # flow in px at full size


class Routing(nn.Module):
    """Per-input block selection probabilities (the paper's routing module)."""

    def __init__(self, in_ch: int, n_blocks: int):
        super().__init__()
        self.net = nn.Sequential(_conv(in_ch, 32, 2), _conv(32, 32, 2), nn.AdaptiveAvgPool2d(1),
                                 nn.Flatten(), nn.Linear(32, n_blocks))

    def forward(self, x):
        return torch.sigmoid(self.net(x))


class DMVFN(nn.Module):
    def __init__(self, cfg: DMVFNConfig = FULL):
        super().__init__()
        self.cfg = cfg
        c = cfg.channels
        in_ch = 4 * c + 4 + 1
        self.blocks = nn.ModuleList(MVFB(in_ch, w, cfg.depth, s) for w, s in zip(cfg.widths, cfg.scales))
        self.routing = Routing(2 * c, len(cfg.widths)) if cfg.routing else None

    def forward(self, prev: torch.Tensor, cur: torch.Tensor, *, train_routing: bool = False,
                with_prediction: bool = True, generator: torch.Generator | None = None):
        """prev, cur: (N, C, H, W) in [0, 1]-ish. Returns (prediction, flow, mask logits);
        with_prediction=False skips the final full-resolution warps (prediction None);
        generator: the seeded stream of the training routing's draws (never the global RNG)."""
        ds = self.cfg.input_downsample
        p_s, c_s = prev, cur
        if ds != 1:
            p_s = F.interpolate(prev, scale_factor=1 / ds, mode="area")
            c_s = F.interpolate(cur, scale_factor=1 / ds, mode="area")
        n, _, h, w = c_s.shape
        flow = torch.zeros(n, 4, h, w, dtype=cur.dtype, device=cur.device)
        mask = torch.zeros(n, 1, h, w, dtype=cur.dtype, device=cur.device)
        use = None
        if self.routing is not None:
            prob = self.routing(torch.cat((p_s, c_s), 1))
            if train_routing and self.training:
                # drawn on the CPU stream and moved: the same draws on any device (a CUDA
                # tensor cannot take the CPU generator that seeds the run)
                u = torch.rand(prob.shape, generator=generator, dtype=prob.dtype).to(prob.device)
                hard = (u < prob.detach()).to(prob.dtype)
                use = hard + prob - prob.detach()          # straight-through estimator
            else:
                use = (prob > 0.5).to(cur.dtype)           # deterministic inference
        for i, block in enumerate(self.blocks):
            if use is not None and not self.training and not bool(use[:, i].any()):
                continue
            w_cur = backward_warp(c_s, flow[:, :2])
            w_prev = backward_warp(p_s, flow[:, 2:4])
            delta = block(torch.cat((p_s, c_s, w_prev, w_cur, flow, mask), 1), flow)
            gate = 1.0 if use is None else use[:, i].view(-1, 1, 1, 1)
            flow = flow + gate * delta[:, :4]
            mask = mask + gate * delta[:, 4:5]
        if ds != 1:
            flow = F.interpolate(flow, size=cur.shape[-2:], mode="bilinear", align_corners=False) * ds
            mask = F.interpolate(mask, size=cur.shape[-2:], mode="bilinear", align_corners=False)
        if not with_prediction:
            return None, flow, mask
        m = torch.sigmoid(mask)
        pred = m * backward_warp(cur, flow[:, :2]) + (1 - m) * backward_warp(prev, flow[:, 2:4])
        return pred, flow, mask


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def count_macs(model: DMVFN, h: int, w: int) -> int:
    """Multiply-accumulates of one forward pass at (h, w), all blocks, counted with hooks."""
    macs = 0

    def hook(mod, inp, out):
        nonlocal macs
        if isinstance(mod, nn.Conv2d):
            macs += out.numel() * mod.in_channels * mod.kernel_size[0] * mod.kernel_size[1] // mod.groups
        elif isinstance(mod, nn.ConvTranspose2d):
            macs += inp[0].numel() * mod.out_channels * mod.kernel_size[0] * mod.kernel_size[1]
        elif isinstance(mod, nn.Linear):
            macs += mod.in_features * mod.out_features

    handles = [m.register_forward_hook(hook) for m in model.modules() if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d, nn.Linear))]
    c = model.cfg.channels
    was = model.training
    model.train()                          # all blocks run in train mode (no skipping)
    with torch.no_grad():
        model(torch.zeros(1, c, h, w), torch.zeros(1, c, h, w))
    model.train(was)
    for hd in handles:
        hd.remove()
    return macs


# ----------------------------------------------------------------------------- weights
def save_weights(model: DMVFN, path: Path, meta: dict, float16: bool = False) -> None:
    """Weights and metadata to safetensors; float16: stored as half floats (half the size)."""
    write_weights_file(path, model, {"config": asdict(model.cfg), **meta}, torch.float16 if float16 else None)


def load_weights(path: Path, expect: DMVFNConfig | None = None) -> tuple[DMVFN, dict]:
    """Load a DMVFN from safetensors (never pickle); clear errors on corruption or mismatch."""
    tensors, meta = read_weights_file(path, "predictor weights")
    try:
        raw = json.loads(meta["config"])
        cfg = DMVFNConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in raw.items()})
    except (KeyError, TypeError, json.JSONDecodeError) as e:
        raise WeightsError(f"{path}: missing or bad 'config' metadata ({e})") from None
    if expect is not None and cfg != expect:
        raise WeightsError(f"{path}: weights are for {cfg}, expected {expect}")
    model = load_state(DMVFN(cfg), tensors, path)
    return model, {k: json.loads(v) for k, v in meta.items() if k != "config"}


class DMVFNPredictor(Predictor):
    """Wraps a DMVFN for the loop: frames on the 8-bit scale in, prediction out."""

    def __init__(self, model: DMVFN, name: str, weights_path: Path | None, meta: dict | None = None):
        self.model = model.eval()
        self.name = name
        self.min_input_px = model.cfg.min_input_px
        self.weights_path = weights_path
        self.meta = meta or {}

    def __call__(self, history):
        """Motion is estimated on the frames clipped to the 8-bit range the network was trained
        on; the voxel flow then warps the unclipped frames, so demodulated (HDR) inputs keep
        their values (warping and blending are linear)."""
        import cv2

        c = self.model.cfg.channels
        device = next(self.model.parameters()).device     # the network runs where its weights are
        frames = [np.ascontiguousarray(h, dtype=np.float32) for h in history[-2:]]
        full = [torch.from_numpy(f)[None, None].to(device) for f in frames]
        prev, cur = (torch.clamp(t / 255.0, 0.0, 1.0).expand(1, c, *t.shape[-2:]) for t in full)
        with torch.inference_mode():
            _, flow, mask = self.model(prev, cur, with_prediction=False)
            m = torch.sigmoid(mask)[0, 0].cpu().numpy()
            fl = flow[0].cpu().numpy()
        # the same bilinear backward warp with border clamping as `backward_warp`, by OpenCV
        # (3x faster on 2 cores; equal to 4e-5 of the value range)
        h, w = frames[1].shape
        ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)

        def warp(img, fx, fy):
            return cv2.remap(img, xs + fx, ys + fy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

        pred = m * warp(frames[1], fl[0], fl[1]) + (1 - m) * warp(frames[0], fl[2], fl[3])
        # the clip marker travels with the warp: where at least half of the blend comes from
        # clipped pixels the prediction is clipped (a blend of 255 and its surround is not a
        # measurement the mask law may read as unclipped)
        clipped = [(f >= SATURATED).astype(np.float32) for f in frames]
        frac = m * warp(clipped[1], fl[0], fl[1]) + (1 - m) * warp(clipped[0], fl[2], fl[3])
        pred = np.where(frac >= 0.5, np.maximum(pred, 255.0), pred)
        for ys, xs in standing_regions(clipped[0] > 0, clipped[1] > 0):
            pred[ys, xs] = frames[1][ys, xs]
        return pred.astype(np.float32)

    def describe(self):
        return {"name": self.name, **weights_identity(self.weights_path),
                "parameters": count_parameters(self.model), **{k: v for k, v in self.meta.items() if k in ("validation",)}}


#: A saturated region stands when its footprint in the two frames overlaps this much (IoU) ...
STANDING_IOU = 0.9
#: ... and its centroid moved less than this (px).
STANDING_SHIFT_PX = 0.5
#: Margin (px) around a standing region that is held too (the network's warp of its edge).
STANDING_MARGIN_PX = 4


def standing_regions(prev_sat: np.ndarray, cur_sat: np.ndarray) -> list[tuple[slice, slice]]:
    """Boxes (grown by STANDING_MARGIN_PX) of frame t's saturated regions that did not move
    from frame t-1: footprint IoU >= STANDING_IOU and centroid shift < STANDING_SHIFT_PX within
    the box. The voxel flow network, given two frames that agree there, still warps a clipped
    region by up to 4 px (the shipped dmvfn_lite on a standing lamp); with no change seen there is
    no motion to extrapolate, so `DMVFNPredictor` holds these boxes at frame t (what `hold`
    predicts)."""
    import cv2

    n, labels, stats, _ = cv2.connectedComponentsWithStats(cur_sat.astype(np.uint8), connectivity=8)
    h, w = cur_sat.shape
    out = []
    for k in range(1, n):
        x, y, bw, bh, _ = (int(v) for v in stats[k])
        g = STANDING_MARGIN_PX
        box = (slice(max(y - g, 0), min(y + bh + g, h)), slice(max(x - g, 0), min(x + bw + g, w)))
        a, b = prev_sat[box], cur_sat[box]
        inter, union = np.logical_and(a, b).sum(), np.logical_or(a, b).sum()
        if not a.any() or inter < STANDING_IOU * union:
            continue
        ca, cb = (np.array([np.mean(i) for i in np.nonzero(m)]) for m in (a, b))
        if np.hypot(*(ca - cb)) < STANDING_SHIFT_PX:
            out.append(box)
    return out


def default_weights(name: str) -> Path:
    return shipped_weights(name)


def load_predictor(name: str, weights: Path | None) -> DMVFNPredictor:
    """`dmvfn` runs the full network with full weights only: with none given and none shipped
    (they are trained on a GPU: `poevp train-predictor --name dmvfn`) it refuses in one line,
    never falling back to another model under its name."""
    cfg = FULL if name == "dmvfn" else LITE
    path = weights or default_weights(name)
    if weights is None and name == "dmvfn" and not path.exists():
        raise WeightsError(f"predictor.name = 'dmvfn': the full DMVFN's weights are not shipped ({path} is "
                           "absent; they need a GPU to train): set predictor.weights to a trained file, or use "
                           "'dmvfn_lite', 'track_net' or 'flow'")
    model, meta = load_weights(path, expect=cfg)
    return DMVFNPredictor(model, name, path, meta)
