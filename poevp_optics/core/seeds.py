"""Every random stream of a run derives from the scene's seeds (STYLE.md 6): reproducible runs.

`render_seeds` gives the Monte Carlo seeds of one radiance sample's independent-seed renders;
`capture_seed` the sensor's per-capture seed (Poisson, read noise). Both hash their inputs with
NumPy's SeedSequence (O'Neill's PCG seeding), so neighbouring frames get unrelated streams.
"""

from __future__ import annotations

import numpy as np

#: Capture streams of a frame (`capture_seed`'s `stream`).
LDR_STREAM, ENCODED_STREAM, CHART_LOOP_STREAM, FUSION_STREAM = 1, 2, 3, 7


def render_seeds(base: int, frame: int, sample: int, n: int) -> list[int]:
    """Independent 31-bit Mitsuba seeds for (frame, radiance sample, MC split) from `base`."""
    state = np.random.SeedSequence([base, frame, sample]).generate_state(n)
    return [int(s & 0x7FFFFFFF) for s in state]


def capture_seed(sensor_seed: int, render_seed: int, index: int, stream: int) -> int:
    """The sensor's seed for capture `index` of a stream (LDR twin, encoded, ...)."""
    return int(np.random.SeedSequence([sensor_seed, render_seed, index, stream]).generate_state(1)[0])
