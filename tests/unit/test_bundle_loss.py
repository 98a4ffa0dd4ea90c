"""What a sweep does when the Dask scheduler cancels a point (apps/sweep/execute.py
`PointSubmitter.bundle_again`): a scene bundle the scheduler lost with every worker that held it
is sent again, once per loss and at most MAX_BUNDLE_SENDS times; any other cancellation stops the
sweep with one line that gives Dask's reason and where the finished points are.

The client here is a stand-in that answers as a scheduler would (who holds a key, which workers
there are, a scatter); tests/regression/test_sweep_cluster.py loses a bundle on a real cluster.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from distributed.client import FutureCancelledError

from poevp_optics.apps.sweep.cluster import ClusterError
from poevp_optics.apps.sweep.execute import MAX_BUNDLE_SENDS, ClusterSettings, DaskSession, PointSubmitter, SentBundle

SCENE = "/scenes/road/scene.toml"
HINT = "the finished points are in out/results.parquet: "


class Held:
    """A Dask future's client side: its key and status ("finished", "lost", "cancelled")."""

    def __init__(self, key: str, status: str = "finished"):
        self.key, self.status = key, status


class Scheduler:
    """The client calls the sweep makes on this path, answered from `holders` {key: [workers]}."""

    def __init__(self, workers=("tcp://w1",)):
        self.holders: dict[str, list[str]] = {}
        self.workers = list(workers)
        self.scattered: list[bytes] = []
        self.waited = 0

    def who_has(self, futures):
        return {f.key: self.holders.get(f.key, []) for f in futures}

    def scheduler_info(self, n_workers=-1):
        return {"workers": {w: {} for w in self.workers}}

    def wait_for_workers(self, n):
        self.waited += 1
        self.workers = ["tcp://w9"]

    def scatter(self, data, broadcast=False, hash=True):
        assert broadcast and not hash            # a new key, on every worker there is
        self.scattered.append(data)
        fut = Held(f"bytes-sent-{len(self.scattered)}")
        self.holders[fut.key] = list(self.workers)
        return fut


def _sender(scheduler: Scheduler, bundle: Held | None):
    """A PointSubmitter of one scene whose bundle (b"zip") is `bundle`, and the lines it logs."""
    lines: list[str] = []
    dask = DaskSession(ClusterSettings(scheduler="tcp://s:8786"), 4, lines.append)
    dask.client = scheduler
    plan = object()
    if bundle is not None:
        dask._bundles[SCENE] = SentBundle(set(), plan, bundle, [], b"zip")
        scheduler.holders[bundle.key] = ["tcp://w1"]
    sender = PointSubmitter([], "render", lambda t: type("Plan", (), {"scene": SCENE})(), dask, None,
                            lines.append, HINT)
    sender.plans[SCENE] = (plan, bundle)
    return sender, dask, lines


def _cancelled(reason: str | None) -> FutureCancelledError:
    return FutureCancelledError("poevp-point-x", reason)


TASK = ({"point": 0, "seed": 0}, (), [], Path("points/x-s0"))


@pytest.mark.parametrize("reason", ["lost dependencies", "already forgotten"])
def test_a_bundle_lost_with_its_workers_is_sent_once_per_loss(reason):
    sch = Scheduler()
    first = Held("bytes-c916")
    sender, dask, lines = _sender(sch, first)
    sch.holders[first.key] = []                  # its only worker died
    first.status = "lost"
    sender.bundle_again(TASK, first, _cancelled(reason))
    assert sch.scattered == [b"zip"] and dask.bundle_sends == 1
    assert lines == ["poevp sweep: the scene bundle was lost with every worker that held it; sending it again"]
    new = sender.plans[SCENE][1]
    assert new is not first and sch.holders[new.key] == ["tcp://w1"]
    # the other points that depended on the lost bundle: run again on the new one, nothing sent
    sender.bundle_again(TASK, first, _cancelled(reason))
    assert sch.scattered == [b"zip"] and dask.bundle_sends == 1


def test_with_no_worker_left_the_bundle_waits_for_one():
    sch = Scheduler(workers=())
    first = Held("bytes-c916", "lost")
    sender, dask, lines = _sender(sch, first)
    sch.holders[first.key] = []
    sender.bundle_again(TASK, first, _cancelled("lost dependencies"))
    assert sch.waited == 1 and lines[-1] == "poevp sweep: no worker is left; waiting for one"
    assert sch.holders[sender.plans[SCENE][1].key] == ["tcp://w9"]


def test_a_lost_input_reason_with_the_bundle_still_held_stops_the_sweep():
    """The scheduler still holds the bundle (status finished, a worker has it): the cancellation
    has another cause, and sending the bundle again would not help."""
    sch = Scheduler()
    first = Held("bytes-c916")
    sender, dask, _ = _sender(sch, first)
    with pytest.raises(ClusterError) as e:
        sender.bundle_again(TASK, first, _cancelled("already forgotten"))
    assert str(e.value) == ("the Dask scheduler cancelled the sweep's tasks (Dask's reason: already forgotten; it "
                            "closed, restarted or lost this client); the finished points are in "
                            "out/results.parquet: run the same command again to resume")
    assert sch.scattered == []


@pytest.mark.parametrize("reason", ["scheduler-restart", "scheduler-connection-lost", None])
def test_a_restart_or_a_lost_connection_stops_the_sweep_with_dasks_reason(reason):
    sch = Scheduler()
    first = Held("bytes-c916", "cancelled")     # a restart cancels every future, the bundle's too
    sender, dask, _ = _sender(sch, first)
    sch.holders[first.key] = []
    with pytest.raises(ClusterError) as e:
        sender.bundle_again(TASK, first, _cancelled(reason))
    why = f"Dask's reason: {reason}; " if reason else ""
    assert str(e.value).startswith(f"the Dask scheduler cancelled the sweep's tasks ({why}it closed, restarted")
    assert sch.scattered == [] and dask.bundle_sends == 0


def test_a_plan_without_a_bundle_stops_the_sweep():
    """Workers that read the client's paths (--shared-fs) need no bundle: nothing to send again."""
    sch = Scheduler()
    sender, dask, _ = _sender(sch, None)
    with pytest.raises(ClusterError, match=r"cancelled the sweep's tasks \(Dask's reason: lost dependencies; "):
        sender.bundle_again(TASK, None, _cancelled("lost dependencies"))


def test_the_bundle_is_sent_again_at_most_max_bundle_sends_times():
    sch = Scheduler()
    first = Held("bytes-c916", "lost")
    sender, dask, lines = _sender(sch, first)
    sch.holders[first.key] = []
    used = first
    for _ in range(MAX_BUNDLE_SENDS):
        sender.bundle_again(TASK, used, _cancelled("lost dependencies"))
        used = sender.plans[SCENE][1]
        sch.holders[used.key] = []              # lost again with its workers
    assert len(sch.scattered) == MAX_BUNDLE_SENDS == dask.bundle_sends
    with pytest.raises(ClusterError) as e:
        sender.bundle_again(TASK, used, _cancelled("lost dependencies"))
    assert str(e.value) == (f"the scene bundle was lost {MAX_BUNDLE_SENDS + 1} times with every worker that held "
                            "it; the finished points are in out/results.parquet: run the same command again to "
                            "resume")
    assert len(sch.scattered) == MAX_BUNDLE_SENDS
