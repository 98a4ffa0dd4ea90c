"""Shared fixtures: repository paths and small throw-away scenes."""

from __future__ import annotations

import os
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "scenes"

os.environ.setdefault("POEVP_CACHE_DIR", str(ROOT / "out" / ".test-cache"))

if os.environ.get("PYTEST_XDIST_WORKER"):
    # `make test` runs two workers on CI's two cores: each renders on one thread (DrJit, torch,
    # OpenCV) instead of on every core, so the two do not fight over both (the commands they
    # start still take every core, as a user's would).
    import torch  # noqa: F401 - loaded first, so that set_threads gives it one thread too

    from poevp_optics.core.runtime import set_threads

    set_threads(1)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Groups for `make test`'s two workers (pytest-xdist, `--dist loadgroup`): a test module runs
    on one worker, so its module fixtures are built once; the documentation's command blocks go by
    page instead (a page's blocks build on each other in one copy of the repository, and the pages
    are the suite's longest module). Before xdist's own hook, which reads the groups."""
    for item in items:
        if item.get_closest_marker("xdist_group") is None:
            block = getattr(getattr(item, "callspec", None), "params", {}).get("block")
            group = f"docs:{block.page}" if hasattr(block, "page") else item.nodeid.split("::")[0]
            item.add_marker(pytest.mark.xdist_group(group))


@pytest.fixture
def write_scene(tmp_path):
    """Write scene.toml (+ optional scene.xml) into a fresh folder; return the folder."""

    def _write(toml: str, xml: str | None = None, name: str = "scene") -> Path:
        d = tmp_path / name
        d.mkdir(parents=True, exist_ok=True)
        (d / "scene.toml").write_text(textwrap.dedent(toml))
        if xml is not None:
            (d / "scene.xml").write_text(textwrap.dedent(xml))
        return d

    return _write
