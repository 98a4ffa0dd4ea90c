"""`make test`'s two workers keep each test module, and each documentation page's commands, on
one worker (tests/conftest.py and pytest-xdist's `--dist loadgroup`). Without that grouping the
suite still passes but runs each module's fixtures, and each page's earlier commands, on both
workers: half as long again on the 2-core machine (pytest 9.2 with pytest-xdist 3.8 lost it
without a word, pytest-xdist issue #1386)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

MODULE = textwrap.dedent("""
    import os, time
    from pathlib import Path
    import pytest

    class Page:
        def __init__(self, page, line):
            self.page, self.line = page, line

    BLOCKS = [Page(p, k) for p in ("a.md", "b.md") for k in range(3)]

    def _record(name):
        time.sleep(0.3)                       # long enough that both workers take work
        out = Path(os.environ["GROUPS_OUT"]) / f"{name}.{os.getpid()}"
        out.write_text(os.environ.get("PYTEST_XDIST_WORKER", "none"))

    @pytest.mark.parametrize("i", range(4))
    def test_plain(i):
        _record(f"{__name__}-plain-{i}")

    @pytest.mark.parametrize("block", BLOCKS, ids=[f"{b.page}:{b.line}" for b in BLOCKS])
    def test_doc_block(block):
        _record(f"{__name__}-{block.page}-{block.line}")
""")


def test_modules_and_pages_stay_on_one_worker(tmp_path):
    pytest_ini = "[pytest]\nmarkers =\n    xdist_group(name): grouped\n"
    (tmp_path / "pytest.ini").write_text(pytest_ini)
    shutil.copy(ROOT / "tests" / "conftest.py", tmp_path / "conftest.py")
    for name in ("test_one", "test_two"):
        (tmp_path / f"{name}.py").write_text(MODULE)
    out = tmp_path / "out"
    out.mkdir()
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "2", "--dist", "loadgroup", "-p",
                        "no:cacheprovider", str(tmp_path)], cwd=tmp_path, capture_output=True, text=True,
                       env={**os.environ, "GROUPS_OUT": str(out)}, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    ran: dict[str, set[str]] = {}
    for f in out.iterdir():
        module, group = f.name.split("-")[:2]
        key = module if group == "plain" else group     # plain tests by module, doc blocks by page
        ran.setdefault(key, set()).add(f.read_text())
    assert len(list(out.iterdir())) == 2 * (4 + 6)
    assert set(ran) == {"test_one", "test_two", "a.md", "b.md"}
    split = {k: sorted(v) for k, v in ran.items() if len(v) != 1}
    assert not split, f"groups run on more than one worker: {split}"
    assert set().union(*ran.values()) == {"gw0", "gw1"}
