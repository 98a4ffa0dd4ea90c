"""`track_net`: the region tracker (track.py) with a trained torch motion model.

The next displacement of a saturated region is a combination of its measured ones,
d_{t+1} = c_0 d_t + c_1 d_{t-1} + c_2 d_{t-2}, and a small network chooses the coefficients from
the chain itself: constant velocity is c = (1, 0, 0), constant acceleration (2, -1, 0), a
constant-curvature arc of turn w per frame (2 cos w, -1, 0), a noisy chain something between. The
network sees only quantities that stay the same when the image is rotated or mirrored (lengths,
dot products and the absolute cross product of the displacements, divided by the largest
squared length, plus log speed, the correlation responses and which displacements exist), so the
prediction turns with the motion: no preferred direction, by construction. Missing displacements
(a region followed back fewer than three frames) have their coefficients forced to zero.

A region whose own newest displacement is under `STOP_PX` has stopped: it stands (no own motion
next frame), whatever the network says. Trained on stops, standing lights and reversals of many
ramps, the network alone predicts a rendered stop within 1.5 px, but on the chain (0, v, v) with
weak correlation responses (0.3) it still returns -2, -5 and -10 px at v = 16, 32 and 48 px/frame:
that chain lies next to smooth reversals (0, a, 2a) -> -a in its inputs, and a coefficient model
does not return exactly zero there. Nor is the newest sub-pixel displacement continued: on the
small regions of standing lights (a street lamp's or a parked car's, 16-265 px) the outline
correlation reads 0.3-1 px of motion where nothing moves (37 % of them on the held-out traffic,
analysis/traffic_paths.py), and moving a 150 px region by 1 px costs its mask 10-20 % of its IoU.
A stopped light reverses within a frame only in a collision, and a light truly creeping under
STOP_PX a frame is missed by less than that. A region whose chain swings back and forth
(track.py `wavering`) stands too, as in `track`: a standing glow's outline, not a motion.

Architecture (ours): MLP 15 -> 64 -> 64 -> 3 with GELU, outputs added to the constant-velocity
coefficients (1, 0, 0), so an untrained network is `flow`'s motion model. 5.4 k parameters,
well under a millisecond per region on a CPU. Trained by apps/train/train_track.py on measured chains
(the tracker's own measurement noise) against the true next displacement, loss what the mask
needs: 1 - the IoU of the region's box with itself moved by the error, plus 0.01 per px of
centroid error (not pixel PSNR). The growth of a region (track.py) is `track`'s closed form.

In the loop the network extrapolates each region's motion relative to the frame's global motion
(its chain less the global shifts: our camera's pitch and yaw, track.py step 1), and the global
motion is continued as `track` continues it (`closed_form_global`: a pitch oscillation or steady
pitch, the yaw's drift); the two are added. A region whose relative chain looms (a light closing
on the camera, or pulling away, at a steady speed: track.py `closed_form_looming`) is continued
by the pinhole law in both predictors: the training paths hold no perspective approach, and the
law is exact there. A region whose relative chain turns faster than the training paths' fastest
turn (0.25 rad a frame) is continued on its arc (track.py `closed_form_turning`, which `track`
applies from 0.05 rad): the constant-turn-rate model is exact at any rate, and the network has
seen none so sharp. Slower turns stay the network's, which learned them with the swerves and
lane changes beside them (where a steady-turn law, applied from 0.05 rad, costs the training
kinds' swerves 0.02 and lane changes 0.04 of mean IoU). Where no global motion is found (one car alone, or no
camera motion) the relative chain is the chain itself. The training paths (one car, no camera motion) hold no
global motion, so their chains are the same either way.
Weights: safetensors with the config and the training record in the metadata (never pickle),
read into NumPy for the loop (torch is not imported to predict); the torch module that is
trained and saved is track_net_model.py.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from poevp_optics.control.predictors.track import MAX_CHAIN, RegionTrack, RegionTracker
from poevp_optics.core.paths import shipped_weights
from poevp_optics.core.weights import WeightsError, read_weights_file, weights_identity

N_FEATURES = 15
#: Fastest turn (rad a frame) of the training paths (analysis/motion_paths.py TRAINING_SHAPES).
TRAINED_TURN_MAX_RAD = 0.25
#: A newest displacement shorter than this (px) is a stop: predicted to stand (module docstring).
STOP_PX = 1.0
#: The state-dict keys of the network's three linear layers (track_net_model.py `TrackNet.net`).
LINEAR_KEYS = ("net.0", "net.2", "net.4")


@dataclass(frozen=True)
class TrackNetConfig:
    hidden: int = 64
    chain: int = MAX_CHAIN


def chain_arrays(tracks, relative: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(disp (N, 3, 2) px newest first, zero-padded; valid (N, 3); responses (N, 3)) of tracks;
    relative: each region's displacements less the frame's global shifts (`RegionTrack.relative`)."""
    n = len(tracks)
    disp = np.zeros((n, MAX_CHAIN, 2), np.float32)
    valid = np.zeros((n, MAX_CHAIN), np.float32)
    resp = np.zeros((n, MAX_CHAIN), np.float32)
    for i, t in enumerate(tracks):
        k = min(len(t.displacements), MAX_CHAIN)
        if k:
            disp[i, :k] = (t.relative() if relative else np.asarray(t.displacements, np.float64))[:k]
            valid[i, :k] = 1.0
            resp[i, :k] = np.asarray(t.responses[:k], np.float32)
    return disp, valid, resp


# ----------------------------------------------------------------------------- weights
def default_weights() -> Path:
    return shipped_weights("track_net")


def read_track_net(path: Path) -> tuple[list[tuple[np.ndarray, np.ndarray]], TrackNetConfig, dict]:
    """(layers [(weight (out, in), bias)] float32, config, record) of a track_net safetensors file,
    in NumPy (torch not imported); one-line errors on a missing, corrupt, non-finite or mismatched
    file (the layers' shapes checked against the config)."""
    path = Path(path)
    tensors, meta = read_weights_file(path, "track_net weights", model="track_net", framework="numpy")
    cfg, record = config_and_record(path, meta)
    shapes = [(cfg.hidden, N_FEATURES), (cfg.hidden, cfg.hidden), (MAX_CHAIN, cfg.hidden)]
    want = {f"{k}.{p}": (s if p == "weight" else s[:1])
            for k, s in zip(LINEAR_KEYS, shapes) for p in ("weight", "bias")}
    got = {k: tuple(v.shape) for k, v in tensors.items()}
    if got != want:
        extra = sorted(set(got) ^ set(want)) or sorted(k for k in want if got[k] != want[k])
        raise WeightsError(f"{path}: weights do not match the model: {extra[0]} "
                           f"{got.get(extra[0], 'missing')} against {want.get(extra[0], 'none')}")
    layers = [(tensors[f"{k}.weight"].astype(np.float32), tensors[f"{k}.bias"].astype(np.float32))
              for k in LINEAR_KEYS]
    return layers, cfg, record


def config_and_record(path: Path, meta: dict) -> tuple[TrackNetConfig, dict]:
    """(config, training record) from a track_net file's metadata (JSON values); a one-line
    WeightsError naming the file when the config is missing or bad. Used by both readers (this
    module's NumPy one and track_net_model.py's torch one)."""
    try:
        cfg = TrackNetConfig(**json.loads(meta["config"]))
    except (KeyError, TypeError, json.JSONDecodeError) as e:
        raise WeightsError(f"{path}: missing or bad 'config' metadata ({e})") from None
    return cfg, {k: json.loads(v) for k, v in meta.items() if k not in ("config", "model")}


def numpy_forward(layers: list[tuple[np.ndarray, np.ndarray]], disp: np.ndarray, valid: np.ndarray,
                  resp: np.ndarray) -> np.ndarray:
    """track_net_model.py `TrackNet.forward` in NumPy float32 (equal to float32 rounding:
    tests/unit/test_track.py); layers [(weight (out, in), bias)] of its three linear layers. The
    loop calls the model on a handful of chains per frame, where torch's thread pool costs
    10-30 ms a call on a loaded 2-core machine and NumPy a few microseconds."""
    from scipy.special import erf

    d = disp * valid[..., None]
    sq = (d * d).sum(-1)
    s2 = np.maximum(sq.max(-1, keepdims=True), 1.0)
    dots = np.stack([(d[:, 0] * d[:, 1]).sum(-1), (d[:, 0] * d[:, 2]).sum(-1), (d[:, 1] * d[:, 2]).sum(-1)], -1)
    cross = np.stack([np.abs(d[:, 0, 0] * d[:, 1, 1] - d[:, 0, 1] * d[:, 1, 0]),
                      np.abs(d[:, 1, 0] * d[:, 2, 1] - d[:, 1, 1] * d[:, 2, 0])], -1)
    x = np.concatenate([sq / s2, dots / s2, cross / s2, 0.5 * np.log(s2) / 4.0 - 0.5, valid, resp], -1)
    for i, (w, b) in enumerate(layers):
        x = x @ w.T + b
        if i < len(layers) - 1:
            x = 0.5 * x * (1.0 + erf(x / np.sqrt(2.0)))              # GELU (exact, torch's default)
    base = np.zeros_like(valid)
    base[:, 0] = 1.0
    coef = (base + x) * valid
    out = (coef[..., None] * disp).sum(1)
    stopped = (np.hypot(disp[:, 0, 0], disp[:, 0, 1]) < STOP_PX)[:, None]
    return np.where(stopped, np.zeros_like(out), out)


class TrackNetPredictor(RegionTracker):
    """`track`'s measurement and move, the trained network's extrapolation (`numpy_forward`).
    layers: [(weight (out, in), bias)] of its three linear layers (`read_track_net`, or
    track_net_model.py `numpy_layers` of a torch module)."""

    name = "track_net"
    #: Turns up to the training paths' fastest (analysis/motion_paths.py TRAINING_SHAPES
    #: turn_rad: 0.25 rad a frame) are the network's, with the swerves and lane changes it learned
    #: beside them; only sharper ones are continued on their arc (track.py `closed_form_turning`).
    turn_min_rad = TRAINED_TURN_MAX_RAD

    def __init__(self, layers: list[tuple[np.ndarray, np.ndarray]], weights_path: Path | None = None,
                 meta: dict | None = None):
        super().__init__()
        self.layers = [(np.asarray(w, np.float32), np.asarray(b, np.float32)) for w, b in layers]
        self.weights_path = weights_path
        self.meta = meta or {}

    def own_motion(self, tracks: list[RegionTrack]) -> list[np.ndarray]:
        """The model on each region's relative chain (its displacements less the frame's global
        shifts). `RegionTracker.next_displacement` adds the frame's global motion extrapolated
        as `track` does (track.py `closed_form_global`: the camera's pitch oscillation, which the
        model's training paths do not hold) and keeps wavering regions standing."""
        if not tracks:
            return []
        disp, valid, resp = chain_arrays(tracks, relative=True)
        return list(numpy_forward(self.layers, disp, valid, resp).astype(np.float64))

    def describe(self) -> dict:
        held = {k: v["track_net"] for k, v in self.meta.get("test", {}).items() if "track_net" in v}
        return {"name": self.name, **weights_identity(self.weights_path),
                "parameters": sum(w.size + b.size for w, b in self.layers), "context_frames": MAX_CHAIN + 1,
                **({"held_out_median_error_px": held} if held else {})}


def load_predictor(weights: Path | None) -> TrackNetPredictor:
    path = Path(weights) if weights else default_weights()
    layers, _, meta = read_track_net(path)
    return TrackNetPredictor(layers, path, meta)
