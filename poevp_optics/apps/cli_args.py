"""argparse types and option groups shared by `poevp`'s commands (cli.py and the commands' own
flag modules, apps/evaluate/evaluate_cli.py and apps/train/train_cli.py): integers with bounds that fail in one
line, the thread and seed limits, the Dask cluster options."""

from __future__ import annotations

import argparse
import os

from poevp_optics.core import runtime


def int_at_least(low: int):
    """An argparse type: an integer >= low, else a one-line argument error."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < low:
            raise argparse.ArgumentTypeError(f"expected an integer >= {low}, got {text!r}")
        return value
    return parse


positive_int = int_at_least(1)
count_arg = int_at_least(0)


def seeds_arg(text: str) -> int:
    """--seeds: 1 to apps/run/run_size.MAX_SEEDS."""
    from poevp_optics.apps.run.run_size import MAX_SEEDS

    n = positive_int(text)
    if n > MAX_SEEDS:
        raise argparse.ArgumentTypeError(f"{n} seeds is above the limit {MAX_SEEDS} per point")
    return n


def threads_arg(text: str) -> int:
    """--threads: 1 to runtime.max_threads()."""
    n = positive_int(text)
    if n > runtime.max_threads():
        raise argparse.ArgumentTypeError(f"{n} threads is above the limit {runtime.max_threads()} "
                                         f"(8 per core, at least 64; this machine has {os.cpu_count()} cores)")
    return n


def tls_options(args) -> dict:
    """The TLS flags of `add_cluster_options` as keyword arguments (apps/sweep/sweep.py
    `sweep`, ClusterSettings)."""
    return {"tls_ca_file": args.tls_ca_file, "tls_cert": args.tls_cert, "tls_key": args.tls_key,
            "require_tls": args.require_tls}


def add_cluster_options(p) -> None:
    """`poevp sweep` on an existing Dask cluster (apps/sweep/cluster.py, apps/sweep/bundle.py)."""
    where = p.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="tls://HOST:PORT (or tcp:// on a trusted network) of an existing Dask scheduler")
    where.add_argument("--scheduler-file", metavar="PATH",
                       help="JSON file naming an existing Dask scheduler (as `dask scheduler "
                            "--scheduler-file` and dask-jobqueue write)")
    p.add_argument("--shared-fs", action="store_true",
                   help="workers read this machine's paths (a shared file system; verified on each "
                        "worker) instead of receiving the scene bundle")
    tls = p.add_argument_group("TLS to the scheduler (default: Dask's distributed.comm.tls configuration)")
    tls.add_argument("--tls-ca-file", metavar="PEM", help="CA certificate that signed the scheduler's and "
                     "workers' certificates")
    tls.add_argument("--tls-cert", metavar="PEM", help="this client's certificate, signed by that CA")
    tls.add_argument("--tls-key", metavar="PEM", help="this client's private key (unless --tls-cert holds it)")
    tls.add_argument("--require-tls", "--require-encryption", dest="require_tls", action="store_true",
                     help="refuse a plaintext (tcp://) scheduler; also POEVP_REQUIRE_TLS=1 or Dask's "
                          "distributed.comm.require-encryption")
    p.add_argument("--retries", type=count_arg, default=2, metavar="N",
                   help="run a point whose worker died again up to N times before it is a failed row "
                        "(default 2)")
