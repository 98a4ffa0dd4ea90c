"""The camera's real-time budget (paper Appendix D) and when each mask reaches the DMD.

Per frame t, after its exposure ends, the loop must: read the capture out and move it to the
compute unit, predict and compute the mask, move the mask to the DMD and load its patterns,
before frame t + 1's display window starts:

    T_bus(H, W, B) = H W B / (f BW)                       (paper App. D, its T_AHB)
    budget = T_bus(sensor H, W, sensor bits) + T_compute + T_bus(mirror H, W, DMD bits) + T_load
    slack  = start of frame t+1's window - (end of frame t's exposure + budget)

| key            | type  | unit | default | meaning |
|----------------|-------|------|---------|---------|
| bus_hz         | float | Hz   | 200e6   | bus clock f (paper: 32-bit AHB at 200 MHz) |
| bus_width_bits | int   | bit  | 32      | bus width BW |
| compute        | str   | -    | fpga_zynq | predictor + mask law time: a device budget (COMPUTE_BUDGETS) or `measured` |
| compute_s      | float | s    | 0.0     | the time for compute = "given" |
| dmd_load_s     | float | s    | 0.0     | controller latency after the bus transfer (pattern-on-the-fly load: 0) |
| late_mask      | str   | -    | ideal   | a mask past its window start: `partial` (takes over at the first bit-plane after it arrives), `next` (waits for the next frame), `ideal` (the budget is reported, the mask is taken as on time) |

Compute budgets: `rtx3090` 16.9 ms (paper Table 2: VP + mask on an RTX 3090), `fpga_zynq`
3.96 ms (paper App. D: 1e10 FLOP at 2.525 TFLOPS on a Zynq XC7Z035), `measured` (this run's
predictor + mask wall time per frame: not reproducible run to run), `given` (compute_s).

Per-frame exposure (control/exposure_time.py): a frame whose exposure controller shortened the
sensor's exposure to T_e shows its B planes in a window equal to that exposure, centred on the
scene's; the budget of the next mask then runs from the shortened exposure's end and the window
it must meet is that frame's own (reported per frame as `window_s`).

One compute unit: a mask whose inputs arrive while the previous mask is still being computed
waits for it. Frame rates reported: `on_time_fps`, the highest frame rate at which every mask
is on time with this exposure and window placement; `pipelined_fps`, 1 / the slowest stage
(stages of consecutive frames overlapping); `paper_serial_fps`, 1 / (budget + t_D), the paper's
App. D form (2 T_AHB + T_FPGA + T_DMD, 104 fps for its FPGA).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from poevp_optics.core.params import param
from poevp_optics.core.registry import Registry

COMPUTE_BUDGETS = Registry("compute budget")
COMPUTE_BUDGETS.register("fpga_zynq", 3.96e-3, source="paper App. D: 1e10 FLOP / 2.525 TFLOPS, Zynq XC7Z035")
COMPUTE_BUDGETS.register("rtx3090", 16.9e-3, source="paper Table 2: VP + mask 16.9 ms, RTX 3090")
COMPUTE_BUDGETS.register("measured", None, source="this run: predictor + mask law wall time per frame")
COMPUTE_BUDGETS.register("given", None, source="the scene's budget.compute_s")

LATE_MASK_MODES = ("ideal", "partial", "next")


@dataclass(frozen=True)
class BudgetSpec:
    """[budget]: the loop's real-time budget (module docstring)."""

    bus_hz: float = param(200e6, gt=0, max=1e12)
    bus_width_bits: int = param(32, min=1, max=4096)
    compute: str = param("fpga_zynq", choices=COMPUTE_BUDGETS)
    compute_s: float = param(0.0, min=0, max=100.0)
    dmd_load_s: float = param(0.0, min=0, max=100.0)
    late_mask: str = param("ideal", choices=LATE_MASK_MODES)


def bus_seconds(h: int, w: int, bits: int, spec: BudgetSpec) -> float:
    """Time (s) to move an H x W image of `bits` bits per pixel over the bus: H W B / (f BW)."""
    return h * w * bits / (spec.bus_hz * spec.bus_width_bits)


@dataclass(frozen=True)
class Shown:
    """What the DMD shows in one frame's window: `levels` from the window start; `late`, a mask
    taking over at `switch_s` (absolute) for the bit-planes that start after it (or None)."""

    levels: np.ndarray | None
    late: np.ndarray | None = None
    switch_s: float | None = None
    record: dict = field(default_factory=dict)


class MaskClock:
    """When each mask is ready and what each frame's window shows (module docstring). State is
    real: the masks computed so far and when the compute unit is free."""

    def __init__(self, spec: BudgetSpec, timing, sensor_shape, sensor_bits: int, mirror_shape, dmd_bits: int):
        self.spec, self.timing = spec, timing
        self.readout_s = bus_seconds(*sensor_shape, sensor_bits, spec)
        self.transfer_s = bus_seconds(*mirror_shape, dmd_bits, spec)
        self.top = (1 << dmd_bits) - 1
        self.free_at_s = -math.inf
        self.masks: list[tuple[float, np.ndarray]] = []     # (ready time, levels), oldest first
        self.records: list[dict] = []
        self.exposures: dict = {}     # frame -> its exposure choice (control/exposure_time.py), where not the scene's

    def exposure_window_s(self, index: int) -> tuple[float, float]:
        """[start, end] of frame `index`'s exposure (s): the scene's, or the frame's shortened
        one centred on it (control/exposure_time.py)."""
        t0, t1 = self.timing.exposure_window_s(index)
        fx = self.exposures.get(index)
        if fx is None:
            return t0, t1
        mid = 0.5 * (t0 + t1)
        return mid - 0.5 * fx.exposure_s, mid + 0.5 * fx.exposure_s

    def compute_seconds(self, measured_s: float | None) -> float:
        """Predictor + mask time of one mask (s): the device budget, the given one or measured."""
        fixed = COMPUTE_BUDGETS[self.spec.compute]     # seconds; None: measured or given
        if fixed is not None:
            return float(fixed)
        if self.spec.compute == "measured" and measured_s is not None:
            return float(measured_s)
        return float(self.spec.compute_s)

    def window_s(self, index: int) -> tuple[float, float]:
        """[start, end] of frame `index`'s DMD window (s): the scene's, or the frame's exposure
        choice's (its B planes in a window equal to the shortened exposure)."""
        t = self.timing
        fx = self.exposures.get(index)
        if fx is not None:
            mid = sum(t.exposure_window_s(index)) / 2
            return mid - 0.5 * fx.window_s, mid + 0.5 * fx.window_s
        w0 = t.frame_start_s(index) + t.dmd_window_offset_s
        return w0, w0 + t.dmd_window_s

    def ready_s(self, index: int, compute_s: float) -> tuple[float, dict]:
        """When the mask of frame `index` (from frame index-1's capture) reaches the DMD."""
        end = self.exposure_window_s(index - 1)[1]
        start = max(end + self.readout_s, self.free_at_s)
        self.free_at_s = start + compute_s
        ready = self.free_at_s + self.transfer_s + self.spec.dmd_load_s
        return ready, {"exposure_end_s": end, "compute_start_s": start, "compute_s": compute_s,
                       "budget_s": ready - end}

    def show(self, index: int, levels: np.ndarray | None, init: bool, measured_s: float | None,
             exposure=None) -> Shown:
        """Frame `index`'s window for the mask computed for it (`init`: a preloaded white mask);
        exposure: the frame's exposure choice (its window replaces the scene's for this frame)."""
        if levels is None:
            return Shown(None)
        if exposure is not None and not exposure.nominal:
            self.exposures[index] = exposure
            self.exposures = {k: v for k, v in self.exposures.items() if k >= index - 2}
        w0, w1 = self.window_s(index)
        if init:
            self.masks.append((-math.inf, levels))
            return Shown(levels, record={"init": True})
        ready, rec = self.ready_s(index, self.compute_seconds(measured_s))
        rec.update({"frame": index, "ready_s": ready, "window_start_s": w0, "slack_s": w0 - ready,
                    "late": ready > w0})
        if index in self.exposures:
            rec["window_s"] = w1 - w0
        ready_before = [m for r, m in self.masks if r <= w0]
        previous = ready_before[-1] if ready_before else np.full_like(levels, float(self.top))
        self.masks.append((ready, levels))
        self.masks = self.masks[-8:]
        self.records.append(rec)
        mode = self.spec.late_mask
        if mode == "ideal" or ready <= w0:
            rec["shown"] = "on time" if ready <= w0 else "on time (late_mask = 'ideal')"
            return Shown(levels, record=rec)
        if mode == "partial" and ready < w1:
            rec["shown"] = f"previous mask, this one from {1e3 * (ready - w0):.3f} ms into the window"
            return Shown(previous, levels, ready, rec)
        rec["shown"] = "the newest mask ready at the window start (this one from a later frame on)"
        return Shown(previous, record=rec)

    def summary(self, budget_parts: dict | None = None) -> dict:
        """The report's timing-budget section: parts, per-frame budget and slack, frame rates."""
        t, recs = self.timing, self.records
        compute = [r["compute_s"] for r in recs]
        c = float(np.median(compute)) if compute else self.compute_seconds(None)
        budget = self.readout_s + c + self.transfer_s + self.spec.dmd_load_s
        lead = t.exposure_offset_s + t.exposure_s - t.dmd_window_offset_s   # exposure end -> own window start
        out = {
            "parts_s": {"sensor_readout": self.readout_s, "compute": c, "dmd_transfer": self.transfer_s,
                        "dmd_load": self.spec.dmd_load_s},
            "compute": self.spec.compute, "late_mask": self.spec.late_mask,
            "bus": {"hz": self.spec.bus_hz, "width_bits": self.spec.bus_width_bits},
            "budget_s": budget,
            "gap_s": 1.0 / t.fps - lead,
            "slack_s": (1.0 / t.fps - lead) - budget,
            "late_frames": [r["frame"] for r in recs if r["late"]],
            "on_time_fps": 1.0 / (lead + budget) if lead + budget > 0 else math.inf,
            "pipelined_fps": 1.0 / max(self.readout_s, c, self.transfer_s + self.spec.dmd_load_s, 1e-12),
            "paper_serial_fps": 1.0 / (budget + t.dmd_window_s),
            "definitions": {
                "budget_s": "sensor readout + compute + DMD transfer + DMD load (median compute)",
                "gap_s": "end of frame t's exposure to the start of frame t+1's window",
                "on_time_fps": "highest fps with every mask on time at this exposure and window placement",
                "pipelined_fps": "1 / slowest stage, stages of consecutive frames overlapping",
                "paper_serial_fps": "1 / (budget + t_D): paper App. D's 2 T_AHB + T_FPGA + T_DMD"},
            **(budget_parts or {}),
        }
        return out
