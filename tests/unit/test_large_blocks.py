"""runtime.keep_large_blocks: a freed large array's memory is reused, not mapped and faulted anew."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from ..conftest import ROOT

_FAULTS = """
import json, resource, sys
import numpy as np
from poevp_optics.core import runtime
kept = runtime.keep_large_blocks() if sys.argv[1] == "keep" else None
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
a = np.ones(8 << 20); del a                 # 64 MiB, over glibc's 32 MiB mmap ceiling
f0 = faults()
b = np.ones(8 << 20)
print(json.dumps({"kept": kept, "again": runtime.keep_large_blocks() if kept else None,
                  "faults": faults() - f0}))
"""


def _faults(mode: str) -> dict:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, "-c", _FAULTS, mode], env=env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_a_second_large_array_reuses_the_first_ones_pages():
    """By default the second 64 MiB array is a fresh mapping: the kernel faults in (and zeroes)
    at least one page per 2 MiB huge page of it, 32 at the fewest (544 measured with NumPy's
    huge-page advice, 16384 4-KiB pages without); with the blocks kept it lands in the freed
    heap block, already in memory: at most a handful of faults."""
    plain, kept = _faults("plain"), _faults("keep")
    assert kept["kept"] is True and kept["again"] is True
    assert plain["faults"] >= (64 << 20) // (2 << 20), plain
    assert kept["faults"] <= 4, kept
