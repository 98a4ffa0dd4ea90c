"""The Dask cluster a sweep runs on: connecting, the workers' software, the dashboard link.

* `connect`: an embedded `LocalCluster` (one process per core, `allowed_failures = 0` so that
  `--retries` alone bounds how often a point whose worker died runs again), or an existing
  scheduler by address (`--scheduler tcp://HOST:PORT`) or by the JSON file that
  `dask scheduler --scheduler-file`, `dask-jobqueue` and `dask-mpi` write (`--scheduler-file`).
* `check_workers`: every connected worker runs `software_versions` and must report the
  client's versions of the packages in `PACKAGES`; a mismatch is one line naming the worker,
  the package and both versions. Each point checks again on its worker (workers that join
  later, e.g. under dask-jobqueue's adaptive scaling). The versions are the modules'
  `__version__`, not Dask's `get_versions`, which reads installed distribution metadata
  (importlib.metadata) and so misses a source tree on PYTHONPATH or an edited editable install.
* `dashboard_link`: the link only when the scheduler serves the dashboard. A scheduler started
  with `--no-dashboard` still advertises its HTTP port as `services["dashboard"]` (health and
  metrics only; `/status` is 404), so the scheduler is asked which plots it serves before the
  link is printed.
"""

from __future__ import annotations

import json
import os
import urllib.error
import urllib.request
from pathlib import Path

from poevp_optics.core.exceptions import UserError

#: Packages whose versions must match between client and workers.
PACKAGES = ("poevp_optics", "mitsuba", "drjit", "torch")


class ClusterError(UserError):
    """A cluster that cannot run this sweep: unreachable, other software, other files."""


def software_versions() -> dict[str, str]:
    """This process's versions of PACKAGES (runs on each worker)."""
    from poevp_optics import __version__
    from poevp_optics.core import runtime  # noqa: F401 - runtime first: it picks DrJit's libLLVM

    import drjit
    import mitsuba
    import torch

    return {"poevp_optics": __version__, "mitsuba": mitsuba.__version__, "drjit": drjit.__version__,
            "torch": torch.__version__}


def version_mismatch(client: dict[str, str], worker: dict[str, str]) -> str | None:
    """The first package whose versions differ, as 'poevp_optics A there, B here', or None."""
    for pkg in PACKAGES:
        if client.get(pkg) != worker.get(pkg):
            return f"{pkg} {worker.get(pkg, 'missing')} there, {client.get(pkg, 'missing')} here"
    return None


def connect(*, scheduler: str | None = None, scheduler_file: str | os.PathLike | None = None,
            workers: int | None = None, n_points: int = 1, timeout_s: float = 30.0):
    """(client, local cluster or None). A local cluster has min(workers or cores, n_points)
    worker processes of one thread each. Unreachable schedulers raise ClusterError."""
    from dask.distributed import Client, LocalCluster

    if scheduler and scheduler_file:
        raise ClusterError("--scheduler and --scheduler-file: give one of them")
    if scheduler_file:
        path = Path(scheduler_file)
        if not path.is_file():
            raise ClusterError(f"--scheduler-file {scheduler_file}: no such file (dask scheduler "
                               "--scheduler-file PATH writes it once the scheduler runs)")
        try:
            return Client(scheduler_file=str(path), timeout=timeout_s), None
        except (OSError, TimeoutError, ValueError) as e:
            raise ClusterError(f"--scheduler-file {scheduler_file}: cannot reach the scheduler it names "
                               f"({type(e).__name__}: {e})") from None
    if scheduler:
        try:
            return Client(scheduler, timeout=timeout_s), None
        except (OSError, TimeoutError, ValueError) as e:
            raise ClusterError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there "
                               f"({type(e).__name__}: {e})") from None
    n = max(1, min(workers or os.cpu_count() or 1, n_points))
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                           silence_logs=40, scheduler_kwargs={"allowed_failures": 0})
    return Client(cluster), cluster


def check_workers(client, versions: dict[str, str]) -> int:
    """Every worker connected now runs the client's software; returns how many there are.
    Raises ClusterError naming the first worker that differs (or cannot answer)."""
    answers = client.run(software_versions, on_error="return")
    for addr in sorted(answers):
        got = answers[addr]
        if isinstance(got, BaseException):
            raise ClusterError(f"worker {addr}: cannot report its software ({type(got).__name__}: "
                               f"{' '.join(str(got).split())}); install the same poevp_optics on every worker")
        problem = version_mismatch(versions, got)
        if problem:
            raise ClusterError(f"worker {addr}: {problem}; install the same software on every worker")
    return len(answers)


def dashboard_link(client, timeout_s: float = 5.0) -> str | None:
    """The scheduler's dashboard URL when it serves one (and this machine reaches it), else None.

    Asks the scheduler's `individual-plots.json` (distributed/http/scheduler/info.py: the Bokeh
    plots it serves, `{}` without a dashboard; ~20 ms) rather than the `/status` page, whose
    Bokeh document takes ~2 s to build on a loaded machine; the page itself only when that route
    is switched off (`distributed.scheduler.http.routes`)."""
    try:
        link = client.dashboard_link
    except (KeyError, AttributeError, OSError):
        return None
    if not link:
        return None
    try:
        with urllib.request.urlopen(link.rsplit("/", 1)[0] + "/individual-plots.json", timeout=timeout_s) as r:
            plots = json.load(r)
        return link if any(not str(v).startswith("/statics/") for v in plots.values()) else None
    except urllib.error.HTTPError:
        pass
    except (urllib.error.URLError, OSError, ValueError, AttributeError):
        return None
    try:
        with urllib.request.urlopen(link, timeout=timeout_s) as r:
            return link if r.status == 200 else None
    except (urllib.error.URLError, OSError, ValueError):
        return None
