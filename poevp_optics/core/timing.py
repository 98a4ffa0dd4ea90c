"""The frame clock: when each frame starts, when the sensor integrates, when the DMD displays.

| key                  | type  | unit | default | meaning |
|----------------------|-------|------|---------|---------|
| fps                  | float | Hz   | 30      | frame rate; frame i starts at i / fps |
| frames               | int   | -    | 8       | frames in the run |
| exposure_s           | float | s    | 1/60    | sensor integration time t_I |
| exposure_offset_s    | float | s    | 0       | exposure start after the frame start |
| dmd_window_s         | float | s    | 1/60    | DMD display window t_D (the bit-planes) |
| dmd_window_offset_s  | float | s    | 0       | window start after the frame start |
| outside_window       | str   | -    | white   | mirrors all on ("white") or off ("dark") outside the window |

Source: the paper's Fig. 7 timing (t_I = 33.33 ms, t_D = 20 ms, white outside t_D).
"""

from __future__ import annotations

from dataclasses import dataclass

from poevp_optics.core.params import param


@dataclass(frozen=True)
class TimingSpec:
    """[timing]: frame clock, sensor exposure and DMD display window (s, from frame start)."""

    fps: float = param(30.0, gt=0, max=1e6)
    frames: int = param(8, min=1, max=100000)
    exposure_s: float = param(1 / 60, gt=0, max=100.0)
    exposure_offset_s: float = param(0.0, min=0)
    dmd_window_s: float = param(1 / 60, gt=0, max=100.0)
    dmd_window_offset_s: float = param(0.0, min=0)
    outside_window: str = param("white", choices=("white", "dark"))

    def frame_start_s(self, index: int) -> float:
        return index / self.fps

    def exposure_window_s(self, index: int) -> tuple[float, float]:
        """[start, end] of frame `index`'s exposure (s)."""
        t0 = self.frame_start_s(index) + self.exposure_offset_s
        return t0, t0 + self.exposure_s
