"""Video predictors by name: past frames (8-bit scale, float32, predictor resolution) -> the
predicted next frame on the same scale. The registry `PREDICTORS` is the [predictor] name's
choices; adding a predictor is one `PREDICTORS.register(...)` with a factory.

| name        | what                                                                 | reference |
|-------------|----------------------------------------------------------------------|-----------|
| oracle      | the true next frame (upper bound; needs the ground truth)            | - |
| hold        | the last frame                                                        | non-predictive spatially varying exposure |
| flow        | DIS optical flow (ultrafast, log curve above 255), one phase-correlation translation per saturated region, forward splat of bright moving pixels | Kroeger et al., ECCV 2016 (DIS); Kuglin & Hines 1975 |
| dmvfn       | dynamic multi-scale voxel flow network, 9 blocks, routing            | Hu et al., CVPR 2023 |
| dmvfn_lite  | same block design, grey, quarter resolution, 3 blocks, no routing    | ours, after Hu et al. |
| track       | `flow` + each saturated region followed back three frames, constant acceleration (least squares) relative to the frame's global motion (our camera's pitch and yaw: the shift the lights share) | ours; SORT-style box tracking (Bewley et al. 2016) |
| track_net   | `track` with a trained torch motion model choosing the extrapolation from the chain (no preferred direction) | ours |

Every predictor takes `history` (oldest first, at least `needs_frames` frames; the loop passes
up to four) and returns one frame. A predictor that moves a clipped pixel moves its value as it
is, so a region clipped in its inputs stays at the clip marker (tests/unit/test_predictors.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from poevp_optics.control.predictors.base import Hold, Predictor, checked_prediction
from poevp_optics.core.params import param
from poevp_optics.core.registry import Registry

__all__ = ["Predictor", "PREDICTORS", "PredictorEntry", "PredictorSpec", "make_predictor",
           "checked_prediction", "takes_weights"]


@dataclass(frozen=True)
class PredictorEntry:
    """A registered predictor: `factory(weights_path_or_None, resolution) -> Predictor`; the
    oracle has none (it reads the ground truth, control/loop_step.py)."""

    factory: Callable[[Path | None, tuple[int, int]], Predictor] | None
    takes_weights: bool = False

    @property
    def needs_truth(self) -> bool:
        return self.factory is None


def _flow(weights, resolution):
    from poevp_optics.control.predictors.flow import FlowExtrapolation

    return FlowExtrapolation()


def _track(weights, resolution):
    from poevp_optics.control.predictors.track import RegionTracker

    return RegionTracker()


def _track_net(weights, resolution):
    from poevp_optics.control.predictors.track_net import load_predictor as load_track_net

    return load_track_net(weights)


def _dmvfn(name):
    def factory(weights, resolution):
        from poevp_optics.control.predictors.dmvfn import load_predictor

        return load_predictor(name, weights)
    return factory


PREDICTORS = Registry("predictor")
PREDICTORS.register("oracle", PredictorEntry(None), source="the rendered next frame (upper bound)")
PREDICTORS.register("hold", PredictorEntry(lambda w, r: Hold()),
                    source="the last frame: a non-predictive spatially varying exposure camera")
PREDICTORS.register("flow", PredictorEntry(_flow), source="Kroeger et al., ECCV 2016 (DIS) + region phase "
                    "correlation (Kuglin & Hines 1975) + forward splat")
PREDICTORS.register("dmvfn", PredictorEntry(_dmvfn("dmvfn"), takes_weights=True),
                    source="Hu et al., CVPR 2023 (DMVFN), deterministic routing")
PREDICTORS.register("track", PredictorEntry(_track), source="ours: flow + per-region displacement chains over "
                    "four frames, least-squares constant acceleration (after SORT, Bewley et al. ICIP 2016)")
PREDICTORS.register("track_net", PredictorEntry(_track_net, takes_weights=True),
                    source="ours: track with a trained rotation-invariant torch motion model (apps/train/train_track.py)")
PREDICTORS.register("dmvfn_lite", PredictorEntry(_dmvfn("dmvfn_lite"), takes_weights=True),
                    source="ours, after Hu et al.: grey, quarter resolution, 3 blocks")


def takes_weights() -> tuple[str, ...]:
    """Names of the predictors that load trained weights (`[predictor] weights`)."""
    return tuple(n for n in PREDICTORS if PREDICTORS[n].takes_weights)


def make_predictor(name: str, weights: str = "", resolution=(368, 640)) -> Predictor:
    """Build a causal predictor by name (the oracle needs the ground truth: not built here)."""
    entry = PREDICTORS[name]
    if entry.needs_truth:
        raise ValueError(f"predictor {name!r} reads the ground truth; it is run by the loop step")
    return entry.factory(Path(weights) if weights else None, tuple(resolution))


@dataclass(frozen=True)
class PredictorSpec:
    """[predictor]: video predictor by name."""

    name: str = param("oracle", choices=PREDICTORS)
    weights: str = param("")                            # relative paths: from the scene's folder
    resolution: tuple[int, int] = param((368, 640), length=2, min=8, max=8192)
