"""Content-keyed caches on disk (DESIGN.md: core/cache): one key function, one folder rule and one
verified load-or-build path for the package's caches:

| cache (folder under the cache root) | key recipe | checked on load, after the checksum | user |
|-------------------------------------|------------|-------------------------------------|------|
| objective/psf-*.npz | SHA-256 of sorted JSON (params, shape, versions, QE table) | name, image shape, node positions; odd square, finite, unit-sum kernels | camera/objective/psfs.py |
| objective/ri-*.npz | the same recipe | angles 0 .. the image's corner field, rising; RI finite, > 0, 1 on axis | camera/objective/vignetting.py |
| meshes/car_rear_*.ply | SHA-1 of the mesh's bytes and MESH_VERSION | PLY header and counts, every vertex and face | sources/road.py |
| retro/tail-*.npz | SHA-256 of JSON (the sheeting table's angles, R_A and efficiency; the tail's constants; TAIL_CACHE_VERSION) | sigma in (0, TAIL_SIGMA_MAX_DEG]; PROPOSAL_ROWS eta values, finite, >= 0 | render/materials/retroreflective.py |
| plates/plate_*.png | SHA-1 of text, width, height, format, band, the font file's SHA-256 (16 hex) and "v2", bar-separated | decodes to the plate's size and pixels | sources/plates.py |
| predictor_data/seq_*.npz | SHA-1 of JSON (sequences, frames, seed, size) | frames uint8 (sequences, frames, H, W) | apps/train/training_data.py |
| eval/*.npz | SHA-1 of JSON (sequence, node times, poses, shutter; the render's fingerprint: resolved scene, hashes of the files it reads, plate font, render code, versions, backend, guard band) | mean, var (frames, nodes, H, W) finite, var >= 0; roi boxes | apps/evaluate/eval_sequences.py |
| train_data/<scene>-<hash>/ | SHA-256 of the scene's files and the settings | manifest's hash; each split's frames, boxes, draws | apps/train/train_data.py |

The cache root is $POEVP_CACHE_DIR, else ~/.cache/poevp_optics (core.runtime.cache_dir). Each
user keeps its own recipe; a key that misses a parameter shaping the content is a stale-result
bug, so each recipe lists everything its content depends on, with a version to bump.

Verification: every cache file is written atomically (core.io.atomic_path), then its checksum
file `<file>.sha256` beside it, also atomically: one line `poevp-cache-sha256-v1 <SHA-256 of the
file's bytes> <byte count> <file name>`. On load a file passes when its checksum file exists and
matches, it loads, and its user's check (expected keys, dtypes, shapes, values) finds nothing
wrong. A file that fails (cut short, emptied, overwritten, another file in its place) is removed
and rebuilt, and one note says so on stderr: `poevp: cache file <path> failed its check
(<reason>); rebuilt`. A file with no checksum file (written before cache files carried one, or a
build cut off between the two) is rebuilt once without a note: nothing was damaged. A rebuild
runs under a lock beside the file (`.<name>.lock`, flock, removed after), so processes sharing a
cache build each file once and never remove one another's good files.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import sys
from pathlib import Path
from typing import Callable, Iterator, TypeVar

from poevp_optics.core.runtime import cache_dir

T = TypeVar("T")

#: First field of every checksum file: the scheme (SHA-256 of the file's bytes) and its version.
CHECKSUM_TAG = "poevp-cache-sha256-v1"


class CacheCheckError(Exception):
    """A cache file failed its check; the message is the reason (one line)."""


class UncheckedFile(CacheCheckError):
    """A cache file with no checksum file beside it (written before cache files carried one, or a
    build cut off between the two): rebuilt without a note, nothing was damaged."""


#: checksum_problem's reason for a file with no checksum file.
NO_CHECKSUM = "no checksum file beside it"


def digest(data: bytes | str, *, algo: str = "sha1", length: int = 16) -> str:
    """Hex digest of `data` (str: UTF-8), cut to `length` characters (16 hex = 64 bits)."""
    raw = data.encode() if isinstance(data, str) else bytes(data)
    return hashlib.new(algo, raw).hexdigest()[:length]


def json_digest(obj, *, algo: str = "sha1", length: int = 16, **dumps) -> str:
    """`digest` of json.dumps(obj, **dumps) (e.g. sort_keys=True, default=str)."""
    return digest(json.dumps(obj, **dumps), algo=algo, length=length)


def save_npz(path: str | os.PathLike, arrays: dict) -> None:
    """Write `arrays` as an uncompressed .npz to `path` (the name kept as given: NumPy would add
    .npz to a temporary file's name)."""
    import numpy as np

    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


def cache_file(kind: str, name: str) -> Path:
    """Path of the cache file `name` in the folder `kind` under the cache root (not created)."""
    return cache_dir(kind) / name


# ------------------------------------------------------------------------------- checksums
def checksum_path(path: str | os.PathLike) -> Path:
    """The checksum file beside `path`: `<name>.sha256`."""
    path = Path(path)
    return path.with_name(path.name + ".sha256")


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_checksum(path: str | os.PathLike) -> None:
    """Write `path`'s checksum file (atomically), after `path` itself is complete."""
    from poevp_optics.core.io import atomic_path

    path = Path(path)
    line = f"{CHECKSUM_TAG} {_file_sha256(path)} {path.stat().st_size} {path.name}\n"
    with atomic_path(checksum_path(path)) as tmp:
        Path(tmp).write_text(line)


def checksum_problem(path: str | os.PathLike) -> str | None:
    """Why `path` fails its checksum (missing, no or unreadable checksum file, other size or
    bytes than written), or None when it passes."""
    path = Path(path)
    if not path.is_file():
        return "missing"
    side = checksum_path(path)
    try:
        fields = side.read_text().split()
    except FileNotFoundError:
        return NO_CHECKSUM
    except (OSError, UnicodeDecodeError):
        return f"unreadable checksum file {side.name}"
    if len(fields) != 4 or fields[0] != CHECKSUM_TAG or fields[3] != path.name or not fields[2].isdigit():
        return f"checksum file {side.name} is not a {CHECKSUM_TAG} line for {path.name}"
    size = path.stat().st_size
    if size != int(fields[2]):
        return f"{size} bytes, {fields[2]} written"
    if _file_sha256(path) != fields[1]:
        return "its bytes differ from the ones written (SHA-256)"
    return None


def discard(path: str | os.PathLike) -> None:
    """Remove a cache file and its checksum file (the checksum first: a reader never takes a
    half-removed pair for a good one)."""
    path = Path(path)
    checksum_path(path).unlink(missing_ok=True)
    path.unlink(missing_ok=True)


def note_rebuilt(path: str | os.PathLike, reason: str, *, kind: str = "file") -> None:
    """The one note line for a cache file (or folder) that failed its check and was rebuilt (stderr)."""
    print(f"poevp: cache {kind} {path} failed its check ({reason}); rebuilt", file=sys.stderr, flush=True)


# ------------------------------------------------------------------------------- load / build
def _reason(e: BaseException) -> str:
    text = " ".join(str(e).split()) or "no message"
    return text[:200] if isinstance(e, CacheCheckError) else f"{type(e).__name__}: {text[:200]}"


def load_verified(path: str | os.PathLike, load: Callable[[Path], T],
                  check: Callable[[T], str | None] | None = None) -> T:
    """`load(path)` of a cache file that passes its checksum and `check(value)` (the reason it
    fails, or None); CacheCheckError with the reason otherwise (a load or check that raises
    counts as a failure: the file is what is wrong)."""
    path = Path(path)
    problem = checksum_problem(path)
    if problem is not None:
        raise (UncheckedFile if problem == NO_CHECKSUM else CacheCheckError)(problem)
    try:
        value = load(path)
        problem = check(value) if check is not None else None
    except Exception as e:                       # noqa: BLE001 - whatever a damaged file makes load raise
        raise CacheCheckError(_reason(e)) from e
    if problem:
        raise CacheCheckError(problem)
    return value


def save_verified(path: str | os.PathLike, value, save: Callable[[Path, object], None]) -> None:
    """`save(tmp, value)` to a temporary file renamed onto `path` (a killed run leaves no partial
    file), then its checksum file."""
    from poevp_optics.core.io import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        save(tmp, value)
    write_checksum(path)


@contextlib.contextmanager
def build_lock(path: str | os.PathLike) -> Iterator[None]:
    """Hold an exclusive flock on `.<name>.lock` beside `path` (blocking) while one process
    checks, removes and rebuilds it; the holder removes the lock file before releasing it (a
    waiter that locked a removed lock file tries again), so none is left behind. The kernel
    releases the lock when its process dies, however it dies."""
    import fcntl

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lock = path.parent / f".{path.name}.lock"
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        fcntl.flock(fd, fcntl.LOCK_EX)
        try:
            if os.fstat(fd).st_ino == os.stat(lock).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    try:
        yield
    finally:
        lock.unlink(missing_ok=True)
        os.close(fd)                              # closing releases the flock


def cached(path: str | os.PathLike, build: Callable[[], T], *, load: Callable[[Path], T],
           save: Callable[[Path, T], None], check: Callable[[T], str | None] | None = None) -> T:
    """The verified value of the cache file `path`: `load(path)` when it passes its checksum and
    `check(value)` (None, or the reason it fails), else `build()`, saved with `save(tmp, value)`
    atomically and its checksum file written. A file that was there and failed is removed before
    the rebuild and noted on stderr (`note_rebuilt`); one with no checksum file is rebuilt
    without a note (`UncheckedFile`)."""
    path = Path(path)
    if path.is_file():
        with contextlib.suppress(CacheCheckError):
            return load_verified(path, load, check)
    with build_lock(path):
        reason = None
        if path.is_file():                        # again, under the lock: another process may have built it
            try:
                return load_verified(path, load, check)
            except UncheckedFile:
                pass
            except CacheCheckError as e:
                reason = str(e)
        discard(path)
        value = build()
        save_verified(path, value, save)
    if reason is not None:
        note_rebuilt(path, reason)
    return value


def cached_png(path: str | os.PathLike, image, what: str) -> Path:
    """`path` holding the 8-bit PNG of `image` (a uint8 array), rewritten unless its pixels are
    exactly `image`'s; `what` names the image in the reason for a rebuild."""
    import numpy as np

    from poevp_optics.core.io import read_png, write_png

    def problem(p: Path) -> str | None:
        img = read_png(p)
        if img.shape != image.shape or img.dtype != image.dtype:
            return f"{img.dtype} image of shape {img.shape}, not uint8 {image.shape}"
        return None if np.array_equal(img, image) else f"pixels differ from {what}"

    return cached_path(path, lambda tmp: write_png(tmp, image), problem)


def cached_path(path: str | os.PathLike, write: Callable[[Path], None],
                check: Callable[[Path], str | None] | None = None) -> Path:
    """`path` once it holds a file that passes its checksum and `check(path)`, written with
    `write(tmp)` when not (`cached` for files read by path, e.g. by Mitsuba)."""
    return cached(Path(path), lambda: Path(path), load=lambda p: p, save=lambda tmp, _: write(tmp), check=check)
