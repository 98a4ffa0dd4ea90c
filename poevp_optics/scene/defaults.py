"""The loop a scene gets when it does not choose one (issue 29): the project's best causal
configuration, as scenes/night_road runs it.

A scene that leaves out a section's *choosing key* (`mask.law`, `loop.mode`, `predictor.name`)
gets that section's entry of BEST_LOOP for every key it does not set itself:

| section     | choosing key | defaults (scenes/night_road/scene.toml) |
|-------------|--------------|------------------------------------------|
| [mask]      | law          | exposure_controller, target 0.6 in a 0.4-0.9 band, smooth_px 4, min_level 1, first_guess 22, clip_step 5, carry extrapolate (+ prior_beam_cd 1e5 on a [road] scene) |
| [loop]      | mode         | demodulated, 2 white initialisation frames |
| [predictor] | name         | track_net (shipped weights assets/predictor/track_net.safetensors) |

A scene that names the key keeps the params dataclasses' own defaults for the rest (the
paper's laws and loop stay one key away: `law = "threshold_exp"`, `mode = "open"`, `name =
"flow"`). Why these defaults: benchmarks/results/recognition.md (the predictors in the demodulated
loop, read side by side on the paper's protocol and the road scenes) and
tests/unit/test_default_loop.py (a 100x highlight moving 8 px/frame unclips by the second loop
frame; the paper's open loop with `flow` keeps it clipped: the flow-warped prediction of a
clipped region falls just below 255 and the `target` law no longer reads it as clipped).
Scenes without a DMD have no loop: nothing is applied. A scene whose mask law reads no
prediction (PREDICTION_FREE_LAWS: `white`, the LDR twin) runs no predictor, so it gets no [loop]
or [predictor] defaults either. The report lists what was applied (`defaults_applied`,
"section.key=value").
"""

from __future__ import annotations

import copy
from typing import Any

#: section -> (choosing key, {key: default}); the values of scenes/night_road/scene.toml.
BEST_LOOP: dict[str, tuple[str, dict[str, Any]]] = {
    "mask": ("law", {"law": "exposure_controller", "target": 0.6, "band_low": 0.4, "band_high": 0.9,  # smooth_px:
                     # night_road's 24 mirrors at 1920 columns is 4 at 320
                     "smooth_px": 4.0, "min_level": 1, "first_guess": 22.0, "clip_step": 5.0,
                     "carry": "extrapolate"}),
    "loop": ("mode", {"mode": "demodulated", "init_frames": 2}),
    "predictor": ("name", {"name": "track_net"}),
}

#: Mask laws (control/masks.py MASK_LAWS) that read no prediction: `white` gives every mirror the
#: top level whatever the predicted frame holds. Every other law reads the prediction's values.
PREDICTION_FREE_LAWS = ("white",)

#: [mask] defaults that only a [road] scene takes: the prior follows its high beams (scene/resolve.py prior_first_guess).
ROAD_ONLY = {"mask": {"prior_beam_cd": 100000.0}}


def apply_best_loop(raw: dict) -> tuple[dict, tuple[str, ...]]:
    """(raw with BEST_LOOP filled in where the scene does not choose, the "section.key=value"
    strings applied). `raw` is not changed; a scene without a DMD gets nothing, and a scene whose
    mask law reads no prediction (PREDICTION_FREE_LAWS) gets no [loop] or [predictor] defaults."""
    dmd = raw.get("dmd", {})
    if not isinstance(dmd, dict) or dmd.get("enabled", True) is False:
        return raw, ()
    mask = raw.get("mask", {})
    predicts = not (isinstance(mask, dict) and mask.get("law") in PREDICTION_FREE_LAWS)
    out, applied = copy.deepcopy(raw), []
    for section, (choosing, defaults) in BEST_LOOP.items():
        table = out.get(section, {})
        if not isinstance(table, dict) or choosing in table:
            continue                    # chosen (or not a table: the loader names that error)
        if section != "mask" and not predicts:
            continue                    # no predictor runs: no loop to choose
        extra = ROAD_ONLY.get(section, {}) if "road" in raw else {}
        for key, value in {**defaults, **extra}.items():
            if key == "min_level" and dmd.get("bits", 8) == 1:
                continue                # a 1-bit DMD has only levels 0 and 1: the law needs one that dims
            if key not in table:
                table[key] = value
                applied.append(f"{section}.{key}={value}")
        out[section] = table
    return out, tuple(applied)
