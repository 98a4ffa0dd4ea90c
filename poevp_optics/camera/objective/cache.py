"""The objective's on-disk cache of PSF grids and relative-illumination tables
($POEVP_CACHE_DIR/objective, core.runtime.cache_dir): content keys and atomic writes."""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import asdict
from pathlib import Path

import numpy as np

from poevp_optics.camera.objective.params import ObjectiveParams
from poevp_optics.core import spectra

#: Bump when a change alters cached PSF grids or relative-illumination tables.
CACHE_VERSION = 2

def resolve_cache_dir(cache_dir) -> Path:
    from poevp_optics.core.runtime import cache_dir as package_cache_dir

    return Path(cache_dir) if cache_dir is not None else package_cache_dir("objective")


def _optiland_version() -> str:
    from importlib.metadata import version

    return version("optiland")


def cache_key(kind: str, params: ObjectiveParams, image_shape, keys) -> str:
    """SHA-256 of what shapes a cached object: its kind, the listed parameters, the image shape,
    CACHE_VERSION, optiland's version and the QE table's content."""
    p = asdict(params)
    qe = spectra.load_spectrum(params.qe, emissive=True)
    blob = json.dumps({"kind": kind, "v": CACHE_VERSION, "optiland": _optiland_version(),
                       "shape": [int(image_shape[0]), int(image_shape[1])],
                       "params": {k: p[k] for k in keys},
                       "qe": hashlib.sha256(np.ascontiguousarray(qe).tobytes()).hexdigest()},
                      sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:32]


def atomic_savez(path: Path, **arrays):
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
