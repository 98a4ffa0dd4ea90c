"""Trained weights on disk: safetensors files (never pickle) read with one-line errors that name
the file. Used by every network the package ships (control/predictors: DMVFN, track_net;
analysis/plate_ocr.py: the plate recogniser)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from poevp_optics.core.exceptions import UserError
from poevp_optics.core.paths import PREDICTOR_WEIGHTS_DIR


class WeightsError(UserError):
    """Missing, corrupted, non-finite or mismatched weights."""


def write_weights_file(path: Path, model, meta: dict, float_dtype=None) -> None:
    """`model`'s state (a torch module) to a safetensors file, written atomically, each `meta`
    value stored as JSON in the file's metadata; `float_dtype` (e.g. torch.float16): floating
    tensors stored in it (they load back into the float32 module)."""
    from safetensors.torch import save_file

    from poevp_optics.core.io import atomic_path

    md = {k: json.dumps(v) for k, v in meta.items()}
    state = {k: v.detach().contiguous() for k, v in model.state_dict().items()}
    if float_dtype is not None:
        state = {k: v.to(float_dtype) if v.is_floating_point() else v for k, v in state.items()}
    with atomic_path(Path(path)) as tmp:
        save_file(state, str(tmp), metadata=md)


def read_weights_file(path: Path, what: str, model: str | None = None,
                      framework: str = "pt") -> tuple[dict, dict]:
    """(tensors, metadata) of a safetensors file (never pickle); a one-line WeightsError naming
    the file when it is missing (`what` names the weights), unreadable, holds NaN or Inf, or
    (with `model`) its metadata's 'model' is another. framework "pt": torch tensors; "numpy":
    NumPy arrays, torch not imported (a network the loop runs in NumPy: track_net.py)."""
    from safetensors import SafetensorError, safe_open

    if framework == "pt":
        from safetensors.torch import load_file
    elif framework == "numpy":
        from safetensors.numpy import load_file
    else:
        raise ValueError(f"framework must be 'pt' or 'numpy', got {framework!r}")
    path = Path(path)
    if not path.is_file():
        raise WeightsError(f"{path}: {what} not found")
    try:
        with safe_open(str(path), framework="numpy") as f:
            meta = f.metadata() or {}
        tensors = load_file(str(path))
    except (SafetensorError, OSError, ValueError) as e:
        raise WeightsError(f"{path}: not a readable safetensors file ({e})") from None
    for key, t in tensors.items():
        bad, total = _non_finite(t)
        if bad:
            raise WeightsError(f"{path}: weights hold NaN or Inf ({bad} of {total} values of {key}): "
                               "a corrupted or diverged training run")
    if model is not None:
        try:
            found = json.loads(meta.get("model", "null"))
        except json.JSONDecodeError:
            found = None
        if found != model:
            raise WeightsError(f"{path}: not {what} (metadata 'model' is {meta.get('model')!r})")
    return tensors, meta


def _non_finite(t) -> tuple[int, int]:
    """(NaN and Inf values, all values) of a torch tensor or NumPy array (none in integers)."""
    if isinstance(t, np.ndarray):
        return (int((~np.isfinite(t)).sum()) if np.issubdtype(t.dtype, np.floating) else 0), int(t.size)
    import torch

    return (int((~torch.isfinite(t)).sum()) if t.is_floating_point() else 0), int(t.numel())


def weights_identity(path: Path | None) -> dict:
    """The weights file as the report names it: shipped weights relative to the assets folder
    (the same on every clone), others absolute; plus the first 16 hex of its SHA-256."""
    if path is None:
        return {"weights": None}
    path = Path(path).resolve()
    try:
        shown = f"assets/predictor/{path.relative_to(PREDICTOR_WEIGHTS_DIR.resolve())}"
    except ValueError:
        shown = str(path)
    return {"weights": shown, "weights_sha256": hashlib.sha256(path.read_bytes()).hexdigest()[:16]}


def load_state(model, tensors: dict, path: Path):
    """`model` with `tensors` loaded strictly, in eval mode; a one-line WeightsError on a mismatch."""
    try:
        model.load_state_dict(tensors, strict=True)
    except RuntimeError as e:
        first = str(e).strip().splitlines()[0]
        raise WeightsError(f"{path}: weights do not match the model: {first}") from None
    return model.eval()
