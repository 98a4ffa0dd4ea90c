"""Trained weights on disk: safetensors files (never pickle) read with one-line errors that name
the file. Used by every network the package ships (control/predictors: DMVFN, track_net;
analysis/plate_ocr.py: the plate recogniser)."""

from __future__ import annotations

import json
from pathlib import Path

from poevp_optics.core.exceptions import UserError


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


def read_weights_file(path: Path, what: str, model: str | None = None) -> tuple[dict, dict]:
    """(tensors, metadata) of a safetensors file (never pickle); a one-line WeightsError naming
    the file when it is missing (`what` names the weights), unreadable, holds NaN or Inf, or
    (with `model`) its metadata's 'model' is another."""
    import torch
    from safetensors import SafetensorError, safe_open
    from safetensors.torch import load_file

    path = Path(path)
    if not path.is_file():
        raise WeightsError(f"{path}: {what} not found")
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = f.metadata() or {}
        tensors = load_file(str(path))
    except (SafetensorError, OSError, ValueError) as e:
        raise WeightsError(f"{path}: not a readable safetensors file ({e})") from None
    for key, t in tensors.items():
        if t.is_floating_point() and not bool(torch.isfinite(t).all()):
            n = int((~torch.isfinite(t)).sum())
            raise WeightsError(f"{path}: weights hold NaN or Inf ({n} of {t.numel()} values of {key}): "
                               "a corrupted or diverged training run")
    if model is not None:
        try:
            found = json.loads(meta.get("model", "null"))
        except json.JSONDecodeError:
            found = None
        if found != model:
            raise WeightsError(f"{path}: not {what} (metadata 'model' is {meta.get('model')!r})")
    return tensors, meta


def load_state(model, tensors: dict, path: Path):
    """`model` with `tensors` loaded strictly, in eval mode; a one-line WeightsError on a mismatch."""
    try:
        model.load_state_dict(tensors, strict=True)
    except RuntimeError as e:
        first = str(e).strip().splitlines()[0]
        raise WeightsError(f"{path}: weights do not match the model: {first}") from None
    return model.eval()
