"""The run's timeline figure (issue 18): three frames, late masks marked."""

from __future__ import annotations

import numpy as np

from poevp_optics.apps.run.timeline import timeline_frames, write_timeline
from poevp_optics.camera.dmd import DMDSpec, Schedule
from poevp_optics.control.timing_budget import BudgetSpec, MaskClock
from poevp_optics.core.io import read_png
from poevp_optics.core.timing import TimingSpec


def test_timeline_png_of_three_frames(tmp_path):
    timing = TimingSpec(fps=30.0, frames=6, exposure_s=0.030, dmd_window_s=0.030)
    clock = MaskClock(BudgetSpec(compute="rtx3090", late_mask="partial"), timing, (46, 80), 8, (46, 80), 8)
    for i in range(6):
        clock.show(i, np.full((46, 80), 255.0 if i < 2 else 40.0), i < 2, None)
    assert timeline_frames(clock, 2, 6) == [1, 2, 3]
    path = write_timeline(tmp_path, timing, clock, lambda i: Schedule.for_frame(DMDSpec(), timing, i / 30.0), 2, 6)
    img = read_png(path)
    assert img.ndim >= 2 and img.shape[0] > 200 and img.shape[1] > 600
    # the hatched late part of a window is drawn in red: some pixels are strongly red
    rgb = img[..., :3].astype(int)
    assert np.any((rgb[..., 0] > 200) & (rgb[..., 1] < 80) & (rgb[..., 2] < 80))


def test_timeline_draws_the_attenuator_settling_late_in_red(tmp_path):
    """30 fps, 30 ms exposure: 3.3 ms between exposures. A 20 ms settling attenuator commanded
    right after its capture's readout settles after the next exposure starts: its bars add red
    (no mask is late here) against the same figure with a 1 ms settling (on time)."""
    timing = TimingSpec(fps=30.0, frames=6, exposure_s=0.030, dmd_window_s=0.030)
    clock = MaskClock(BudgetSpec(compute="given", compute_s=0.0, late_mask="partial"), timing, (4, 4), 8, (4, 4), 8)
    for i in range(6):
        clock.show(i, np.full((4, 4), 255.0 if i < 2 else 40.0), i < 2, None)
    assert not any(r["late"] for r in clock.records)
    sched = lambda i: Schedule.for_frame(DMDSpec(), timing, i / 30.0)  # noqa: E731
    red = lambda p: np.count_nonzero((lambda rgb: (rgb[..., 0] > 200) & (rgb[..., 1] < 80) & (rgb[..., 2] < 80))(  # noqa: E731
        read_png(p)[..., :3].astype(int)))
    on_time = red(write_timeline(tmp_path, timing, clock, sched, 2, 6, attenuator_settle_s=0.001))
    assert red(write_timeline(tmp_path, timing, clock, sched, 2, 6, attenuator_settle_s=0.020)) > on_time + 100
