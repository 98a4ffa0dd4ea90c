"""A render run writes each frame's files on a thread of its own while the loop goes on
(render_run.py `BackgroundWriter`): every frame written, in order, one at a time; the loop not
held up by the write in flight; a writer's error raised in the loop; nothing left running."""

from __future__ import annotations

import threading

import pytest

from poevp_optics.apps.run.render_run import BackgroundWriter, RunResult
from poevp_optics.cli import main
from tests.conftest import SCENES
from tests.regression.test_interrupts import QUICK_RENDER, debris, earlier_output, tree


class Frame:
    def __init__(self, index: int):
        self.index = index


class RecordingWriter:
    """Writes nothing; records which frame it was given, on which thread, and whether two
    writes ever ran at once. `gate`: each write waits for it (the loop's go-ahead)."""

    def __init__(self, gate: threading.Event | None = None, fail_at: int | None = None):
        self.frames, self.threads, self.busy, self.overlap = [], [], False, False
        self.gate, self.fail_at = gate, fail_at

    def frame(self, fc) -> None:
        self.overlap |= self.busy
        self.busy = True
        try:
            if self.gate is not None:
                assert self.gate.wait(10.0), "the loop never went on while the frame was being written"
                self.gate.clear()
            if fc.index == self.fail_at:
                raise OSError(f"disk full at frame {fc.index}")
            self.frames.append(fc.index)
            self.threads.append(threading.current_thread().name)
        finally:
            self.busy = False


def test_frames_written_in_order_on_their_own_thread_while_the_loop_goes_on():
    gate = threading.Event()
    writer, res = RecordingWriter(gate), RunResult()
    bw = BackgroundWriter(writer, res)
    for i in range(5):
        bw.submit(Frame(i))    # returns with the write still waiting: a writer in line would hang here
        gate.set()             # the loop's next work, done while the frame is written
    bw.close()
    assert writer.frames == [0, 1, 2, 3, 4] and not writer.overlap
    assert set(writer.threads) == {writer.threads[0]} and writer.threads[0] != threading.current_thread().name
    assert res.write_seconds > 0.0 and res.write_wait_seconds >= 0.0
    assert not any(t.name.startswith("poevp-writer") for t in threading.enumerate())


def test_a_writers_error_is_raised_in_the_loop():
    writer, res = RecordingWriter(fail_at=1), RunResult()
    bw = BackgroundWriter(writer, res)
    bw.submit(Frame(0))
    bw.submit(Frame(1))
    with pytest.raises(OSError, match="disk full at frame 1"):
        bw.submit(Frame(2))                 # the hand-over waits for frame 1 and raises its error
    bw.close()
    assert writer.frames == [0]             # frame 2 was never handed over
    writer, res = RecordingWriter(fail_at=0), RunResult()
    bw = BackgroundWriter(writer, res)
    bw.submit(Frame(0))
    with pytest.raises(OSError, match="disk full at frame 0"):
        bw.close()                          # the last frame's error at close
    assert not any(t.name.startswith("poevp-writer") for t in threading.enumerate())


def test_render_whose_writer_fails_on_a_later_frame_leaves_earlier_output(tmp_path, monkeypatch, capsys):
    """The second frame's files fail while the third frame renders: one line, exit 1, the earlier
    output untouched, no staging folder left, no writer thread left."""
    out = tmp_path / "out"
    kept = earlier_output(out, "render")
    import poevp_optics.apps.run.outputs as outputs

    real, calls = outputs.write_exr, []

    def fails_on_frame_1(path, *a, **k):
        calls.append(path.name)
        if path.name.startswith("frame_0001"):
            raise RuntimeError("disk on fire")
        return real(path, *a, **k)

    monkeypatch.setattr(outputs, "write_exr", fails_on_frame_1)
    render_fails_leaving(out, kept, 4, "RuntimeError: disk on fire", capsys)
    assert any(n.startswith("frame_0000") for n in calls) and not any(n.startswith("frame_0003") for n in calls)


def render_fails_leaving(out, kept: dict, frames: int, message: str, capsys) -> None:
    """A small render of `frames` frames into `out` fails with one line holding `message`, and
    leaves the earlier output `kept`, no staging folder and no writer thread."""
    capsys.readouterr()
    args = [a for a in QUICK_RENDER if a not in ("--frames", "1")] + ["--frames", str(frames)]
    assert main(["render", str(SCENES / "smoke"), "--out", str(out), *args]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert tree(out) == kept and debris(out) == []
    assert not any(t.name.startswith("poevp-writer") for t in threading.enumerate())


def test_the_loops_own_error_is_the_one_reported(tmp_path, monkeypatch, capsys):
    """Frame 0's files fail (a disk full) and the loop fails on frame 1 before it hands that frame
    over: the loop's error is the line reported, the writer's thread is ended, nothing is left."""
    out = tmp_path / "out"
    kept = earlier_output(out, "render")
    import poevp_optics.apps.run.outputs as outputs
    from poevp_optics.apps.run import render_run

    def disk_full(path, *a, **k):
        raise OSError("disk full")

    real_metrics = render_run._metrics

    def metrics(spec, camera, fc):
        if fc.exposure.index == 1:
            raise FloatingPointError("capture of frame 1 holds NaN")
        return real_metrics(spec, camera, fc)

    monkeypatch.setattr(outputs, "write_exr", disk_full)
    monkeypatch.setattr(render_run, "_metrics", metrics)
    render_fails_leaving(out, kept, 3, "capture of frame 1 holds NaN", capsys)
    writer = RecordingWriter(fail_at=0)
    bw = BackgroundWriter(writer, RunResult())
    bw.submit(Frame(0))
    bw.close(quiet=True)                    # the loop's error is being raised: the writer's is not
