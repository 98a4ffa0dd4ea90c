"""Where the package's data lives: the repository's assets/ and scenes/ folders."""

from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
ASSETS_DIR = REPO_ROOT / "assets"
SCENES_DIR = REPO_ROOT / "scenes"
