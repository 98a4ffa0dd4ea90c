"""The one place that sets process-wide state: Mitsuba variant, DrJit and torch threads, the
SIGTERM handler.

STYLE.md 12: nothing else calls `mi.set_variant`, `dr.set_thread_count`,
`torch.set_num_threads` or `signal.signal`.
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import re
import sys
import warnings
from pathlib import Path

_LLVM_CANDIDATES = ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so",
                    "/usr/lib/aarch64-linux-gnu/libLLVM.so.19.1")


def _prefer_llvm19() -> None:
    """Point DrJit at Debian's libLLVM 19 when present and nothing else was chosen: DrJit 1.5
    emits llvm.minimum/maximum, which libLLVM 14/15 cannot select (FACTS.md)."""
    if "DRJIT_LIBLLVM_PATH" in os.environ:
        return
    for cand in _LLVM_CANDIDATES:
        if Path(cand).exists():
            os.environ["DRJIT_LIBLLVM_PATH"] = cand
            return


_prefer_llvm19()


class Terminated(BaseException):
    """SIGTERM, raised in the main thread like KeyboardInterrupt (a BaseException, so no
    `except Exception` on the way swallows it and every `finally` and staging cleanup runs)."""


#: A SIGTERM seen inside `sigterm_raises`: `term` (noted, not yet acted on by a block's end),
#: `raised` (Terminated raised so far), `depth` (nested blocks).
_TERM = {"term": False, "raised": 0, "depth": 0}


def _raise_terminated(signum, frame):
    _TERM["term"] = True
    _TERM["raised"] += 1
    raise Terminated()


def check_terminated() -> None:
    """A safe point: raise Terminated when a SIGTERM was noted inside `sigterm_raises` (one that
    a library swallowed on its way up still stops the command here)."""
    if _TERM["term"]:
        _TERM["raised"] += 1
        raise Terminated()


def _caused_by_terminated(exc) -> bool:
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, Terminated):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def _unraisable(previous):
    """sys.unraisablehook inside `sigterm_raises`: a Terminated that Python could not raise (the
    SIGTERM landed in a garbage-collection callback, a __del__ or a weakref callback: the
    exception is printed and dropped there) is delivered again, by the signal itself sent from a
    helper thread 50 ms later, unless a Terminated was raised since; anything else goes to the
    previous hook."""
    import threading

    def hook(args):
        if not _caused_by_terminated(args.exc_value):
            previous(args)
            return
        lost_at = _TERM["raised"]

        def again():
            if _TERM["depth"] and _TERM["raised"] == lost_at:
                os.kill(os.getpid(), signal.SIGTERM)

        t = threading.Timer(0.05, again)
        t.daemon = True
        t.start()
    return hook


@contextlib.contextmanager
def sigterm_raises():
    """Within the block, SIGTERM raises `Terminated` (handled like Ctrl-C: message, cleanup,
    exit 143) and is noted. Python drops an exception raised inside a garbage-collection
    callback, a __del__ or a weakref callback (Dask registers a GC callback), so a SIGTERM that
    lands there is not lost: the signal is delivered again once that callback is over
    (`_unraisable`), `check_terminated` raises at a safe point, and a block that ends without
    an exception after a noted SIGTERM raises Terminated at its end. Yields the noted state
    (`["term"]`). Outside the main thread signals cannot be handled: the block runs as is."""
    import sys
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield _TERM
        return
    old = signal.signal(signal.SIGTERM, _raise_terminated)
    old_hook = sys.unraisablehook
    if _TERM["depth"] == 0:
        _TERM.update(term=False, raised=0)
        sys.unraisablehook = _unraisable(old_hook)
    _TERM["depth"] += 1
    try:
        yield _TERM
        check_terminated()              # a SIGTERM swallowed on the way: the command still stops
    finally:
        _TERM["depth"] -= 1
        signal.signal(signal.SIGTERM, old)
        if _TERM["depth"] == 0:
            sys.unraisablehook = old_hook
            _TERM["term"] = False


def sigterm_exits(message: str) -> None:
    """From now on, a SIGTERM outside `sigterm_raises` blocks (argument parsing, or the
    interpreter's shutdown after a command wrote everything: Dask closing its cluster) prints
    `message` and exits 143 at once instead of dying silently. Main thread only."""
    import sys
    import threading

    if threading.current_thread() is not threading.main_thread():
        return

    def _exit(signum, frame):
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        with contextlib.suppress(OSError):
            os.write(2, (message + "\n").encode())
        os._exit(143)

    signal.signal(signal.SIGTERM, _exit)


@contextlib.contextmanager
def signals_deferred():
    """Hold SIGTERM and SIGINT back for the block (an output folder being swapped into place)
    and deliver them after it; only the main thread can do this, elsewhere the block just runs."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held = {signal.SIGTERM, signal.SIGINT}
    old = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


_THREADS: int | None = None


def max_threads() -> int:
    """Most threads a run may ask for: 8 per core, at least 64 (more only oversubscribes)."""
    return max(64, 8 * (os.cpu_count() or 1))


def set_threads(n: int | None) -> None:
    """Thread count for DrJit's LLVM backend, torch, OpenCV and SciPy's FFTs (`fft_workers`;
    None: leave the defaults). torch is not imported for it (1.7-3 s a process): set here when
    loaded, else by `torch_threads` in each module that computes with torch, once it loads."""
    global _THREADS
    if n is None:
        return
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"thread count must be an integer >= 1, got {n!r}")
    if n > max_threads():
        raise ValueError(f"thread count {n} is above the limit {max_threads()} (8 per core, at least 64)")
    _THREADS = int(n)
    import drjit as dr

    try:
        dr.set_thread_count(int(n))
    except RuntimeError as e:          # the OS refused the threads (EAGAIN)
        raise OSError(errno.EAGAIN, f"cannot start {n} threads ({e})", "--threads") from None
    torch_threads()
    try:
        import cv2

        cv2.setNumThreads(int(n))
    except ImportError:
        pass


def torch_threads() -> None:
    """The run's thread count (`set_threads`) given to torch, where torch is loaded; called by
    `set_threads` and by each module that computes with torch, after its import."""
    torch = sys.modules.get("torch")
    if _THREADS is not None and torch is not None:
        torch.set_num_threads(_THREADS)


_BLOCKS_KEPT: bool | None = None


def keep_large_blocks() -> bool:
    """Have glibc's malloc serve large arrays from its heap and keep freed ones for reuse
    (mallopt(3): M_MMAP_THRESHOLD 1 GiB, M_TRIM_THRESHOLD 2 GiB - 1). By default every block
    over 32 MiB (the dynamic threshold's ceiling on 64-bit) is mmapped and unmapped on free, so
    each FFT buffer of a 1920x1080 frame (up to 160 MB) was a fresh mapping the kernel faulted in
    and zeroed: 3.2 s of system time in 8 objective passes, 0.1 s with this (wall 7.3-8.7 ->
    5.5-6.7 s, 2-core VM). Freed blocks stay with the process: the default scene's 21 frames
    at 1920x1080 peaked at 3.06 GB resident, 2.57 GB without (system time 50 -> 8 s, wall 188
    -> 167 s), inside the run's memory estimate (4.6 GB, apps/run/memory.py). Returns whether
    it applies (glibc only: elsewhere nothing changes); once per process, before the run's
    arrays. Set by the command line's own process only: a long-lived process that runs many
    jobs (a Dask worker, the tests' workers) would hold its largest job's memory for the rest."""
    global _BLOCKS_KEPT
    if _BLOCKS_KEPT is None:
        _BLOCKS_KEPT = False
        try:
            import ctypes

            libc = ctypes.CDLL("libc.so.6")
            m_trim_threshold, m_mmap_threshold = -1, -3          # malloc.h
            _BLOCKS_KEPT = bool(libc.mallopt(m_mmap_threshold, 1 << 30)) and \
                bool(libc.mallopt(m_trim_threshold, (1 << 31) - 1))
        except (OSError, AttributeError):                         # not glibc
            pass
    return _BLOCKS_KEPT


def run_threads() -> int:
    """The run's thread count (`set_threads`), else the CPUs."""
    return _THREADS or os.cpu_count() or 1


def fft_workers() -> int:
    """Threads for SciPy's FFTs (scipy.fft.set_workers): `run_threads`. pocketfft splits the
    independent 1-D transforms of an axis between threads, so the result is the same for any
    count."""
    return run_threads()


def backend_available(name: str) -> bool:
    """Whether DrJit's 'cuda' or 'llvm' backend initialises on this machine."""
    import drjit as dr

    backend = {"cuda": dr.JitBackend.CUDA, "llvm": dr.JitBackend.LLVM}[name]
    try:
        return bool(dr.has_backend(backend))
    except Exception:  # noqa: BLE001 - a broken driver/LLVM just means "not available"
        return False


def choose_variant(mode: str, requested: str = "auto") -> tuple[str, str]:
    """Pick a Mitsuba variant for `mode` ('spectral' or 'mono'): cuda > llvm > scalar.

    Returns (variant, reason). `requested` other than 'auto' is used as given (checked).
    """
    import mitsuba as mi

    if requested != "auto":
        if requested not in mi.variants():
            raise ValueError(f"render.variant: {requested!r} is not a Mitsuba variant here "
                             f"(have {', '.join(mi.variants())})")
        return requested, "requested in the scene file"
    suffix = "spectral" if mode == "spectral" else "mono"
    if backend_available("cuda") and f"cuda_ad_{suffix}" in mi.variants():
        return f"cuda_ad_{suffix}", "CUDA GPU available"
    if backend_available("llvm") and f"llvm_ad_{suffix}" in mi.variants():
        return f"llvm_ad_{suffix}", "no CUDA GPU; LLVM backend available"
    warnings.warn("poevp: neither CUDA nor LLVM backend works; falling back to scalar_spectral "
                  "(about 10x slower). Install Debian's libllvm19.", RuntimeWarning, stacklevel=2)
    return "scalar_spectral", "no CUDA or LLVM backend: scalar fallback"


#: Called after every `set_variant`: render/__init__.py registers its Mitsuba plugins here (the
#: materials and emitters written in Python), so core/ imports nothing of ours (DESIGN's table).
_VARIANT_HOOKS: list = []


def on_variant(hook) -> None:
    """Call `hook()` after every `set_variant` from now on (once per hook)."""
    if hook not in _VARIANT_HOOKS:
        _VARIANT_HOOKS.append(hook)


def set_variant(variant: str) -> None:
    """Activate a Mitsuba variant (the only call site of mi.set_variant) and run the hooks that
    register our Python plugins with it (render/__init__.py: retroreflective sheeting,
    photometric lamps; any import of poevp_optics.render installs it)."""
    import mitsuba as mi

    if mi.variant() != variant:
        mi.set_variant(variant)
        mi.set_log_level(mi.LogLevel.Error)  # Mitsuba's warnings are not ours to print
    for hook in _VARIANT_HOOKS:
        hook()


def register_asset_dir(path) -> None:
    """Let Mitsuba XML name files relative to `assets/` (e.g. plates/plate_F9H28.png)."""
    import mitsuba as mi

    fr = mi.Thread.thread().file_resolver()
    if str(path) not in [str(p) for p in fr]:
        fr.append(str(path))


def libllvm_in_use() -> str | None:
    """Path of the libLLVM shared library DrJit loaded (read from /proc/self/maps), if any."""
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return os.environ.get("DRJIT_LIBLLVM_PATH")
    hits = sorted(set(re.findall(r"(/\S*libLLVM[^\s/]*\.so[^\s/]*)", maps)))
    return hits[0] if hits else None


def pyplot():
    """matplotlib.pyplot with the non-interactive Agg backend (the one place that sets it)."""
    import matplotlib

    if matplotlib.get_backend().lower() != "agg":
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def cache_dir(*parts: str) -> Path:
    """The package's cache folder ($POEVP_CACHE_DIR, else ~/.cache/poevp_optics), sub-folder `parts`."""
    root = Path(os.environ.get("POEVP_CACHE_DIR", Path.home() / ".cache" / "poevp_optics"))
    return root.joinpath(*parts)


_OCR_ENGINES: dict = {}


def ocr_engine(**config):
    """The process's OCR engine for `config` (RapidOCR keyword settings, e.g. det_limit_type),
    PP-OCRv4 ONNX models inside its wheel, built on first use: loading the models costs ~1 s."""
    key = tuple(sorted(config.items()))
    if key not in _OCR_ENGINES:
        from rapidocr_onnxruntime import RapidOCR

        _OCR_ENGINES[key] = RapidOCR(**config)
    return _OCR_ENGINES[key]
