"""The `track_net` motion model as a torch module (track_net.py holds what the loop runs: the
same network in NumPy, `numpy_forward`, equal to float32 rounding: tests/unit/test_track.py).
Trained by apps/train/train_track.py and saved here; the architecture, features and training
are described in track_net.py's docstring."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import torch
from torch import nn

from poevp_optics.control.predictors.track import MAX_CHAIN
from poevp_optics.control.predictors.track_net import N_FEATURES, STOP_PX, TrackNetConfig, config_and_record
from poevp_optics.core.weights import load_state, read_weights_file, write_weights_file
from poevp_optics.core import runtime

runtime.torch_threads()          # the run's thread count, where it was set before torch loaded


def invariant_features(disp: torch.Tensor, valid: torch.Tensor, resp: torch.Tensor) -> torch.Tensor:
    """(N, 15) rotation- and mirror-invariant features of (N, 3, 2) displacement chains."""
    d = disp * valid[..., None]
    sq = (d * d).sum(-1)                                          # (N, 3) squared lengths
    s2 = sq.max(-1, keepdim=True).values.clamp_min(1.0)           # scale: largest, at least 1 px^2
    dots = torch.stack([(d[:, 0] * d[:, 1]).sum(-1), (d[:, 0] * d[:, 2]).sum(-1),
                        (d[:, 1] * d[:, 2]).sum(-1)], -1)
    cross = torch.stack([(d[:, 0, 0] * d[:, 1, 1] - d[:, 0, 1] * d[:, 1, 0]).abs(),
                         (d[:, 1, 0] * d[:, 2, 1] - d[:, 1, 1] * d[:, 2, 0]).abs()], -1)
    return torch.cat([sq / s2, dots / s2, cross / s2, 0.5 * torch.log(s2) / 4.0 - 0.5, valid, resp], -1)


class TrackNet(nn.Module):
    """Coefficients of the displacement chain (track_net.py's docstring)."""

    def __init__(self, cfg: TrackNetConfig = TrackNetConfig()):
        super().__init__()
        self.cfg = cfg
        self.net = nn.Sequential(nn.Linear(N_FEATURES, cfg.hidden), nn.GELU(),
                                 nn.Linear(cfg.hidden, cfg.hidden), nn.GELU(), nn.Linear(cfg.hidden, MAX_CHAIN))
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, disp: torch.Tensor, valid: torch.Tensor, resp: torch.Tensor) -> torch.Tensor:
        """(N, 2) next displacement (px) from (N, 3, 2) chains; a stopped region's (newest
        displacement under STOP_PX) is zero: it stands."""
        base = torch.zeros_like(valid)
        base[:, 0] = 1.0
        coef = (base + self.net(invariant_features(disp, valid, resp))) * valid
        out = (coef[..., None] * disp).sum(1)
        stopped = (disp[:, 0].norm(dim=-1) < STOP_PX)[:, None]
        return torch.where(stopped, torch.zeros_like(out), out)


def save_track_net(model: TrackNet, path: Path, meta: dict) -> None:
    write_weights_file(path, model, {"config": asdict(model.cfg), "model": "track_net", **meta})


def load_track_net(path: Path) -> tuple[TrackNet, dict]:
    """A TrackNet from safetensors (never pickle); one-line errors on a missing, corrupt,
    non-finite or mismatched file."""
    path = Path(path)
    tensors, meta = read_weights_file(path, "track_net weights", model="track_net")
    cfg, record = config_and_record(path, meta)
    return load_state(TrackNet(cfg), tensors, path), record


def numpy_layers(model: TrackNet) -> list:
    """[(weight (out, in), bias)] float32 arrays of the module's three linear layers: what
    track_net.py's `TrackNetPredictor` runs."""
    return [(mod.weight.detach().numpy().astype("float32"), mod.bias.detach().numpy().astype("float32"))
            for mod in model.net if isinstance(mod, nn.Linear)]
