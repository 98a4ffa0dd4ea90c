"""The Dask cluster a sweep runs on: connecting, the workers' software, the dashboard link.

* `connect`: an embedded `LocalCluster` (one process per core, `allowed_failures = 0` so that
  `--retries` alone bounds how often a point whose worker died runs again), or an existing
  scheduler by address (`--scheduler tcp://HOST:PORT`) or by the JSON file that
  `dask scheduler --scheduler-file`, `dask-jobqueue` and `dask-mpi` write (`--scheduler-file`).
  A `tls://` scheduler is reached with the CA, certificate and key of `--tls-ca-file`,
  `--tls-cert`, `--tls-key` (else Dask's `distributed.comm.tls.*`), checked before connecting;
  a plaintext address off this machine warns, and `--require-tls` / `POEVP_REQUIRE_TLS=1` /
  `distributed.comm.require-encryption` refuse it (tls.py). Under such a setting the
  LocalCluster talks TLS too, with a certificate held in memory.
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
import sys
import urllib.error
import urllib.request
from pathlib import Path

from poevp_optics.apps.sweep.tls import (ENCRYPTED_SCHEMES, IN_PROCESS_SCHEMES, TlsError, address_transport,
                                          check_tls_files, client_security, plaintext_warning,
                                          tls_connect_error, tls_required, tls_sources)
from poevp_optics.core.exceptions import UserError

#: Packages whose versions must match between client and workers.
PACKAGES = ("poevp_optics", "mitsuba", "drjit", "torch")


class ClusterError(UserError):
    """A cluster that cannot run this sweep: unreachable, other software, other files."""


def software_versions() -> dict[str, str]:
    """This process's versions of PACKAGES (runs on each worker)."""
    from poevp_optics import __version__
    from poevp_optics.core import runtime  # noqa: F401 - runtime first: it picks DrJit's libLLVM

    from importlib.metadata import version

    import drjit
    import mitsuba

    return {"poevp_optics": __version__, "mitsuba": mitsuba.__version__, "drjit": drjit.__version__,
            "torch": version("torch")}            # the installed package's; torch itself not imported


def version_mismatch(client: dict[str, str], worker: dict[str, str]) -> str | None:
    """The first package whose versions differ, as 'poevp_optics A there, B here', or None."""
    for pkg in PACKAGES:
        if client.get(pkg) != worker.get(pkg):
            return f"{pkg} {worker.get(pkg, 'missing')} there, {client.get(pkg, 'missing')} here"
    return None


def connect(*, scheduler: str | None = None, scheduler_file: str | os.PathLike | None = None,
            workers: int | None = None, n_points: int = 1, timeout_s: float = 30.0,
            tls_ca_file: str | None = None, tls_cert: str | None = None, tls_key: str | None = None,
            require_tls: bool = False, warn=None):
    """(client, local cluster or None). A local cluster has min(workers or cores, n_points)
    worker processes of one thread each. Unreachable schedulers raise ClusterError.

    tls_ca_file / tls_cert / tls_key: PEM files for a tls:// scheduler (else Dask's
    `distributed.comm.tls.*` configuration); require_tls: refuse plaintext (`require_tls`).
    Everything is checked before the first packet is sent: the address's transport (a
    non-loopback plaintext one warns through `warn`, default one line on stderr), the
    certificate files (`check_tls_files`)."""
    from distributed import Client, LocalCluster

    if scheduler and scheduler_file:
        raise ClusterError("--scheduler and --scheduler-file: give one of them")
    flags = {"--tls-ca-file": tls_ca_file, "--tls-cert": tls_cert, "--tls-key": tls_key}
    try:
        required = tls_required(require_tls)
    except TlsError as e:
        raise ClusterError(str(e)) from None
    if not (scheduler or scheduler_file):
        check_local_flags(tls_ca_file, tls_cert, tls_key)
        n = max(1, min(workers or os.cpu_count() or 1, n_points))
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                               silence_logs=40, scheduler_kwargs={"allowed_failures": 0},
                               **_local_security(required))
        return Client(cluster, security=cluster.security), cluster
    if scheduler_file:
        path = Path(scheduler_file)
        where = f"--scheduler-file {scheduler_file}"
        if not path.is_file():
            raise ClusterError(f"{where}: no such file (dask scheduler "
                               "--scheduler-file PATH writes it once the scheduler runs)")
        address = scheduler_file_address(path)
    else:
        where, address = f"--scheduler {scheduler}", scheduler
    sources, security = _scheduler_security(where, address, flags, required, warn)
    try:
        if scheduler_file:
            return Client(scheduler_file=str(path), timeout=timeout_s, security=security), None
        return Client(scheduler, timeout=timeout_s, security=security), None
    except (OSError, TimeoutError, ValueError) as e:
        tls_problem = tls_connect_error(e, where, sources) if security is not None else None
        if tls_problem:
            raise ClusterError(tls_problem) from None
        what = "cannot reach the scheduler it names" if scheduler_file else "cannot reach a Dask scheduler there"
        hint = ""
        if security is None and "reset by peer" in str(e):    # a TLS listener drops plaintext
            hint = "; a scheduler started with --tls-* flags listens at a tls:// address"
        raise ClusterError(f"{where}: {what} ({type(e).__name__}: {e}){hint}") from None


def check_local_flags(tls_ca_file: str | None, tls_cert: str | None, tls_key: str | None) -> None:
    """ClusterError for TLS files given to a sweep that runs a local cluster."""
    for flag, value in (("--tls-ca-file", tls_ca_file), ("--tls-cert", tls_cert), ("--tls-key", tls_key)):
        if value:
            raise ClusterError(f"{flag}: only with --scheduler or --scheduler-file (a local cluster runs "
                               "on this machine)")


def scheduler_file_address(path: Path) -> str:
    """The scheduler address a `--scheduler-file` JSON names (its "address" key)."""
    try:
        address = json.loads(path.read_text()).get("address")
    except (OSError, ValueError, AttributeError) as e:
        raise ClusterError(f"--scheduler-file {path}: not a Dask scheduler file ({type(e).__name__}: "
                           f"{e})") from None
    if not isinstance(address, str) or not address:
        raise ClusterError(f"--scheduler-file {path}: names no scheduler address (key \"address\")")
    return address


def _scheduler_security(where: str, address: str, flags: dict, required: str | None, warn):
    """(TLS sources, distributed.Security or None) for connecting to `address`, decided before
    any packet is sent (tls.py): a tls:// address needs a CA and a certificate (flags, else
    Dask's configuration), checked here; a plaintext one is refused when `required` names the
    setting that refuses it or when TLS flags were given, and warns when it leaves this machine."""
    try:
        scheme, _host = address_transport(address)
    except (ValueError, TypeError) as e:
        raise ClusterError(f"{where}: not a scheduler address (tls://HOST:PORT; {e})") from None
    try:
        if scheme in ENCRYPTED_SCHEMES:
            sources = tls_sources(*flags.values())
            if "--tls-ca-file" not in sources or "--tls-cert" not in sources:
                raise ClusterError(f"{where}: TLS needs --tls-ca-file and --tls-cert (and --tls-key unless "
                                   "the certificate file holds the key), or distributed.comm.tls.ca-file "
                                   "and distributed.comm.tls.client.cert in the Dask configuration")
            check_tls_files(sources)
            return sources, client_security(sources)
    except TlsError as e:
        raise ClusterError(str(e)) from None
    if scheme in IN_PROCESS_SCHEMES:
        return {}, None
    given = [f for f, v in flags.items() if v]
    if given:
        raise ClusterError(f"{where}: a plaintext address, but {given[0]} is given; the scheduler's TLS "
                           f"address is tls://HOST:PORT")
    if required:
        raise ClusterError(f"{where}: plaintext connection refused ({required}); connect to the "
                           "scheduler's tls:// address with --tls-ca-file, --tls-cert and --tls-key")
    line = plaintext_warning(where, address)
    if line:
        (warn or (lambda m: print(m, file=sys.stderr)))(line)
    return {}, None


def _local_security(required: str | None) -> dict:
    """LocalCluster keyword arguments: none, or under a setting that refuses plaintext
    (`tls_required`) TLS with a certificate made for this cluster alone and held in memory
    (`Security.temporary`, which needs the `cryptography` package)."""
    if not required:
        return {}
    from distributed import Security

    try:
        return {"security": Security.temporary(), "protocol": "tls://"}
    except ImportError:
        raise ClusterError(f"{required}: the local cluster would talk plaintext on this machine's "
                           "loopback, which its other users reach; TLS for it needs the cryptography "
                           "package (pip install cryptography), or give --scheduler tls://HOST:PORT") from None


def worker_addresses(client) -> list[str]:
    """The addresses of every worker in the cluster now (`n_workers=-1`: all of them, where some
    distributed releases list only the first 5 by default)."""
    return list(client.scheduler_info(n_workers=-1)["workers"])


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
