"""The immutable `Frame` passed between stages (DESIGN.md "The Frame"), and the ground truth of
one exposure (`RenderedExposure`) that every radiance source (render/, sources/) yields."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

import numpy as np

from poevp_optics.core.units import PHOTON_RADIANCE_UNIT


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


@dataclass(frozen=True)
class RenderedExposure:
    """Ground truth for one frame: K radiance samples and their time average (mirror grid)."""

    index: int
    t_start_s: float
    exposure_s: float
    subframe_times_s: np.ndarray        # (K,) sample times (camera/dmd.py node_times_s)
    subframes: tuple[np.ndarray, ...]   # K x (H, W) photon radiance, mirror (render) grid
    radiance: Frame                     # time average over the exposure
    variance: np.ndarray                # MC variance of `radiance` per pixel
    roi: tuple[int, int, int, int] | None
    rel_error: float | None
    rel_error_roi: float | None
    basis: tuple[str, ...] = ()         # subframes are emitter-group images (PWM lamps), not times
    subframe_variances: tuple[np.ndarray, ...] = ()   # MC variance of each sample (temporal error)
    subframe_weights: tuple[float, ...] = ()  # radiance = sum of weight x sample (a moving scene's time average)
    ground_truth: dict | None = None    # from a frame source: plate text, frames read, plate velocity
    spp: tuple[int, ...] = ()           # spp each radiance sample (or basis image) actually used
    target_met: bool | None = None      # render.target_rel_error reached (None: no target)
    plates: tuple = ()                  # render.roi_shape = "plates": one dict per plate (render/exposures.py PlateTrack)

    @classmethod
    def build(cls, index: int, t0_s: float, t1_s: float, times_s: np.ndarray, subframes, mean: np.ndarray,
              variance: np.ndarray, roi, rel_error: float | None = None, rel_error_roi: float | None = None,
              **extra) -> "RenderedExposure":
        """The one way every source makes an exposure: frame `index` exposed over [t0_s, t1_s]
        (s), its radiance samples at `times_s` and their time average `mean` (photon radiance,
        `PHOTON_RADIANCE_UNIT`) with its MC variance; the MC errors as the source measured them
        (None: not estimated, e.g. read from files)."""
        frame = Frame(mean, Quantity.RADIANCE, PHOTON_RADIANCE_UNIT, t0_s, t1_s - t0_s, index)
        return cls(index, t0_s, t1_s - t0_s, times_s, tuple(subframes), frame, variance, roi, rel_error,
                   rel_error_roi, **extra)

    def capture_timing(self) -> dict:
        """The keyword a capture of these samples takes: the basis names, or the sample times."""
        if self.basis:
            return {"basis": self.basis}
        return {"times_s": self.subframe_times_s} if len(self.subframes) > 1 else {}
