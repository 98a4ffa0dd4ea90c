"""File output and input: OpenEXR (float32) and PNG, always written atomically.

Every writer puts the bytes in a temporary file in the destination folder and renames it into
place (`os.replace`, atomic on POSIX), so a crash never leaves a truncated file. `staged_dir`
does the same for a whole output folder: a run writes into a sibling staging folder which
replaces the old folder only when the run succeeded.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator, Mapping

import cv2
import numpy as np
import OpenEXR


def _tmp_path(path: Path) -> Path:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=path.parent)
    os.close(fd)
    return Path(tmp)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path`; rename it onto `path` if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _tmp_path(path)
    try:
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_json(path: str | os.PathLike, obj) -> None:
    """Write `obj` as indented JSON, atomically. NaN/Inf are refused (not valid JSON)."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, allow_nan=False) + "\n")


def write_exr(path: str | os.PathLike, channels: Mapping[str, np.ndarray],
              attributes: Mapping[str, str] | None = None) -> None:
    """Write float32 channels (each (H, W)) to a ZIP-compressed scanline OpenEXR file.

    Float32, not Mitsuba's float16 default: half floats overflow to inf above 65504 (FACTS.md).
    `attributes` are string header entries (units, quantity, provenance).
    """
    chans = {}
    shape = None
    for name, arr in channels.items():
        a = np.ascontiguousarray(arr, dtype=np.float32)
        if a.ndim != 2:
            raise ValueError(f"EXR channel {name!r} must be 2-D, got shape {a.shape}")
        if shape is not None and a.shape != shape:
            raise ValueError(f"EXR channel {name!r} has shape {a.shape}, expected {shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"EXR channel {name!r} for {path} contains NaN or Inf")
        shape = a.shape
        chans[name] = a
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for k, v in (attributes or {}).items():
        header[k] = str(v)
    with atomic_path(path) as tmp:
        with OpenEXR.File(header, chans) as f:
            f.write(str(tmp))


def read_exr(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """Read an OpenEXR file: (channels by name as float32 arrays, header dict)."""
    with OpenEXR.File(str(path), separate_channels=True) as f:
        part = f.parts[0]
        chans = {name: np.array(c.pixels, dtype=np.float32) for name, c in part.channels.items()}
        return chans, dict(part.header)


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write a uint8 or uint16 image ((H, W) grey or (H, W, 3) RGB) as PNG, atomically."""
    img = np.asarray(image)
    if img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"PNG data for {path} must be uint8 or uint16, got {img.dtype}")
    if img.ndim == 3:
        img = img[..., ::-1]  # OpenCV writes BGR
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), img):
            raise OSError(f"could not write PNG {path}")


def read_png(path: str | os.PathLike) -> np.ndarray:
    """Read a PNG as stored (8 or 16 bit); colour images come back RGB."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise OSError(f"could not read image {path}")
    if img.ndim == 3:
        img = img[..., ::-1].copy()
    return img


@contextlib.contextmanager
def staged_dir(out_dir: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty staging folder; on success it replaces `out_dir` whole.

    On failure the staging folder is removed and an existing `out_dir` is left untouched, so
    an output folder is never half-overwritten.
    """
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.staging-", dir=out_dir.parent))
    try:
        yield stage
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    old = None
    if out_dir.exists():
        old = out_dir.parent / f".{out_dir.name}.old-{os.getpid()}"
        os.replace(out_dir, old)
    os.replace(stage, out_dir)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
