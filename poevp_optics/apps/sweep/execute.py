"""Points on Dask (apps/sweep/sweep.py's docstring): where they run (`ClusterSettings`), the
client session (`DaskSession`), and `execute_points`, which submits points, runs a point again
whose worker died, holds back the points that wait for a shared render (reuse.py), writes each
point's folder as it comes back and hands its result to the caller (the sweep's table, the
search's trials)."""

from __future__ import annotations

import contextlib
import os
import uuid
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, NamedTuple

from poevp_optics.apps.sweep.bundle import InputPlan, InputRef, make_bundle, unpack_archive
from poevp_optics.apps.sweep.cluster import (ClusterError, check_workers, connect, dashboard_link, software_versions,
                                             worker_addresses)
from poevp_optics.apps.sweep.point import PointTask, one_line, run_point
from poevp_optics.core.io import MARKER, staged_dir
from poevp_optics.core.runtime import Terminated


@dataclass(frozen=True)
class ClusterSettings:
    """Where a sweep runs (cluster.py): an embedded LocalCluster of `workers` processes, or the
    scheduler at `scheduler` (tcp://HOST:PORT) or named by `scheduler_file`.

    shared_fs: the workers read the client's paths (verified) instead of a scene bundle; a
    LocalCluster always does. retries: how often a point whose worker died runs again
    elsewhere before it is a failed row. threads: DrJit/torch/OpenCV threads per point
    (default: cores // workers on a LocalCluster, 1 on a cluster). tls_ca_file, tls_cert,
    tls_key: PEM file paths for a tls:// scheduler (None: Dask's configuration); require_tls:
    refuse a plaintext scheduler (cluster.py `connect`)."""

    workers: int | None = None
    scheduler: str | None = None
    scheduler_file: str | None = None
    shared_fs: bool = False
    retries: int = 2
    threads: int | None = None
    tls_ca_file: str | None = None
    tls_cert: str | None = None
    tls_key: str | None = None
    require_tls: bool = False

    @property
    def local(self) -> bool:
        return not (self.scheduler or self.scheduler_file)


class SentBundle(NamedTuple):
    """A scene's bundle as sent to the workers: the (source, sha256) of the scene and asset
    files in it, the input plan carrying its hash, the Dask future of its bytes, the input refs
    it was made from, and the bytes (to send again should the workers holding them all leave)."""

    files: set
    plan: InputPlan
    future: object
    refs: list
    data: bytes


class DaskSession:
    """A sweep's (or search's) Dask client, connected on first use (cluster.py): an external
    scheduler before anything is written, a LocalCluster only when points remain to run. Holds
    the client's software versions, the threads per point and the scene bundle sent to the
    workers (`bundle_for`)."""

    def __init__(self, cl: ClusterSettings, n_points: int, log):
        self.cl, self.n_points, self.log = cl, n_points, log
        self.client = self.cluster = None
        self.versions: dict[str, str] = {}
        self.threads = 1
        self.workers_now = 0
        self._bundles: dict[str, SentBundle] = {}       # scene -> its bundle as sent
        self.bundle_sends = 0              # times a bundle was sent again after its holders were lost
        self.told_shared = False

    def open(self):
        if self.client is not None:
            return self.client
        cl = self.cl
        self.client, self.cluster = connect(scheduler=cl.scheduler, scheduler_file=cl.scheduler_file,
                                            workers=cl.workers, n_points=self.n_points,
                                            tls_ca_file=cl.tls_ca_file, tls_cert=cl.tls_cert,
                                            tls_key=cl.tls_key, require_tls=cl.require_tls)
        link = dashboard_link(self.client)
        if link:
            self.log(f"poevp sweep: Dask dashboard {link}")
        # only an external cluster's: a LocalCluster's workers are spawned from this interpreter
        # and its sys.path, the same software by construction (importing torch to say so: 2 s)
        if self.cluster is None:
            self.versions = software_versions()
            self.workers_now = check_workers(self.client, self.versions)
        if self.cluster is not None:
            self.threads = cl.threads or max(1, (os.cpu_count() or 1) // max(1, len(self.cluster.workers)))
        else:
            self.threads = cl.threads or 1
        return self.client

    def bundle_for(self, plan: InputPlan, refs: list[InputRef], log) -> tuple[InputPlan, object]:
        """(the plan with its bundle's hash, the Dask future of the bundle's bytes), or (plan,
        None) for a plan that reads the client's paths: one bundle per scene for every point so
        far, made again (and sent again) only when a point reads a file it lacks."""
        if plan.mode != "bundle":
            return plan, None
        names = {(r.source, r.sha256) for r in refs if r.kind in ("scene", "assets")}
        have = self._bundles.get(plan.scene)
        if have is not None and names <= have.files:
            return have.plan, have.future
        every = [*(have.refs if have else []), *refs]
        b = make_bundle(plan, every)
        plan = replace(plan, bundle_sha256=b.sha256)
        log(f"poevp sweep: {self.workers_now} workers now; scene bundle of {b.files} files, "
            f"{len(b.data) / 1e6:.2f} MB (sha256 {b.sha256[:12]}), sent to the workers once")
        fut = self.client.scatter(b.data, broadcast=True, hash=True)
        self._bundles[plan.scene] = SentBundle({(r.source, r.sha256) for r in every if r.kind in ("scene", "assets")},
                                               plan, fut, every, b.data)
        return plan, fut

    def bundle_lost(self, scene: str) -> bool:
        """Whether the scheduler no longer holds `scene`'s bundle: every worker that held it left
        (scattered data has no recipe to compute it again, so Dask forgets it and every point that
        needs it). False for a plan that reads the client's paths."""
        have = self._bundles.get(scene)
        if have is None:
            return False
        fut = have.future
        return fut.status != "finished" or not self.client.who_has([fut]).get(fut.key)

    def send_bundle_again(self, scene: str, log) -> tuple[InputPlan, object]:
        """`scene`'s bundle, the same bytes, sent under a new key (the lost one may still be known
        to this client) to the workers now present, once there is one; (plan, future) as
        `bundle_for`."""
        have = self._bundles[scene]
        self.bundle_sends += 1
        log("poevp sweep: the scene bundle was lost with every worker that held it; sending it again")
        if not worker_addresses(self.client):
            log("poevp sweep: no worker is left; waiting for one")
            self.client.wait_for_workers(1)
        fut = self.client.scatter(have.data, broadcast=True, hash=False)
        self._bundles[scene] = have._replace(future=fut)
        return have.plan, fut

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        self.client = self.cluster = None


@contextlib.contextmanager
def sigterm_noted():
    """core.runtime.sigterm_raises: SIGTERM raises Terminated and is noted in the yielded dict
    (`term`), which a sweep or search checks after every point (`stop_if_terminated`), so a
    SIGTERM that a library swallows (Dask's garbage-collection callback) still stops it."""
    from poevp_optics.core import runtime

    with runtime.sigterm_raises() as noted:
        yield noted


def stop_if_terminated(noted: dict | None) -> None:
    """Raise Terminated when `sigterm_noted` saw a SIGTERM."""
    if noted and noted.get("term"):
        from poevp_optics.core import runtime

        runtime.check_terminated()
        raise Terminated()


def write_point(folder: Path, archive: bytes, job: str) -> None:
    """A point's outputs, as its worker zipped them, into `folder`: staged, swapped in whole."""
    with staged_dir(folder, kind=job) as stage:
        unpack_archive(archive, stage, skip=(MARKER,))


#: How often a sweep sends a scene bundle again after the scheduler lost it with every worker
#: that held it, before it stops (each loss means the cluster lost every such worker at once).
MAX_BUNDLE_SENDS = 3
#: Why the scheduler cancels a task whose input it lost (distributed.scheduler: a submitted
#: task whose dependency it no longer knows; a waiting task whose dependency it forgot). A
#: restart or a lost connection cancels for other reasons, and stops the sweep.
LOST_INPUT_REASONS = ("lost dependencies", "already forgotten")


def lost_worker_errors() -> tuple[type, ...]:
    """What a future raises when the worker running it died or dropped off."""
    from distributed import KilledWorker
    from distributed.comm.core import CommClosedError

    return KilledWorker, CommClosedError


def _name(row: dict, folder: Path) -> str:
    return f"point {row['point']} seed {row['seed']}" if "point" in row and "seed" in row else f"point {folder.name}"


class PointSubmitter:
    """execute_points' submissions to Dask: each point with its scene's input plan and bundle,
    under a key of its own per send, remembering which bundle each send depends on."""

    def __init__(self, todo: list, job: str, plan_of: Callable, dask: DaskSession, reuse, log, resume_hint: str):
        self.job, self.plan_of, self.dask, self.reuse, self.log = job, plan_of, dask, reuse, log
        self.resume_hint = resume_hint
        self.client = dask.client
        self.plans: dict[str, tuple] = {}               # scene -> (plan with its bundle, bundle future)
        for t in todo:
            pl = plan_of(t)
            if pl.scene not in self.plans:
                refs = [r for u in todo if plan_of(u).scene == pl.scene for r in u[2]]
                self.plans[pl.scene] = dask.bundle_for(pl, refs, log)
        self.run_id = uuid.uuid4().hex[:8]
        self.sends = 0
        self.futs: dict = {}                            # future -> (row, overrides, refs, folder, attempt, bundle)

    def submit(self, row, ov, refs, attempt: int, folder: Path):
        """Send one point (its `attempt`-th retry); the Dask future."""
        t, reuse = (row, ov, refs, folder), self.reuse
        group = reuse.group_of(t) if reuse else ""
        pl, bundle = self.plans[self.plan_of(t).scene]
        task = PointTask(ov, self.job, self.dask.threads, pl, refs, self.dask.versions, group,
                         reuse.read_dirs() if group else (), folder.name, reuse.store_dir() if group else "")
        renders = reuse.payload(self.client, t) if group else []
        self.sends += 1
        f = self.client.submit(run_point, task, bundle, renders, pure=False,
                               key=f"poevp-point-{folder.name}-{self.run_id}-a{attempt}-s{self.sends}")
        self.futs[f] = (*t, attempt, bundle)
        return f

    def bundle_again(self, t, bundle, e) -> None:
        """A point `t` the scheduler cancelled: its scene's bundle is sent again if the scheduler
        lost it (unless it was sent again since `bundle`, the one `t` used), else ClusterError."""
        scene, dask, hint, reason = self.plan_of(t).scene, self.dask, self.resume_hint, getattr(e, "reason", None)
        lost_input = bundle is not None and reason in LOST_INPUT_REASONS
        if lost_input and bundle is not self.plans[scene][1]:
            return
        if not lost_input or not dask.bundle_lost(scene):
            why = f"Dask's reason: {reason}; " if reason and reason != "unknown" else ""
            raise ClusterError(f"the Dask scheduler cancelled the sweep's tasks ({why}it closed, restarted or lost "
                               f"this client); {hint}run the same command again to resume") from None
        if dask.bundle_sends >= MAX_BUNDLE_SENDS:
            raise ClusterError(f"the scene bundle was lost {dask.bundle_sends + 1} times with every worker that held "
                               f"it; {hint}run the same command again to resume") from None
        self.plans[scene] = dask.send_bundle_again(scene, self.log)


def execute_points(todo: list, job: str, plan: InputPlan | Callable, dask: DaskSession, *, on_result: Callable,
                   reuse=None, progress: bool = True, log=print, resume_hint: str = "") -> None:
    """Run `todo` [(row, overrides, input refs, point folder)] on Dask with the scene's input plan
    (`plan`, or `plan(task)` for points of several scenes): each point's folder is
    written as it comes back (ok points), then `on_result(task, result)` is called with
    run_point's result ({"row": ..., ...}; a point whose worker died `retries` times, or whose
    task could not run, is a failed row). reuse: the RenderReuse (reuse.py) that holds points
    back until their render is stored, or None. A worker that refuses (other software or
    files) stops everything with ClusterError; so does a scheduler that cancels the tasks
    (`resume_hint` says where the finished points are), unless it cancelled them because it lost
    the scene bundle with every worker that held it: then the bundle is sent again (at most
    MAX_BUNDLE_SENDS times) and those points run again, no retry spent."""
    from distributed import as_completed
    from distributed.client import CancelledError
    from tqdm import tqdm

    lost = lost_worker_errors()
    cl = dask.cl
    client = dask.open()
    if not cl.local and dask.workers_now == 0:
        log("poevp sweep: no worker has joined the scheduler yet; waiting for one")
        client.wait_for_workers(1)
    sender = PointSubmitter(todo, job, plan if callable(plan) else (lambda task: plan), dask, reuse, log, resume_hint)
    if any(pl.mode != "bundle" for pl, _ in sender.plans.values()) and not cl.local and not dask.told_shared:
        log(f"poevp sweep: {dask.workers_now} workers now; they read this machine's paths "
            "(--shared-fs), verified on each worker")
        dask.told_shared = True
    for row, ov, refs, folder in (reuse.initial(todo) if reuse else todo):
        sender.submit(row, ov, refs, 0, folder)
    bar = tqdm(total=len(todo), desc="sweep", unit="point", disable=not progress or None)
    pending = as_completed(list(sender.futs))
    for f in pending:
        row, ov, refs, folder, attempt, bundle = sender.futs.pop(f)
        try:
            res = f.result()
        except lost as e:
            if attempt < cl.retries:
                log(f"poevp sweep: {_name(row, folder)}: its worker was lost "
                    f"({type(e).__name__}); running it again (retry {attempt + 1} of {cl.retries})")
                pending.add(sender.submit(row, ov, refs, attempt + 1, folder))
                continue
            res = {"row": {"status": "failed", "error": f"worker lost {attempt + 1} times ({one_line(e)})"}}
        except CancelledError as e:
            sender.bundle_again((row, ov, refs, folder), bundle, e)
            pending.add(sender.submit(row, ov, refs, attempt, folder))   # it never ran: no retry spent
            continue
        except Exception as e:  # noqa: BLE001 - the task could not run at all
            res = {"row": {"status": "failed", "error": one_line(e)}}
        if res.get("refused"):
            client.cancel(list(sender.futs))
            raise ClusterError(res["refused"])
        if res.get("archive") is not None:
            write_point(folder, res["archive"], job)
        for t in reuse.finished((row, ov, refs, folder), res, client) if reuse else ():
            pending.add(sender.submit(*t[:3], 0, t[3]))
        on_result((row, ov, refs, folder), res)
        bar.update(1)
    bar.close()
