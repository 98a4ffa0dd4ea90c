"""File output and input: OpenEXR (float32) and PNG, always written atomically; the one policy
for output folders.

Every writer puts the bytes in a temporary file in the destination folder and renames it into
place (`os.replace`, atomic on POSIX), so a crash never leaves a truncated file.

Output folders (`staged_dir` for a run's whole folder, `locked_dir` for a folder a sweep fills
in place) follow one policy:

* checked before any work: `--out` must not be the current folder or hold it, nor hold the
  scene; an existing `--out` must be a folder, empty or written by poevp for the same kind of
  run (the marker file `.poevp-output.json` says which); its parent must be writable.
* locked: `.<name>.lock` beside the folder (flock) while a run writes it; a second run into the
  same folder refuses. The kernel releases the lock when its process dies, however it dies.
* staged: a run writes into `.<name>.staging-<pid>-*` beside the folder, which replaces the old
  folder only when the run succeeded, in one atomic exchange (renameat2 RENAME_EXCHANGE; a
  two-step rename where the file system lacks it), with SIGTERM/SIGINT held back meanwhile.
  A failed or interrupted run removes its staging folder; one left by a killed process
  (SIGKILL) is removed by the next run into the same folder, under its lock.
* folders get normal permissions (0777 minus the umask), not mkdtemp's 0700.
"""

from __future__ import annotations

import contextlib
import ctypes
import datetime
import errno
import fcntl
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator, Mapping

import cv2
import numpy as np
import OpenEXR

from poevp_optics.core.exceptions import UserError

#: Written into every output folder: which kind of poevp run made it.
MARKER = ".poevp-output.json"
OUTPUT_KINDS = ("render", "chart", "compare", "evaluate", "sweep", "search", "train_sequence")


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
    except OSError as e:               # name the file being written, not its temporary twin
        if e.filename is not None and os.fsdecode(e.filename) == str(tmp):
            e.filename = str(path)
        raise
    finally:
        if tmp.exists():
            tmp.unlink()


#: Below this many free bytes a failed write is taken for a full disk.
_NEARLY_FULL = 1 << 20


def write_error(path: str | os.PathLike, what: str) -> OSError:
    """An OSError for a library's failed write of `path` (OpenEXR, OpenCV give no errno):
    ENOSPC when the text says so or the file system is (nearly) full, else EIO."""
    try:
        full = free_bytes(Path(path).parent) < _NEARLY_FULL
    except OSError:
        full = False
    if full or "no space left" in what.lower():
        return OSError(errno.ENOSPC, "No space left on device", str(path))
    return OSError(errno.EIO, f"could not write the file ({' '.join(what.split())[:300]})", str(path))


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
        try:
            with OpenEXR.File(header, chans) as f:
                f.write(str(tmp))
        except OSError:
            raise
        except Exception as e:  # noqa: BLE001 - OpenEXR raises RuntimeError for I/O failures
            raise write_error(path, f"OpenEXR: {e}") from None


def read_exr(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """Read an OpenEXR file: (channels by name as float32 arrays, header dict). What OpenEXR
    prints itself on a damaged file is folded into the exception's text, never printed loose."""
    from poevp_optics.core.failures import quiet_native_stderr

    try:
        with quiet_native_stderr() as printed:
            with OpenEXR.File(str(path), separate_channels=True) as f:
                part = f.parts[0]
                chans = {name: np.array(c.pixels, dtype=np.float32) for name, c in part.channels.items()}
                return chans, dict(part.header)
    except OSError:
        raise
    except Exception as e:  # noqa: BLE001 - the binding raises RuntimeError variants
        extra = " ".join(printed).strip()
        raise RuntimeError(" ".join(f"{e} {extra}".split())[:400]) from None


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write a uint8 or uint16 image ((H, W) grey or (H, W, 3) RGB) as PNG, atomically."""
    img = np.asarray(image)
    if img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"PNG data for {path} must be uint8 or uint16, got {img.dtype}")
    if img.ndim == 3:
        img = img[..., ::-1]  # OpenCV writes BGR
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), img):
            raise write_error(path, "OpenCV could not write the PNG")


def read_png(path: str | os.PathLike) -> np.ndarray:
    """Read a PNG as stored (8 or 16 bit); colour images come back RGB."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise OSError(f"could not read image {path}")
    if img.ndim == 3:
        img = img[..., ::-1].copy()
    return img


#: Largest ADC depth whose codes a PNG holds (uint16); deeper captures go to float32 EXR, whose
#: 24-bit significand holds every integer code up to 2^24 exactly (sensor.bits <= 24).
PNG_MAX_BITS = 16


def dn_suffix(bits: int) -> str:
    """File suffix of a capture with `bits`-bit codes: .png up to 16 bits, else .exr."""
    return ".png" if bits <= PNG_MAX_BITS else ".exr"


def write_dn(path_stem: str | os.PathLike, dn: np.ndarray, bits: int) -> Path:
    """Write a capture's digital numbers losslessly: 8-bit PNG (bits <= 8), 16-bit PNG
    (<= 16), else a float32 EXR with channel `DN` (exact to 24 bits). `path_stem` has no
    suffix; returns the written path. Codes outside [0, 2^bits - 1] or not integers are an
    error: a capture is never wrapped or rounded on its way to disk."""
    d = np.asarray(dn)
    top = (1 << bits) - 1
    if d.size and (not np.all(np.isfinite(d)) or d.min() < 0 or d.max() > top or np.any(d != np.rint(d))):
        raise ValueError(f"{path_stem}: capture codes must be integers in [0, {top}] for {bits} bits")
    path = Path(path_stem).with_suffix(dn_suffix(bits))
    if bits <= 8:
        write_png(path, d.astype(np.uint8))
    elif bits <= PNG_MAX_BITS:
        write_png(path, d.astype(np.uint16))
    else:
        write_exr(path, {"DN": d.astype(np.float32)},
                  {"poevp_quantity": "digital numbers (integers)", "poevp_unit": "DN",
                   "poevp_bits": str(bits)})
    return path


def read_dn(path: str | os.PathLike) -> np.ndarray:
    """Read a capture written by `write_dn` (PNG or EXR) as float64 digital numbers."""
    path = Path(path)
    if path.suffix.lower() == ".exr":
        return read_exr(path)[0]["DN"].astype(np.float64)
    return read_png(path).astype(np.float64)


class OutputError(UserError):
    """An output folder that must not or cannot be written; raised before any work."""


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def output_kind(folder: Path) -> str | None:
    """The kind of run whose marker `folder` holds, or None (not a poevp output)."""
    try:
        kind = json.loads((Path(folder) / MARKER).read_text()).get("kind")
    except (OSError, ValueError, AttributeError):
        return None
    return kind if kind in OUTPUT_KINDS else None


def _contains(outer: Path, inner: Path) -> bool:
    return inner == outer or outer in inner.parents


#: Characters a staging or parked name adds to the output folder's (`.<name>.staging-<pid>-<8>`).
_STAGING_EXTRA = 40


def _checked_path(given: str, where: str) -> Path:
    """`given` made absolute, symbolic links resolved; OutputError for a name too long for the
    file system (with room for the staging name beside it) or a symbolic-link loop."""
    out = Path(os.path.abspath(given))
    probe = out
    while probe.parent != probe:
        try:
            if probe.is_dir():
                break
        except OSError:                        # a name too long, a loop: look further up
            pass
        probe = probe.parent
    try:
        name_max = os.pathconf(probe, "PC_NAME_MAX")
        path_max = os.pathconf(probe, "PC_PATH_MAX")
    except (OSError, ValueError):
        name_max, path_max = 255, 4096
    for part in out.parts:
        if len(os.fsencode(part)) + _STAGING_EXTRA > name_max:
            raise OutputError(f"{where}: the name {part[:40]}... is {len(os.fsencode(part))} bytes; this "
                              f"file system allows {name_max} (and poevp needs {_STAGING_EXTRA} more for "
                              "its staging folder beside it): give a shorter name")
    if len(os.fsencode(str(out))) + _STAGING_EXTRA > path_max:
        raise OutputError(f"{where}: the path is {len(os.fsencode(str(out)))} bytes; this file system "
                          f"allows {path_max}: give a shorter path")
    try:
        resolved = out.resolve()               # raises on a loop anywhere on the path
        if os.path.lexists(out):
            return resolved
        return out
    except (RuntimeError, OSError) as e:       # Python 3.11 raises RuntimeError for a loop
        if isinstance(e, OSError) and e.errno not in (errno.ELOOP, errno.ENOENT):
            raise OutputError(f"{where}: {e.strerror or e}") from None
        raise OutputError(f"{where}: symbolic links on the path form a loop or point nowhere "
                          "(it does not resolve); give a path that resolves") from None


def free_bytes(path: str | os.PathLike) -> int:
    """Free bytes for an unprivileged writer on the file system that holds `path` (or its
    nearest existing parent): shutil.disk_usage's `free`."""
    p = Path(os.path.abspath(path))
    while not p.exists() and p.parent != p:
        p = p.parent
    return shutil.disk_usage(p).free


def check_free_space(out_dir: str | os.PathLike, need_bytes: int, what: str) -> None:
    """Refuse (OutputError, before any work) when the file system of `out_dir` has less free
    space than `need_bytes` (a run-size estimate, core/run_size.py): `what` names the run."""
    try:
        free = free_bytes(out_dir)
    except OSError:
        return                         # cannot tell: the writers' own errors still apply
    if need_bytes > free:
        raise OutputError(f"--out {out_dir}: {what} needs about {_size(need_bytes)} on disk, "
                          f"{_size(free)} free there; free space, give --out on another disk, or "
                          "make the run smaller")


def _size(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"


def check_output(out_dir: str | os.PathLike, kind: str, *, protect: tuple = ()) -> Path:
    """Apply the output policy's checks to `out_dir` (module docstring); return it absolute.

    protect: paths the folder must not be nor contain (the scene file and its folder).
    Raises OutputError (one line naming --out and the path) before any work is done."""
    if kind not in OUTPUT_KINDS:
        raise ValueError(f"unknown output kind {kind!r}")
    given = str(out_dir)
    if not given.strip():
        raise OutputError("--out: empty path")
    where = f"--out {given}"
    out = _checked_path(given, where)
    if out.parent == out:
        raise OutputError(f"{where}: the file-system root cannot be an output folder")
    cwd = Path.cwd().resolve()
    if _contains(out, cwd):
        raise OutputError(f"{where}: is the current folder or holds it ({cwd}); "
                          "a run replaces its output folder whole: give a subfolder")
    for p in protect:
        p = Path(p).resolve()
        if _contains(out, p):
            raise OutputError(f"{where}: is or holds {p}, which this run reads; give another folder")
    if out.exists():
        if not out.is_dir():
            raise OutputError(f"{where}: {out} exists and is not a folder; give a folder path")
        found = output_kind(out)
        if found is None and any(out.iterdir()):
            raise OutputError(f"{where}: {out} holds files that poevp did not write (no {MARKER}); "
                              "give an empty or new folder, or remove it yourself")
        if found is not None and found != kind:
            raise OutputError(f"{where}: {out} holds a poevp {found} output, not a {kind} output; "
                              "give another folder")
    parent = out.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{where}: cannot create {parent}: {e.strerror or e}") from None
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{where}: {parent} is not writable")
    return out


# ---------------------------------------------------------------------------- locks
def _lock_path(out: Path) -> Path:
    return out.parent / f".{out.name}.lock"


def _acquire(out: Path) -> int:
    """flock `.<name>.lock` beside `out`; OutputError when another process holds it."""
    path = _lock_path(out)
    for _ in range(100):
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666 & ~_umask())
        except OSError as e:
            raise OutputError(f"--out {out}: cannot create the lock {path}: {e.strerror or e}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            finally:
                os.close(fd)
            raise OutputError(f"--out {out}: another poevp process (pid {holder}) is writing this "
                              f"folder (lock {path}); wait for it or give another folder") from None
        # the previous holder may have unlinked the file between our open and flock: retry
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            return fd
        os.close(fd)
    raise OutputError(f"--out {out}: could not take the lock {path}")


def _release(out: Path, fd: int) -> None:
    with contextlib.suppress(OSError):
        os.unlink(_lock_path(out))
    os.close(fd)


def _clean_stale(out: Path) -> list[str]:
    """Under `out`'s lock, nothing else writes it: staging folders beside it are debris of a
    killed run. A previous folder parked by an interrupted two-step swap is put back first."""
    parent, name = out.parent, out.name
    notes = []
    parked = sorted(parent.glob(f".{name}.old-*"))
    if parked and not out.exists():
        os.rename(parked[0], out)
        notes.append(f"restored {out} from {parked[0].name} (a run was killed while swapping it)")
        parked = parked[1:]
    for stale in [*parent.glob(f".{name}.staging-*"), *parked]:
        shutil.rmtree(stale, ignore_errors=True)
        notes.append(f"removed {stale.name} (left by a killed run)")
    return notes


def _write_marker(folder: Path, kind: str) -> None:
    from poevp_optics.core.version import __version__

    write_json(folder / MARKER, {"kind": kind, "poevp_version": __version__,
                                 "written_utc": datetime.datetime.now(datetime.timezone.utc)
                                 .isoformat(timespec="seconds")})


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux renameat2 RENAME_EXCHANGE); False when unsupported."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _commit(stage: Path, out: Path) -> None:
    """Put `stage` in place of `out` (which may not exist); the old folder is removed."""
    from poevp_optics.core.runtime import signals_deferred

    with signals_deferred():
        if not out.exists():
            os.rename(stage, out)
            return
        if _exchange(stage, out):
            shutil.rmtree(stage, ignore_errors=True)        # now holds the old folder
            return
        old = out.parent / f".{out.name}.old-{os.getpid()}"
        os.rename(out, old)
        os.rename(stage, out)
        shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def staged_dir(out_dir: str | os.PathLike, *, kind: str, protect: tuple = ()) -> Iterator[Path]:
    """Yield an empty staging folder; on success it replaces `out_dir` whole (module docstring).

    kind: "render", "chart", "compare" or "evaluate" (written in the marker; an existing folder
    of another kind, or not written by poevp, is refused). On failure or interruption the
    staging folder is removed and an existing `out_dir` is left untouched."""
    out = check_output(out_dir, kind, protect=protect)
    fd = _acquire(out)
    try:
        _clean_stale(out)
        try:
            stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.staging-{os.getpid()}-", dir=out.parent))
        except OSError as e:
            raise OutputError(f"--out {out}: cannot write in {out.parent}: {e.strerror or e}") from None
        try:
            os.chmod(stage, 0o777 & ~_umask())
            _write_marker(stage, kind)
            try:
                yield stage
            except OSError as e:       # name the file as it would be in --out
                if e.filename is not None and os.fsdecode(e.filename).startswith(str(stage) + os.sep):
                    e.filename = str(out / os.path.relpath(os.fsdecode(e.filename), stage))
                raise
            _commit(stage, out)
        finally:
            if stage.exists():
                shutil.rmtree(stage, ignore_errors=True)
    finally:
        _release(out, fd)


@contextlib.contextmanager
def locked_dir(out_dir: str | os.PathLike, *, kind: str, protect: tuple = ()) -> Iterator[Path]:
    """Yield `out_dir` itself, created if needed and locked: a folder filled in place (a sweep
    adds points to it). Same checks as `staged_dir`; the marker is written on creation."""
    out = check_output(out_dir, kind, protect=protect)
    fd = _acquire(out)
    try:
        try:
            out.mkdir(exist_ok=True)
        except OSError as e:
            raise OutputError(f"--out {out}: cannot create it: {e.strerror or e}") from None
        if output_kind(out) is None:
            _write_marker(out, kind)
        yield out
    finally:
        _release(out, fd)
