"""The objective's on-disk cache of PSF grids and relative-illumination tables
($POEVP_CACHE_DIR/objective; core/cache.py's verified load-or-build: atomic writes, a checksum
file beside each, a damaged file rebuilt): the content key and the folder."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np

from poevp_optics.camera.objective.params import ObjectiveParams
from poevp_optics.core import spectra
from poevp_optics.core.cache import digest, json_digest
from poevp_optics.core.runtime import cache_dir as package_cache_dir

#: Bump when a change alters cached PSF grids or relative-illumination tables.
CACHE_VERSION = 2


def resolve_cache_dir(cache_dir) -> Path:
    """`cache_dir` when given, else the package cache's objective/ folder."""
    return Path(cache_dir) if cache_dir is not None else package_cache_dir("objective")


def _optiland_version() -> str:
    from importlib.metadata import version

    return version("optiland")


def cache_key(kind: str, params: ObjectiveParams, image_shape, keys) -> str:
    """SHA-256 of what shapes a cached object: its kind, the listed parameters, the image shape,
    CACHE_VERSION, optiland's version and the QE table's content."""
    p = asdict(params)
    qe = spectra.load_spectrum(params.qe, emissive=True)
    return json_digest({"kind": kind, "v": CACHE_VERSION, "optiland": _optiland_version(),
                        "shape": [int(image_shape[0]), int(image_shape[1])],
                        "params": {k: p[k] for k in keys},
                        "qe": digest(np.ascontiguousarray(qe).tobytes(), algo="sha256", length=64)},
                       algo="sha256", length=32, sort_keys=True)
