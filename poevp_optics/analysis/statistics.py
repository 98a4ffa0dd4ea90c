"""Statistics of a recognition benchmark: score intervals for read rates, and the lag artifact.

Read rate: k plates read of n frames is a binomial proportion; its 95 % interval is Wilson's score
interval (E. B. Wilson, "Probable inference, the law of succession, and statistical inference",
J. Am. Stat. Assoc. 22 (1927) 209-212), which unlike the Wald interval p +- z sqrt(p(1-p)/n) stays
inside [0, 1] and keeps width at k = 0 and k = n:

    centre = (k + z^2/2) / (n + z^2),  half = z sqrt(k (n - k) / n + z^2 / 4) / (n + z^2)

Lag artifact (paper Sec. 8, the sudden-reversal failure case): frames after a motion change until
the plate reads again.
"""

from __future__ import annotations

import math
from typing import Sequence

#: Two-sided 95 % normal quantile, Phi^-1(0.975).
Z95 = 1.959963984540054


def wilson_interval(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson (1927) score interval (low, high) of a binomial proportion, k successes of n trials;
    z: normal quantile (default 95 % two-sided). n = 0 gives the uninformative (0, 1)."""
    if n < 0 or k < 0 or k > n:
        raise ValueError(f"wilson_interval: need 0 <= k <= n, got k={k}, n={n}")
    if n == 0:
        return 0.0, 1.0
    z2 = z * z
    centre = (k + z2 / 2.0) / (n + z2)
    half = z * math.sqrt(k * (n - k) / n + z2 / 4.0) / (n + z2)
    return max(0.0, centre - half), min(1.0, centre + half)


def lag_frames(read: Sequence[bool], change: int) -> int | None:
    """Frames after a motion change at index `change` until the plate reads again: 0 when it
    reads in the change frame itself; None when it never reads again in `read`."""
    for j in range(max(0, change), len(read)):
        if read[j]:
            return j - change
    return None
