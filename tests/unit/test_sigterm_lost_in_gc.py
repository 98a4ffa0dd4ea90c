"""core/runtime.sigterm_raises when the SIGTERM lands inside a garbage-collection callback (as
Dask registers one): Python drops an exception raised there (it goes to sys.unraisablehook), so
without help the command would run on. The signal is delivered again once the callback is
over, a safe point (`check_terminated`) raises, and a block that ends normally after a noted
SIGTERM raises at its end."""

from __future__ import annotations

import gc
import os
import signal
import time

import pytest

from poevp_optics.core import runtime


class _TermInGc:
    """A GC callback that sends this process SIGTERM once and runs bytecode meanwhile, so the
    handler's Terminated is raised (and dropped) inside the callback."""

    def __init__(self):
        self.armed = False                               # armed by the test, just before its collect

    def __call__(self, phase, info):
        if phase == "start" and self.armed:
            self.armed = False
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(200_000):                 # the handler runs at one of these bytecodes
                pass


@pytest.fixture
def term_in_gc():
    cb = _TermInGc()
    gc.callbacks.append(cb)
    yield cb
    gc.callbacks.remove(cb)


def test_a_sigterm_dropped_in_a_gc_callback_is_delivered_again(term_in_gc):
    steps = 0
    with pytest.raises(runtime.Terminated):
        with runtime.sigterm_raises():
            term_in_gc.armed = True
            gc.collect()                                # Terminated raised and dropped in the callback
            for steps in range(1, 1001):                # 10 s of work at most: the signal comes again
                time.sleep(0.01)
    # raised twice: once dropped inside the callback, once delivered again (at the collect's end
    # or in the loop); the block did not run to its end
    assert runtime._TERM["raised"] >= 2 and steps < 1000
    assert signal.getsignal(signal.SIGTERM) is not runtime._raise_terminated   # the handler is restored
    assert runtime._TERM["term"] is False and runtime._TERM["depth"] == 0


def test_a_noted_sigterm_stops_the_block_at_a_safe_point_or_its_end():
    with pytest.raises(runtime.Terminated):
        with runtime.sigterm_raises() as noted:
            noted["term"] = True                       # as the handler leaves it when its raise is lost
            runtime.check_terminated()
    with pytest.raises(runtime.Terminated):
        with runtime.sigterm_raises() as noted:
            noted["term"] = True                       # no safe point on the way: the block's end raises
    with runtime.sigterm_raises() as noted:            # a fresh block starts clean
        assert not noted["term"]
        runtime.check_terminated()
