"""Shared fixtures: repository paths and small throw-away scenes."""

from __future__ import annotations

import os
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "scenes"

os.environ.setdefault("POEVP_CACHE_DIR", str(ROOT / "out" / ".test-cache"))


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
