"""Which pixel grid an array is on: the predictor's, the sensor's or the DMD's mirror grid.

A mask on its way from the predictor to the DMD changes grid three times (issue 30): the
predictor works at `[predictor].resolution` (resized with the clip marker kept,
control/loop_step.py), the camera measures on the sensor grid (`render.resolution`), and the
DMD takes levels on the mirror grid (the sensor's footprint on the DMD plus the guard band,
placed through the relay's registration, camera/registration.py). The arrays that cross the
loop's boundary carry their grid as an `OnGrid`, and each conversion takes and returns that
tagged form and refuses an array on another grid (`GridError`), even one of the same shape.

`OnGrid` is a plain record, not an ndarray subclass: arithmetic happens on `.array`, so a tag
can never be carried silently onto a result it does not describe.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: The grids of the loop (module docstring).
GRID_NAMES = ("predictor", "sensor", "mirror")


class GridError(ValueError):
    """An array on one grid where another is needed (the message names both)."""


@dataclass(frozen=True)
class Grid:
    """A pixel grid: its name (GRID_NAMES), (H, W) and pixel pitch in metres where known
    (sensor: the pixel pitch; mirror: the DMD's mirror pitch, or the sensor's without a DMD;
    predictor: None, its pixels are a resampling of the sensor's)."""

    name: str
    shape: tuple[int, int]
    pitch_m: float | None = None

    def __post_init__(self):
        if self.name not in GRID_NAMES:
            raise ValueError(f"grid name {self.name!r} is not one of {GRID_NAMES}")
        shape = tuple(int(n) for n in self.shape)
        if len(shape) != 2 or min(shape) < 1:
            raise ValueError(f"{self.name} grid shape {self.shape!r} is not (H, W) with H, W >= 1")
        object.__setattr__(self, "shape", shape)
        if self.pitch_m is not None and not (np.isfinite(self.pitch_m) and self.pitch_m > 0):
            raise ValueError(f"{self.name} grid pitch {self.pitch_m!r} m is not a positive number")

    def __str__(self) -> str:
        pitch = f", {self.pitch_m * 1e6:.4g} um" if self.pitch_m is not None else ""
        return f"{self.name} grid ({self.shape[0]}x{self.shape[1]}{pitch})"

    def tag(self, array) -> "OnGrid":
        """`array` as on this grid (its shape checked)."""
        return OnGrid(array, self)

    def take(self, x, what: str):
        """The array of `x` for a consumer that needs this grid: an `OnGrid` on another grid is
        refused (GridError naming both); a plain array passes as it is (untagged callers)."""
        if isinstance(x, OnGrid):
            return x.on(self, what).array
        return x


@dataclass(frozen=True, eq=False)
class OnGrid:
    """An array (H, W) or (H, W, ...) and the grid it is on (module docstring)."""

    array: Any
    grid: Grid

    def __post_init__(self):
        if isinstance(self.array, OnGrid):
            raise TypeError(f"an array already on the {self.array.grid} cannot be tagged again")
        shape = tuple(np.shape(self.array))
        if shape[:2] != self.grid.shape:
            raise GridError(f"an array of shape {shape} is not on the {self.grid}")

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(np.shape(self.array))

    def on(self, grid: Grid, what: str = "array") -> "OnGrid":
        """Itself, checked to be on `grid`: a different grid (name, shape or pitch) is refused."""
        if self.grid != grid:
            raise GridError(f"{what} is on the {self.grid}, but the {grid} is needed here")
        return self

    def expect(self, name: str, what: str = "array") -> "OnGrid":
        """Itself, checked to be on a grid named `name` (its shape is then that grid's)."""
        if self.grid.name != name:
            raise GridError(f"{what} is on the {self.grid}, but the {name} grid is needed here")
        return self
