"""The immutable `Frame` passed between stages (DESIGN.md "The Frame")."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any


class Quantity(enum.Enum):
    """What a frame's pixels measure."""

    RADIANCE = "radiance"                      # sensor-weighted photon radiance
    ELECTRONS = "electrons"
    DN = "dn"
    RADIANCE_ESTIMATE = "radiance_estimate"
    MASK = "mask"
    EXPOSURE = "exposure"


@dataclass(frozen=True)
class Frame:
    """One image between two stages.

    data: numpy array or DrJit tensor, shape (H, W) or (H, W, C).
    quantity, unit: what the pixels measure and in which unit (e.g. "e- s-1 m-2 sr-1").
    t_start_s, exposure_s: the time window the pixels integrate or average over, in s.
    index: frame number in the sequence.
    """

    data: Any
    quantity: Quantity
    unit: str
    t_start_s: float
    exposure_s: float
    index: int

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.data.shape)
