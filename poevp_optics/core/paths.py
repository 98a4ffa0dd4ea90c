"""Where the package's data lives: the repository's assets/ and scenes/ folders, and the shipped
predictor weights (read without importing torch: a run whose predictor needs none never loads it)."""

from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
ASSETS_DIR = REPO_ROOT / "assets"
SCENES_DIR = REPO_ROOT / "scenes"
PREDICTOR_WEIGHTS_DIR = ASSETS_DIR / "predictor"


def shipped_weights(name: str) -> Path:
    """The weights file shipped for predictor `name`: assets/predictor/NAME.safetensors."""
    return PREDICTOR_WEIGHTS_DIR / f"{name}.safetensors"
