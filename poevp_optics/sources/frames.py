"""Frame sequences as radiance sources: time sampling, area resampling onto the mirror grid, plate
boxes, and the source object the run loop reads (shared by `exr_sequence` and `ldr_highlight`).

**Time.** Input frame j shows the radiance at t_j = `t0_s` + j / `fps` on the scene clock (or at
the times of `times_csv`) and, for `integrate`, stands for the interval between the midpoints to
its neighbours (half a step beyond the first and the last frame). The camera asks for radiance
samples at its nodes (`RenderScene.subframe_times_s`: K uniform nodes including the exposure's
ends, joined by the DMD's switching times); `source.subframes` says how a sample comes from the
frames:

| mode      | sample at node t_k                                                        |
|-----------|---------------------------------------------------------------------------|
| nearest   | the frame whose t_j is nearest (a tie goes to the earlier frame)          |
| linear    | (1 - w) L_j + w L_j+1, w = (t_k - t_j) / (t_j+1 - t_j), t_j <= t_k < t_j+1 |
| integrate | the time mean of the piecewise-constant input over the node's cell: from (t_k-1 + t_k) / 2 to (t_k + t_k+1) / 2, cut at the exposure's ends (for input faster than the nodes) |

The cells of `integrate` are as long as the trapezoid (hat-function) weights of the camera's time
quadrature (`dmd.node_time_weights_s`), so with every mirror on, the exposure integrates the
piecewise-constant input exactly. A sample that needs time outside the frames is an error (no
extrapolation).

**Space.** Frames hold the sensor's field plus `guard_px` input pixels beyond each edge. The
mirror grid (render.resolution plus the camera's guard band, `Camera.guard_px`) is mapped onto
them linearly per axis, and each mirror pixel is the mean of the input over its footprint (area
resampling, a box filter; an exact copy when the grids coincide). Where the camera's guard band
reaches beyond the frames, the frames' edge pixels are continued outward (edge replication); the
report's notes say over how many mirrors.

**Boxes.** `frame,x0,y0,x1,y1[,text]`: frame is the 0-based index in the sorted sequence; the
box's edges are in input pixels (x0, y0 inclusive, x1, y1 exclusive: the box covers columns
x0 ... x1 - 1), so pixel (row y, column x) has its centre at (x + 0.5, y + 0.5).
"""

from __future__ import annotations

import csv
import glob
import os
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from poevp_optics.core.exceptions import UserError
from poevp_optics.core.frame import RenderedExposure
from poevp_optics.sources import spectra

SUBFRAME_MODES = ("nearest", "linear", "integrate")


class SourceError(UserError):
    """Bad source data (a frame, a CSV, a time span): one line naming the file and the key."""


class SourceKeyError(Exception):
    """A [source] key (or combination) that its kind refuses; scene/validate.py adds the file name."""

    def __init__(self, key: str, message: str):
        super().__init__(message)
        self.key = key


@dataclass(frozen=True)
class SourcePlan:
    """What a source is, for the report (`stages.render.path`, `path_reason`, `notes`)."""

    mode: str
    reason: str
    notes: tuple[str, ...] = ()


@dataclass
class SourceStats:
    """Report counters: frames decoded (`calls`) and the seconds spent decoding and resampling."""

    calls: int = 0
    seconds: float = 0.0


# ---------------------------------------------------------------------------- files
def resolve_path(base_dir: Path, name: str) -> Path:
    """A file named in [source], relative to the scene's folder unless absolute."""
    p = Path(name).expanduser()
    return p if p.is_absolute() else base_dir / p


def frame_files(base_dir: Path, pattern: str) -> list[Path]:
    """The files matching `pattern` (a glob relative to the scene's folder), sorted by name."""
    pat = str(resolve_path(base_dir, pattern))
    found = sorted(Path(p) for p in glob.glob(pat))
    for p in found:                    # a frame that cannot be read is named, not skipped
        if p.is_symlink() and not p.exists():
            raise SourceError(f"{p}: source.frames: matches {pattern!r} but is a broken symbolic link "
                              f"(to {os.readlink(p)}); restore the frame or remove the link")
    return [p for p in found if p.is_file()]


def check_file_keys(src, given: frozenset[str], base_dir: Path, file_keys: Sequence[str]) -> None:
    """Files named by `file_keys` exist; the `frames` glob matches at least one file."""
    if "frames" in given:
        if not frame_files(base_dir, src.frames):
            raise SourceKeyError("frames", f"no file matches {src.frames!r} (relative to {base_dir})")
    for key in file_keys:
        name = getattr(src, key)
        if key in given and not resolve_path(base_dir, name).is_file():
            raise SourceKeyError(key, f"file not found: {resolve_path(base_dir, name)}")


def check_clock_keys(src, given: frozenset[str], *, times_csv: bool) -> None:
    """`fps` (uniform frames from `t0_s`), or per-frame times from `times_csv`."""
    if times_csv and "times_csv" in given:
        if "fps" in given or "t0_s" in given:
            raise SourceKeyError("fps" if "fps" in given else "t0_s",
                                 "give either fps (and t0_s) or times_csv, not both")
    elif "fps" not in given:
        raise SourceKeyError("fps", "required: the frame rate of the sequence, frames per second"
                             + (" (or per-frame times in times_csv)" if times_csv else ""))


def photon_radiance_per_w(spectrum: str, response_e_per_J: np.ndarray) -> float:
    """e- s-1 m-2 sr-1 per W m-2 sr-1 of light with the SPD `spectrum`: the sensor-weighted
    fraction integral(S spd) / integral(spd) over the spectra grid (S = QE lambda / (h c))."""
    shape = spectra.load_spectrum(spectrum, emissive=True)
    return spectra.integrate(response_e_per_J * shape) / spectra.integrate(shape)


def photon_radiance_per_cd_per_m2(spectrum: str, response_e_per_J: np.ndarray) -> float:
    """e- s-1 m-2 sr-1 per cd m-2 of light with the SPD `spectrum`: integral(S spd) /
    (K_m integral(V spd)), K_m = 683.002 lm W-1 (spectra.scale_to_photometric)."""
    shape = spectra.load_spectrum(spectrum, emissive=True)
    return spectra.integrate(response_e_per_J * spectra.scale_to_photometric(shape, 1.0))


def check_spectrum_key(spectrum: str) -> None:
    """`spectrum` names a spectra.py source with visible power (it anchors W or cd m-2)."""
    try:
        shape = spectra.load_spectrum(spectrum, emissive=True)
    except spectra.SpectrumError as e:
        raise SourceKeyError("spectrum", str(e)) from None
    if not spectra.integrate(spectra.photopic_v() * shape) > 0:
        raise SourceKeyError("spectrum", f"{spectrum}: no visible power (zero under V(lambda))")


# ---------------------------------------------------------------------------- time
@dataclass(frozen=True)
class Clock:
    """When each input frame is (s, scene clock) and the interval it stands for."""

    times_s: np.ndarray      # (N,) strictly increasing
    edges_s: np.ndarray      # (N + 1,) midpoints between frames, half a step beyond the ends

    @classmethod
    def uniform(cls, n: int, fps: float, t0_s: float) -> "Clock":
        j = np.arange(n, dtype=np.float64)
        return cls(t0_s + j / fps, t0_s + (np.arange(n + 1, dtype=np.float64) - 0.5) / fps)

    @classmethod
    def from_times(cls, times_s: np.ndarray) -> "Clock":
        t = np.asarray(times_s, dtype=np.float64)
        mid = 0.5 * (t[1:] + t[:-1])
        return cls(t, np.concatenate([[t[0] - (t[1] - t[0]) / 2], mid, [t[-1] + (t[-1] - t[-2]) / 2]]))

    def taps_at(self, t_s: float, mode: str) -> tuple[tuple[int, float], ...]:
        """(frame, weight) pairs giving the radiance at `t_s` (nearest or linear)."""
        t = self.times_s
        if mode == "nearest":
            return ((int(np.searchsorted(self.edges_s[1:-1], t_s, side="left")), 1.0),)
        j = int(np.searchsorted(t, t_s, side="right")) - 1
        if j < 0:                       # within check_covers' rounding tolerance of the first frame
            return ((0, 1.0),)
        if j >= t.size - 1:
            return ((t.size - 1, 1.0),)
        w = (t_s - t[j]) / (t[j + 1] - t[j])
        return ((j, 1.0),) if w == 0.0 else ((j, 1.0 - w), (j + 1, w))

    def taps_over(self, a_s: float, b_s: float) -> tuple[tuple[int, float], ...]:
        """(frame, weight) pairs of the time mean over [a, b] of the piecewise-constant input."""
        e = self.edges_s
        j0 = max(int(np.searchsorted(e, a_s, side="right")) - 1, 0)
        j1 = min(int(np.searchsorted(e, b_s, side="left")), e.size - 1)
        if b_s <= a_s:
            return ((min(j0, self.times_s.size - 1), 1.0),)
        out = []
        for j in range(j0, j1):
            overlap = min(b_s, e[j + 1]) - max(a_s, e[j])
            if overlap > 0:
                out.append((j, overlap / (b_s - a_s)))
        return tuple(out)

    def span_s(self, mode: str) -> tuple[float, float]:
        """Times a sample may need: between the first and last frame for `linear`, within the
        frames' intervals otherwise."""
        if mode == "linear":
            return float(self.times_s[0]), float(self.times_s[-1])
        return float(self.edges_s[0]), float(self.edges_s[-1])


def read_times_csv(path: Path, files: Sequence[Path]) -> np.ndarray:
    """Per-frame times from a CSV `file,t_s` (file: a frame's file name); one row per frame."""
    rows = _csv_rows(path, ("file", "t_s"), "source.times_csv")
    by_name = {}
    for line, row in rows:
        by_name[row["file"].strip()] = (line, _csv_float(path, line, row, "t_s", "source.times_csv"))
    times = []
    for f in files:
        if f.name not in by_name:
            raise SourceError(f"{path}: source.times_csv: no row for frame file {f.name!r}")
        times.append(by_name[f.name][1])
    extra = sorted(set(by_name) - {f.name for f in files})
    if extra:
        raise SourceError(f"{path}:{by_name[extra[0]][0]}: source.times_csv: {extra[0]!r} is not one "
                          "of the frames (source.frames)")
    t = np.asarray(times, dtype=np.float64)
    bad = np.nonzero(np.diff(t) <= 0)[0]
    if bad.size:
        i = int(bad[0]) + 1
        raise SourceError(f"{path}: source.times_csv: times must increase with the frames' sorted "
                          f"names: {files[i].name} at {t[i]!r} s follows {files[i - 1].name} at {t[i - 1]!r} s")
    if t.size < 2:
        raise SourceError(f"{path}: source.times_csv: one frame has no interval to stand for: "
                          "give fps instead (or more frames)")
    return t


def exposure_taps(scene, clock: Clock, mode: str, index: int):
    """Per radiance node of frame `index`'s exposure, the (input frame, weight) pairs of its sample."""
    times = scene.subframe_times_s(index)
    if mode != "integrate":
        return [clock.taps_at(float(t), mode) for t in times]
    a, b = scene.exposure_window_s(index)
    cuts = np.concatenate([[a], 0.5 * (times[1:] + times[:-1]), [b]])
    return [clock.taps_over(float(lo), float(hi)) for lo, hi in zip(cuts[:-1], cuts[1:])]


def check_covers(scene, clock: Clock, mode: str, where: str) -> None:
    """Every sample of every exposure of the run lies inside the frames' time span."""
    lo, hi = clock.span_s(mode)
    tol = 1e-12 * max(1.0, abs(lo), abs(hi))
    for i in range(scene.timing.frames):
        a, b = scene.exposure_window_s(i)
        need = scene.subframe_times_s(i) if mode != "integrate" else np.array([a, b])
        if need.min() < lo - tol or need.max() > hi + tol:
            t = need.min() if need.min() < lo - tol else need.max()
            raise SourceError(f"{where}: source.frames: the {clock.times_s.size} frames cover t = "
                              f"[{lo:.6g}, {hi:.6g}] s for subframes = {mode!r}, but frame {i}'s "
                              f"exposure needs t = {t:.6g} s: give more frames (or times), or fewer "
                              f"timing.frames")


# ---------------------------------------------------------------------------- space
def _axis_weights(n_in: int, guard_in: int, n_field: int, guard_m: int):
    """Area-resampling matrix (mirrors x input pixels) of one axis, and the number of mirrors on
    each side whose footprint reaches beyond the input (edge-replicated)."""
    n_m = n_field + 2 * guard_m
    step = (n_in - 2 * guard_in) / n_field           # input pixels per mirror
    edges = guard_in + (np.arange(n_m + 1, dtype=np.float64) - guard_m) * step
    w = np.zeros((n_m, n_in))
    low = high = 0
    for p in range(n_m):
        a, b = edges[p], edges[p + 1]
        if a < 0:
            w[p, 0] += min(b, 0.0) - a
            low += 1
        if b > n_in:
            w[p, n_in - 1] += b - max(a, float(n_in))
            high += 1
        for i in range(max(int(math.floor(a)), 0), min(int(math.ceil(b)), n_in)):
            overlap = min(b, i + 1.0) - max(a, float(i))
            if overlap > 0:
                w[p, i] += overlap
    return w / (edges[1:] - edges[:-1])[:, None], (low, high)


@dataclass(frozen=True)
class AreaMap:
    """Input frame (guard_in px beyond the field) -> mirror grid (guard_m mirrors beyond it)."""

    in_shape: tuple[int, int]
    guard_in_px: int
    field_shape: tuple[int, int]
    guard_m_px: int
    wy: np.ndarray = field(repr=False)
    wx: np.ndarray = field(repr=False)
    replicated: tuple[int, int, int, int] = (0, 0, 0, 0)   # mirrors beyond the input: top, bottom, left, right

    @classmethod
    def build(cls, in_shape, guard_in_px: int, field_shape, guard_m_px: int) -> "AreaMap":
        wy, (top, bottom) = _axis_weights(in_shape[0], guard_in_px, field_shape[0], guard_m_px)
        wx, (left, right) = _axis_weights(in_shape[1], guard_in_px, field_shape[1], guard_m_px)
        return cls(tuple(in_shape), guard_in_px, tuple(field_shape), guard_m_px, wy, wx,
                   (top, bottom, left, right))

    @property
    def is_identity(self) -> bool:
        return self.wy.shape[0] == self.wy.shape[1] and self.wx.shape[0] == self.wx.shape[1] and \
            np.array_equal(self.wy, np.eye(self.wy.shape[0])) and np.array_equal(self.wx, np.eye(self.wx.shape[0]))

    def apply(self, img: np.ndarray) -> np.ndarray:
        """The input image (float64) on the mirror grid (float64)."""
        if self.is_identity:
            return np.asarray(img, dtype=np.float64)
        from scipy import sparse

        wy, wx = sparse.csr_matrix(self.wy), sparse.csr_matrix(self.wx)
        return np.asarray((wx @ (wy @ np.asarray(img, dtype=np.float64)).T).T)

    def box(self, box: "Box") -> tuple[int, int, int, int] | None:
        """A box in input pixels as the mirror-grid box (y0, x0, y1, x1) covering it, clipped."""
        (h_in, w_in), (h, w), g, gm = self.in_shape, self.field_shape, self.guard_in_px, self.guard_m_px
        sy, sx = h / (h_in - 2 * g), w / (w_in - 2 * g)
        hm, wm = h + 2 * gm, w + 2 * gm
        y0 = int(np.clip(math.floor(gm + (box.y0 - g) * sy), 0, hm))
        y1 = int(np.clip(math.ceil(gm + (box.y1 - g) * sy), 0, hm))
        x0 = int(np.clip(math.floor(gm + (box.x0 - g) * sx), 0, wm))
        x1 = int(np.clip(math.ceil(gm + (box.x1 - g) * sx), 0, wm))
        return (y0, x0, y1, x1) if y1 > y0 and x1 > x0 else None

    def scale_px(self) -> tuple[float, float]:
        """Mirrors per input pixel (y, x)."""
        (h_in, w_in), (h, w), g = self.in_shape, self.field_shape, self.guard_in_px
        return h / (h_in - 2 * g), w / (w_in - 2 * g)

    def note(self) -> str | None:
        if not any(self.replicated):
            return None
        t, b, l, r = self.replicated
        return (f"guard band: the camera's guard band of {self.guard_m_px} mirrors reaches beyond the "
                f"frames' {self.guard_in_px} px border (source.guard_px) over {t}/{b}/{l}/{r} mirror rows/"
                f"rows/columns/columns (top/bottom/left/right): there the frames' edge pixels are "
                f"continued outward (edge replication), so light beyond the frames' field is a guess")


def check_aspect(in_shape, guard_in_px: int, field_shape, where: str, key: str) -> None:
    """The frames' field has the aspect of render.resolution (at most 1 px of distortion)."""
    h_in, w_in = in_shape
    fh, fw = h_in - 2 * guard_in_px, w_in - 2 * guard_in_px
    if fh < 1 or fw < 1:
        raise SourceError(f"{where}: source.guard_px: {guard_in_px} px on each side leaves no field "
                          f"in {h_in}x{w_in} frames")
    h, w = field_shape
    if abs((fh / h) / (fw / w) - 1.0) * max(h, w) > 1.0:
        raise SourceError(f"{where}: {key}: the frames' field is {fh}x{fw} px, not of the aspect of "
                          f"render.resolution {h}x{w} (more than 1 px of distortion): crop the frames "
                          "or change render.resolution")


# ---------------------------------------------------------------------------- boxes
@dataclass(frozen=True)
class Box:
    """A plate box in input pixels (edges; x1, y1 exclusive) and its text (may be empty)."""

    x0: float
    y0: float
    x1: float
    y1: float
    text: str = ""

    @property
    def center_xy(self) -> tuple[float, float]:
        return 0.5 * (self.x0 + self.x1), 0.5 * (self.y0 + self.y1)


def _csv_rows(path: Path, columns: Sequence[str], key: str):
    try:
        with open(path, newline="") as f:
            reader = csv.DictReader(line for line in f if line.strip() and not line.lstrip().startswith("#"))
            header = [c.strip() for c in (reader.fieldnames or [])]
            missing = [c for c in columns if c not in header]
            if missing:
                raise SourceError(f"{path}: {key}: the header {','.join(header) or '(none)'} lacks "
                                  f"column {missing[0]!r} (expected {','.join(columns)})")
            return [(reader.line_num, {k.strip(): (v or "") for k, v in row.items() if k}) for row in reader]
    except UnicodeDecodeError:
        raise SourceError(f"{path}: {key}: not a UTF-8 text file") from None


def _csv_float(path, line, row, col, key) -> float:
    try:
        v = float(row[col])
    except ValueError:
        raise SourceError(f"{path}:{line}: {key}: column {col}: not a number: {row[col]!r}") from None
    if not math.isfinite(v):
        raise SourceError(f"{path}:{line}: {key}: column {col}: must be finite, got {row[col]!r}")
    return v


def read_boxes_csv(path: Path, n_frames: int, frame_shape: tuple[int, int]) -> dict[int, Box]:
    """Plate boxes per frame from `frame,x0,y0,x1,y1[,text]`; a frame may have no row (no plate)."""
    out: dict[int, Box] = {}
    h, w = frame_shape
    for line, row in _csv_rows(path, ("frame", "x0", "y0", "x1", "y1"), "source.boxes"):
        try:
            j = int(row["frame"])
        except ValueError:
            raise SourceError(f"{path}:{line}: source.boxes: column frame: not an integer: {row['frame']!r}") from None
        if not 0 <= j < n_frames:
            raise SourceError(f"{path}:{line}: source.boxes: frame {j} is not one of the {n_frames} "
                              f"frames (0 ... {n_frames - 1}, in sorted order)")
        if j in out:
            raise SourceError(f"{path}:{line}: source.boxes: frame {j} has a second row (one plate per frame)")
        x0, y0, x1, y1 = (_csv_float(path, line, row, c, "source.boxes") for c in ("x0", "y0", "x1", "y1"))
        if not (x1 > x0 and y1 > y0):
            raise SourceError(f"{path}:{line}: source.boxes: empty box (need x1 > x0 and y1 > y0), got "
                              f"x0={x0:g} y0={y0:g} x1={x1:g} y1={y1:g}")
        if x1 <= 0 or y1 <= 0 or x0 >= w or y0 >= h:
            raise SourceError(f"{path}:{line}: source.boxes: box x0={x0:g} y0={y0:g} x1={x1:g} y1={y1:g} "
                              f"lies outside the {h}x{w} frames")
        out[j] = Box(x0, y0, x1, y1, row.get("text", "").strip())
    return out


# ---------------------------------------------------------------------------- the source
class FrameSequenceSource:
    """A sequence of frames as the run's radiance source.

    It offers what the run loop reads from the Mitsuba source (render/radiance.py: `guard_px`,
    `plan`, `stats`, `variant`, `variant_reason`, `exposures()`, `temporal_skip`) and, for the
    step-halving estimate of apps/run/temporal_check.py, the radiance at any time (`set_time`,
    `render_once`; no Monte Carlo: seeds and spp are unused). Subclasses read frame j as
    absolute photon radiance on the input grid (`load`).
    """

    kind = ""

    def __init__(self, scene, guard_px: int, files: Sequence[Path], clock: Clock, in_shape,
                 guard_in_px: int, boxes: dict[int, Box], reason: str, notes: Sequence[str] = ()):
        self.scene = scene
        self.guard_px = int(guard_px)
        self.files = list(files)
        self.clock = clock
        self.mode = scene.source.subframes
        where = str(scene.origin or scene.toml_path)
        check_aspect(in_shape, guard_in_px, scene.render.resolution, where, "source.frames")
        check_covers(scene, clock, self.mode, where)
        self.area = AreaMap.build(in_shape, guard_in_px, scene.render.resolution, self.guard_px)
        self.boxes = boxes
        notes = list(notes)
        if self.area.note():
            notes.append(self.area.note())
        self.plan = SourcePlan(self.kind, reason, tuple(notes))
        self.variant = "none"
        self.variant_reason = f"no Mitsuba render: radiance from [source] kind = {self.kind!r}"
        self.stats = SourceStats()
        self._cache: dict[int, np.ndarray] = {}
        self._time = None

    # ------------------------------------------------------------------ frames
    def load(self, j: int) -> np.ndarray:
        """Frame j as absolute sensor-weighted photon radiance (float64, input grid)."""
        raise NotImplementedError

    def frame_name(self, j: int) -> str:
        """How the report names input frame j."""
        return self.files[j].name

    def frames_used(self) -> list[int]:
        """Input frames the run's exposures read, in order."""
        used = set()
        for i in range(self.scene.timing.frames):
            for taps in exposure_taps(self.scene, self.clock, self.mode, i):
                used.update(j for j, _ in taps)
        return sorted(used)

    def frame(self, j: int) -> np.ndarray:
        """Frame j on the mirror grid (float64), cached."""
        if j not in self._cache:
            t = time.perf_counter()
            self._cache[j] = self.area.apply(self.load(j))
            self.stats.calls += 1
            self.stats.seconds += time.perf_counter() - t
        return self._cache[j]

    def sample(self, taps) -> np.ndarray:
        """Sum of weight x frame over `taps` (float64), as float32 (one frame: an exact copy)."""
        if len(taps) == 1:
            return self.frame(taps[0][0]).astype(np.float32)
        acc = 0.0
        for j, w in taps:
            acc = acc + w * self.frame(j)
        return np.asarray(acc, dtype=np.float32)

    # ------------------------------------------------------------------ exposures
    def exposures(self, progress: bool = True):
        """Yield a `core.frame.RenderedExposure` per frame: the K radiance samples from the input frames,
        their time mean (the weights of `RenderScene.subframe_weights`, summed as the Mitsuba path
        sums them), the plate ROI and ground truth from the boxes. No Monte Carlo error: the
        variance is zero and rel_error None."""
        from tqdm import tqdm

        scene = self.scene
        for i in tqdm(range(scene.timing.frames), desc=f"read {scene.name}", unit="frame",
                      disable=not progress or None, leave=False):
            t0, t1 = scene.exposure_window_s(i)
            times = scene.subframe_times_s(i)
            weights = scene.subframe_weights(i)
            all_taps = exposure_taps(scene, self.clock, self.mode, i)
            used = sorted({j for taps in all_taps for j, _ in taps})
            for j in [j for j in self._cache if j < used[0]]:
                del self._cache[j]
            subs = [self.sample(taps) for taps in all_taps]
            mean = 0.0
            for k, m in enumerate(subs):
                mean = mean + weights[k] * m.astype(np.float64)
            mean = np.asarray(mean, dtype=np.float32)
            var = np.zeros(mean.shape)
            roi, truth = self.truth(used)
            yield RenderedExposure.build(i, t0, t1, times, subs, mean, var, roi, ground_truth=truth)

    def truth(self, used: Sequence[int]):
        """ROI (mirror grid: the union of the used frames' boxes) and ground truth: plate text,
        input frames read, and the plate's image velocity (mirrors per s, from the box centres of
        the first and last used frames that have boxes)."""
        roi = None
        boxed = [j for j in used if j in self.boxes]
        for j in boxed:
            b = self.area.box(self.boxes[j])
            if b is not None:
                roi = b if roi is None else (min(roi[0], b[0]), min(roi[1], b[1]), max(roi[2], b[2]), max(roi[3], b[3]))
        texts = sorted({self.boxes[j].text for j in boxed if self.boxes[j].text})
        velocity = None
        if len(boxed) >= 2:
            sy, sx = self.area.scale_px()
            (ax, ay), (bx, by) = self.boxes[boxed[0]].center_xy, self.boxes[boxed[-1]].center_xy
            dt = self.clock.times_s[boxed[-1]] - self.clock.times_s[boxed[0]]
            velocity = [(bx - ax) * sx / dt, (by - ay) * sy / dt]
        truth = {"source": self.kind, "frames": [self.frame_name(j) for j in used],
                 "text": " | ".join(texts), "plate_velocity_px_per_s": velocity}
        return roi, truth

    # ------------------------------------------------------------------ time queries
    def set_time(self, t_s: float) -> None:
        self._time = float(t_s)

    def render_once(self, seed: int = 0, spp: int = 0) -> np.ndarray:
        """The source's radiance at the time of `set_time` (float32, mirror grid)."""
        return self.sample(self.clock.taps_at(self._time, self.mode))

    @property
    def temporal_skip(self) -> str | None:
        """Why the time-quadrature error (apps/run/temporal_check.py, step halving on the source's
        L(t)) is not estimated, or None when it is: `integrate` samples are interval means."""
        if self.mode == "integrate":
            return ("not estimated: subframes = 'integrate' samples are the input's means over each "
                    "node's interval (exact for an all-white exposure), not L(t)")
        return None


def check_frames(source: FrameSequenceSource) -> SourcePlan:
    """Read every frame a run uses (each read checks its size and values); return the plan."""
    for j in source.frames_used():
        source.load(j)
    return source.plan
