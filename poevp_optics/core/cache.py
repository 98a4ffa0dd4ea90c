"""Content-keyed caches on disk (DESIGN.md: core/cache): one key function, one folder rule and one
load-or-build path for the package's caches:

| cache (folder under the cache root)     | key recipe                                   | user |
|-----------------------------------------|----------------------------------------------|------|
| objective/psf-*.npz, objective/ri-*.npz | SHA-256 of sorted JSON (params, shape, versions, QE table) | camera/objective/cache.py |
| meshes/car_rear_*.ply                   | SHA-1 of the mesh's bytes and MESH_VERSION    | sources/road.py |
| plates/plate_*.png                      | SHA-1 of "text|width|height|v1"               | sources/plates.py |
| predictor_data/seq_*.npz                | SHA-1 of JSON (sequences, frames, seed, size)  | apps/train/training_data.py |
| eval/*.npz                              | SHA-1 of JSON (scene files' hashes, sequence, poses, settings) | apps/evaluate/eval_sequences.py |

The cache root is $POEVP_CACHE_DIR, else ~/.cache/poevp_optics (core.runtime.cache_dir). Each
user keeps its own recipe (the bytes hashed are what they were, so cache files written before
stay valid); a key that misses a parameter shaping the content is a stale-result bug, so each
recipe lists everything its content depends on, with a version to bump.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Callable, TypeVar

from poevp_optics.core.runtime import cache_dir

T = TypeVar("T")


def digest(data: bytes | str, *, algo: str = "sha1", length: int = 16) -> str:
    """Hex digest of `data` (str: UTF-8), cut to `length` characters (16 hex = 64 bits)."""
    raw = data.encode() if isinstance(data, str) else bytes(data)
    return hashlib.new(algo, raw).hexdigest()[:length]


def json_digest(obj, *, algo: str = "sha1", length: int = 16, **dumps) -> str:
    """`digest` of json.dumps(obj, **dumps) (e.g. sort_keys=True, default=str)."""
    return digest(json.dumps(obj, **dumps), algo=algo, length=length)


def cache_file(kind: str, name: str) -> Path:
    """Path of the cache file `name` in the folder `kind` under the cache root (not created)."""
    return cache_dir(kind) / name


def cached(path: Path, build: Callable[[], T], *, load: Callable[[Path], T],
           save: Callable[[Path, T], None], unreadable: tuple[type[BaseException], ...] = ()) -> T:
    """`load(path)` when the file exists, else `build()`, written with `save(tmp, value)` to a
    temporary file renamed onto `path` (core.io.atomic_path: a killed run leaves no partial
    file). A load raising one of `unreadable` removes the file and rebuilds it."""
    path = Path(path)
    if path.is_file():
        try:
            return load(path)
        except unreadable:
            path.unlink(missing_ok=True)
    value = build()
    from poevp_optics.core.io import atomic_path          # cv2 / OpenEXR: only when writing

    with atomic_path(path) as tmp:
        save(tmp, value)
    return value
