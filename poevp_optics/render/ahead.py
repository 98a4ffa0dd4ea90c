"""Render one frame ahead: the next frame's radiance is rendered on a thread of its own while the
camera, the loop and the metrics work on the frame before.

The render is open loop (render/exposures.py reads only the scene and the frame index: no mask,
capture or prediction reaches it), so rendering ahead changes no number: every frame draws its
own seeds (core/seeds.py), and the run writes the same bytes as one that renders in line
(tests/unit/test_render_ahead.py). It pays where the camera's stages leave a core idle: NumPy's
array passes run on one thread while Mitsuba's kernels use every DrJit thread. night_road at
540x960 (21 frames, 2 cores, four runs of each, interleaved): median 43.6 s against 49.0 s in
line, the same CPU time and the same outputs byte for byte (docs/physics/render-speed.md).

A run whose loop budget is measured (`[budget] compute = "measured"`: the mask is late or on
time by this run's own predictor and mask wall time) renders in line, so that the time it
measures is not the render's contention for the cores.

At most one frame is held beyond the one the loop works on (the memory estimate counts it:
apps/run/memory.py "exposure ahead"). A source error reaches the loop when it asks for that
frame, as it would in line; a loop that stops early (an error, Ctrl-C, SIGTERM) stops the thread
after the frame it is rendering and waits for it, so nothing renders after the run returns.
"""

from __future__ import annotations

import queue
import threading
import time

#: Seconds between checks of the stop flag while the thread waits for the loop to take a frame.
_POLL_S = 0.05


class RenderAhead:
    """Iterate `exposures` (any iterator of frames) one frame ahead on a thread of its own; use
    as a context manager, or call `close`. `wait_seconds`: what the loop spent waiting for
    frames (wall)."""

    #: None: render ahead where the run has two threads or more (core/runtime.py run_threads); True:
    #: always; False: never (benchmarks/render_cost.py: its stage clocks read the process's CPU
    #: time, which a second thread would blur).
    enabled: bool | None = None

    @classmethod
    def wanted(cls) -> bool:
        """Whether a run renders ahead (`enabled`)."""
        if cls.enabled is not None:
            return cls.enabled
        from poevp_optics.core.runtime import run_threads

        return run_threads() >= 2

    def __init__(self, exposures):
        self._source = exposures
        self._frames: queue.Queue = queue.Queue()
        self._slot = threading.Semaphore(1)      # taken per frame rendered, given back when the loop takes it
        self._stop = threading.Event()
        self._done = False
        self.wait_seconds = 0.0
        self._thread = threading.Thread(target=self._work, name="poevp-render-ahead", daemon=True)
        self._thread.start()

    def _take_slot(self) -> bool:
        """Wait until the loop has taken the frame rendered before (at most one frame ahead);
        False once the loop has stopped."""
        while not self._slot.acquire(timeout=_POLL_S):
            if self._stop.is_set():
                return False
        return not self._stop.is_set()

    def _work(self) -> None:
        source = self._source
        try:
            frames = iter(source)
            while self._take_slot():
                try:
                    ex = next(frames)
                except StopIteration:
                    self._frames.put(("end", None))
                    return
                self._frames.put(("frame", ex))
        except BaseException as e:      # noqa: BLE001 - handed to the loop's thread, raised there
            self._frames.put(("error", e))
        finally:
            close = getattr(source, "close", None)
            if close is not None:        # a generator stopped early runs its cleanup on this thread
                close()

    def __iter__(self):
        return self

    def __next__(self):
        if self._done:
            raise StopIteration
        t = time.perf_counter()
        while True:
            try:
                kind, value = self._frames.get(timeout=_POLL_S)
                break
            except queue.Empty:
                if not self._thread.is_alive() and self._frames.empty():
                    self._done = True
                    raise RuntimeError("the render thread ended without a frame or an error") from None
        self.wait_seconds += time.perf_counter() - t
        if kind == "frame":
            self._slot.release()                 # the thread may render the next frame now
            return value
        self._done = True
        self._thread.join()
        if kind == "error":
            raise value
        raise StopIteration

    def close(self) -> None:
        """Stop after the frame being rendered and wait for the thread."""
        self._done = True
        self._stop.set()
        self._thread.join()
        while True:                              # a frame rendered ahead that the loop never took
            try:
                self._frames.get_nowait()
            except queue.Empty:
                break

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
