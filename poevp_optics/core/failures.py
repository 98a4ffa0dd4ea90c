"""The command line's error boundary: any exception that ends a command becomes one line.

`describe(e)` turns an exception into (message, exit status): 2 for what the user gave (a
path, a key, a flag: the UserError family, a path the OS refuses as named, input nested too
deeply), 1 for the environment (disk full, out of memory, too many open files, I/O errors) and
for internal errors (a bug: the line says so and that `--debug` or POEVP_DEBUG=1 shows the
traceback). Exit statuses: cli.py's module docstring.

`quiet_native_stderr()` captures what C libraries (OpenEXR, Mitsuba) print straight to file
descriptors 1 and 2 during a block, so that their text can be folded into our one line instead of
appearing loose on the terminal.
"""

from __future__ import annotations

import contextlib
import errno
import os
import sys
import tempfile
from typing import Iterator

from poevp_optics.core.exceptions import UserError

#: errno values that say the machine, not the input, is at fault: exit 1.
ENVIRONMENT_ERRNOS = {errno.ENOSPC: "no space left on the device",
                      errno.EDQUOT: "disk quota exceeded",
                      errno.EIO: "input/output error (a failing disk or network file system)",
                      errno.ENOMEM: "out of memory",
                      errno.EMFILE: "too many open files in this process",
                      errno.ENFILE: "too many open files on this machine",
                      errno.EAGAIN: "a system resource is temporarily unavailable"}

#: What to do, by errno, for errors caused by the path as given: exit 2.
_PATH_ADVICE = {errno.ENAMETOOLONG: "the name is too long for the file system: give a shorter path",
                errno.ELOOP: "symbolic links there form a loop: give a path that resolves",
                errno.EACCES: "permission denied: give a path you can write, or change its permissions",
                errno.EPERM: "operation not permitted there: give another path",
                errno.EROFS: "the file system is read-only: give a path on a writable one",
                errno.ENOENT: "no such file or folder: check the path",
                errno.ENOTDIR: "a component of the path is not a folder: check the path",
                errno.EISDIR: "is a folder where a file was expected: check the path",
                errno.EEXIST: "already exists: give another path",
                errno.EXDEV: "crosses file systems: keep --out on one file system",
                errno.ENOTEMPTY: "the folder is not empty: give another path"}

_ENV_ADVICE = {errno.ENOSPC: "free space there or give --out on another disk (`poevp validate` "
                             "prints the run's disk estimate)",
               errno.EDQUOT: "free space or give --out on another disk",
               errno.ENOMEM: "close other programs or make the run smaller (--resolution, --frames)",
               errno.EMFILE: "raise the limit (ulimit -n) or run with fewer --workers",
               errno.ENFILE: "close other programs or run with fewer --workers",
               errno.EAGAIN: "run with fewer --threads or --workers"}


def _where(e: OSError) -> str:
    names = [n for n in (e.filename, e.filename2) if n]
    return " -> ".join(str(os.fsdecode(n)) if isinstance(n, bytes) else str(n) for n in names)


def describe_oserror(e: OSError, context: str = "") -> tuple[str, int]:
    """One line for an OSError and its exit status (1 environment, 2 the path given)."""
    where = _where(e)
    head = f"{context}: " if context else ""
    head += f"{where}: " if where else ""
    reason = e.strerror or str(e) or type(e).__name__
    if e.errno in ENVIRONMENT_ERRNOS:
        advice = _ENV_ADVICE.get(e.errno, "check the machine and run again")
        return f"{head}{reason} ({ENVIRONMENT_ERRNOS[e.errno]}); {advice}; nothing already written was lost", 1
    advice = _PATH_ADVICE.get(e.errno)
    return f"{head}{reason}" + (f" ({advice})" if advice else ""), 2


def _chain(e: BaseException) -> Iterator[BaseException]:
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        yield e
        e = e.__cause__ or e.__context__


def describe(e: BaseException) -> tuple[str, int]:
    """(one line without the `poevp: error: ` prefix, exit status) for an exception that ended
    a command; KeyboardInterrupt and SIGTERM are cli.py's (130, 143)."""
    if isinstance(e, UserError):
        return str(e), 2
    for c in _chain(e):
        if isinstance(c, OSError) and c.errno is not None:
            return describe_oserror(c)
    if isinstance(e, RecursionError):
        return ("input nested too deeply to read (RecursionError): a TOML/XML value or an "
                "--set/--grid value holds thousands of nested brackets; flatten it"), 2
    if isinstance(e, MemoryError):
        return ("out of memory (MemoryError): make the run smaller (--resolution, --frames, "
                "--grid points, --workers) or set POEVP_MEMORY_LIMIT to what this machine has"), 1
    if isinstance(e, OSError):
        return describe_oserror(e)
    first = " ".join(str(e).split())[:400]
    return (f"internal error {type(e).__name__}" + (f": {first}" if first else "")
            + " (a bug in poevp: rerun with --debug or POEVP_DEBUG=1 for the traceback and report it)"), 1


def debug_requested(argv: list[str]) -> bool:
    """`--debug` anywhere before a `--`, or POEVP_DEBUG set to a non-empty value other than 0."""
    head = argv[:argv.index("--")] if "--" in argv else argv
    return "--debug" in head or os.environ.get("POEVP_DEBUG", "") not in ("", "0")


@contextlib.contextmanager
def quiet_native_stderr() -> Iterator[list[str]]:
    """Capture what C code writes to file descriptors 1 and 2 within the block (OpenEXR prints
    its warnings to stdout, Mitsuba its log to stderr); the text lands in the yielded list (one
    string) when the block ends, so the caller can fold it into its error. With POEVP_DEBUG set
    the text is written through to stderr as well. Python code in the block must not print."""
    captured: list[str] = []
    saved = []
    with contextlib.ExitStack() as stack:
        tmp = stack.enter_context(tempfile.TemporaryFile())
        for stream, fd in ((sys.stdout, 1), (sys.stderr, 2)):
            with contextlib.suppress(Exception):
                stream.flush()
            try:
                saved.append((fd, os.dup(fd)))
                os.dup2(tmp.fileno(), fd)
            except OSError:
                pass
        try:
            yield captured
        finally:
            for fd, old in saved:
                os.dup2(old, fd)
                os.close(old)
            tmp.seek(0)
            text = tmp.read().decode(errors="replace")
            captured.append(" ".join(text.split()))
            if text.strip() and os.environ.get("POEVP_DEBUG", "") not in ("", "0"):
                sys.stderr.write(text)
