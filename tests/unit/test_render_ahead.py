"""A run renders the next frame while the camera works on the one before (render/ahead.py):
frames come in order from a thread of their own, the next one rendered while the loop holds the
current one and no further; a source's error reaches the loop at its frame; a loop that stops
early stops the thread and closes the source; and a run that renders ahead writes the recorded
reference bytes (tests/regression/reference_hashes.json) and says so in its report."""

from __future__ import annotations

import json
import threading

import pytest

from poevp_optics.core.exceptions import SceneError
from poevp_optics.render.ahead import RenderAhead


def _no_ahead_thread() -> bool:
    return not any(t.name == "poevp-render-ahead" for t in threading.enumerate())


class Source:
    """A frame source that records which frames it made, on which thread, and whether it was
    closed; frame `fail_at` raises instead."""

    def __init__(self, n: int, fail_at: int | None = None):
        self.n, self.fail_at = n, fail_at
        self.made, self.threads, self.closed = [], set(), False
        self.made_event = threading.Condition()

    def __iter__(self):
        try:
            for i in range(self.n):
                if i == self.fail_at:
                    raise SceneError(f"scene.toml: frame {i}: radiance is NaN")
                with self.made_event:
                    self.made.append(i)
                    self.threads.add(threading.current_thread().name)
                    self.made_event.notify_all()
                yield i
        finally:
            self.closed = True

    def wait_made(self, count: int) -> bool:
        with self.made_event:
            return self.made_event.wait_for(lambda: len(self.made) >= count, timeout=10.0)


def test_frames_come_in_order_and_the_next_renders_while_the_loop_holds_this_one():
    src = Source(5)
    got = []
    with RenderAhead(iter(src)) as ahead:
        for i in ahead:
            got.append(i)
            if i + 1 < src.n:             # the loop still holds frame i: frame i + 1 is made meanwhile
                assert src.wait_made(i + 2), (i, src.made)
            assert len(src.made) <= i + 2, (i, src.made)     # one frame ahead, no more
    assert got == list(range(5)) and src.closed
    assert src.threads == {"poevp-render-ahead"}
    assert ahead.wait_seconds >= 0.0 and _no_ahead_thread()


def test_a_source_error_reaches_the_loop_at_its_frame():
    src = Source(5, fail_at=2)
    got = []
    with pytest.raises(SceneError, match="frame 2: radiance is NaN"):
        with RenderAhead(iter(src)) as ahead:
            for i in ahead:
                got.append(i)
    assert got == [0, 1] and src.closed and _no_ahead_thread()


def test_a_loop_that_stops_early_stops_the_thread_and_closes_the_source():
    src = Source(50)
    with pytest.raises(KeyboardInterrupt):
        with RenderAhead(iter(src)) as ahead:
            for i in ahead:
                if i == 1:
                    raise KeyboardInterrupt        # Ctrl-C in the loop
    assert src.closed and _no_ahead_thread()
    assert src.made[-1] <= 2, src.made             # the frame in flight finished, nothing after it


@pytest.mark.parametrize("enabled", [True, False])
def test_a_run_rendering_ahead_writes_the_reference_bytes(tmp_path, monkeypatch, enabled):
    """highbeam_plate (92x160, 4 moving frames, 3 radiance nodes each) with the next frame
    rendered ahead and in line: every output array and the report's physics as recorded."""
    from tests.regression.bit_identical import REFERENCE, run_case

    monkeypatch.setattr(RenderAhead, "enabled", enabled)
    got = run_case("highbeam_plate", tmp_path)
    ref = json.loads(REFERENCE.read_text())["cases"]["highbeam_plate"]
    assert got == ref, sorted(k for k in ref if ref[k] != got.get(k))
    render = json.loads((tmp_path / "highbeam_plate" / "report.json").read_text())["stages"]["render"]
    assert (render["ahead_wait_seconds"] is not None) is enabled
    assert _no_ahead_thread()


def test_a_render_whose_source_fails_on_a_later_frame_leaves_earlier_output(tmp_path, monkeypatch, capsys):
    """Rendering ahead, the render fails on frame 2 while the camera works on frame 1: one line,
    exit 1, the earlier output untouched, no staging folder, no render or writer thread left."""
    from poevp_optics.render import radiance
    from tests.regression.test_interrupts import earlier_output
    from tests.unit.test_background_writer import render_fails_leaving

    out = tmp_path / "out"
    kept = earlier_output(out, "render")
    real = radiance.render_exposures

    def fails_at_frame_2(scene, renderer, progress=True):
        for ex in real(scene, renderer, progress):
            if ex.index == 2:
                raise RuntimeError("jit_malloc(): out of memory while rendering frame 2")
            yield ex

    monkeypatch.setattr(radiance, "render_exposures", fails_at_frame_2)
    monkeypatch.setattr(RenderAhead, "enabled", True)
    render_fails_leaving(out, kept, 4, "RuntimeError: jit_malloc(): out of memory while rendering frame 2", capsys)
    assert _no_ahead_thread()


def test_a_loop_timed_by_its_own_wall_clock_renders_in_line(tmp_path, monkeypatch):
    """`[budget] compute = "measured"` decides late masks by this run's predictor and mask wall
    time: such a run renders in line (rendering ahead would time the render's contention for the
    cores), and the same run on a device budget renders ahead."""
    from poevp_optics.cli import main
    from tests.conftest import SCENES

    monkeypatch.setattr(RenderAhead, "enabled", True)
    waits = {}
    for compute in ("measured", "fpga_zynq"):
        out = tmp_path / compute
        args = ["render", str(SCENES / "highbeam_plate"), "--out", str(out), "--quiet", "--resolution", "46x80",
                "--frames", "3", "--spp", "2", "--set", f"budget.compute='{compute}'"]
        assert main(args) == 0
        report = json.loads((out / "report.json").read_text())
        assert report["timing_budget"]["compute"] == compute
        waits[compute] = report["stages"]["render"]["ahead_wait_seconds"]
    assert waits["measured"] is None and waits["fpga_zynq"] is not None, waits
