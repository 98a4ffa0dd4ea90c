"""Video predictors by name: past frames (8-bit scale, float32, predictor resolution) -> the
predicted next frame on the same scale.

| name        | what                                                                 | reference |
|-------------|----------------------------------------------------------------------|-----------|
| oracle      | the true next frame (upper bound; handled by the loop, needs truth)  | - |
| hold        | the last frame                                                        | non-predictive spatially varying exposure |
| flow        | DIS optical flow (ultrafast) + forward splat of bright moving pixels | Kroeger et al., ECCV 2016 (DIS) |
| dmvfn       | dynamic multi-scale voxel flow network, 9 blocks, routing            | Hu et al., CVPR 2023 |
| dmvfn_lite  | same block design, grey, quarter resolution, 3 blocks, no routing    | ours, after Hu et al. |

Every predictor takes `history` (oldest first, at least 2 frames) and returns one frame.
"""

from __future__ import annotations

from poevp_optics.control.predictors.base import Predictor, checked_prediction, make_predictor

__all__ = ["Predictor", "make_predictor", "checked_prediction", "PREDICTORS", "TAKES_WEIGHTS"]

PREDICTORS = ("oracle", "hold", "flow", "dmvfn", "dmvfn_lite")
#: Predictors that load trained weights (`[predictor] weights`); the others take none.
TAKES_WEIGHTS = ("dmvfn", "dmvfn_lite")
