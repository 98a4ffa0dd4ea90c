"""Trained weights on disk: safetensors files (never pickle) read with one-line errors that name
the file. Used by every network the package ships (control/predictors: DMVFN, track_net;
analysis/plate_ocr.py: the plate recogniser)."""

from __future__ import annotations

from pathlib import Path

from poevp_optics.core.exceptions import UserError


class WeightsError(UserError):
    """Missing, corrupted, non-finite or mismatched weights."""


def read_weights_file(path: Path, what: str) -> tuple[dict, dict]:
    """(tensors, metadata) of a safetensors file (never pickle); a one-line WeightsError naming
    the file when it is missing (`what` names the weights), unreadable, or holds NaN or Inf."""
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
    return tensors, meta


def load_state(model, tensors: dict, path: Path):
    """`model` with `tensors` loaded strictly, in eval mode; a one-line WeightsError on a mismatch."""
    try:
        model.load_state_dict(tensors, strict=True)
    except RuntimeError as e:
        first = str(e).strip().splitlines()[0]
        raise WeightsError(f"{path}: weights do not match the model: {first}") from None
    return model.eval()
