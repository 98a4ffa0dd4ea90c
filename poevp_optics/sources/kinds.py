"""[source]: where a run's radiance comes from, by kind (`SOURCES`), and its parameters.

| kind          | radiance                                                        | reference |
|---------------|-----------------------------------------------------------------|-----------|
| mitsuba       | the scene's XML rendered by Mitsuba 3 (default; render/)        | Jakob et al., Mitsuba 3 (2022) |
| exr_sequence  | HDR frames from another renderer or an HDR camera, in stated units | OpenEXR (ASWF) |
| ldr_highlight | an LDR video, linearised, with the paper's artificial highlight H = O (E G + 1) | He et al., Photonics Research 12(11) 2524 (2024), Eq. 3 |

`SourceSpec` holds every kind's keys (each kind's module tables its keys, units and defaults;
`SourceKind.keys` says which apply, scene/validate.py refuses the others). Every kind opens as an
object with the interface the render run reads (`guard_px`, `plan` with mode/reason/notes,
`stats`, `variant`, `variant_reason`, `exposures(progress)` yielding core.frame.RenderedExposure,
`temporal_skip`, `set_time`, `render_once`), built from the scene, the camera's guard band and
the sensor's QE table: frame kinds by `SourceKind.open` (frames.py), the mitsuba kind by
render/radiance.py (`open` is None here: sources/ imports only core).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from poevp_optics.core.params import param
from poevp_optics.core.registry import Registry
from poevp_optics.sources import exr_sequence, ldr_highlight, mitsuba_source
from poevp_optics.sources.frames import SUBFRAME_MODES, FrameSequenceSource, SourcePlan, check_frames


@dataclass(frozen=True)
class SourceKind:
    """One [source] kind: the keys it takes, their combination check (raises
    frames.SourceKeyError), how it opens, (scene, guard_px, sensor_qe) -> source (None: rendered
    by render/radiance.py), and the files it reads besides the TOML."""

    keys: tuple[str, ...]
    check_keys: Callable[[object, frozenset, Path], None]
    open: Callable[[object, int, str], FrameSequenceSource] | None
    files: Callable[[object], list]


SOURCES = Registry("[source] kind")
SOURCES.register("mitsuba", SourceKind(mitsuba_source.KEYS, mitsuba_source.check_keys, None,
                                       mitsuba_source.input_files),
                 source="Jakob, Speierer, Roussel, Vicini, Mitsuba 3 renderer (2022); render/renderer.py")
SOURCES.register("exr_sequence", SourceKind(exr_sequence.KEYS, exr_sequence.check_keys, exr_sequence.open_source,
                                            exr_sequence.input_files),
                 source="OpenEXR (Academy Software Foundation); sources/exr_sequence.py")
SOURCES.register("ldr_highlight", SourceKind(ldr_highlight.KEYS, ldr_highlight.check_keys,
                                             ldr_highlight.open_source, ldr_highlight.input_files),
                 source="He et al., Photonics Research 12(11), 2524 (2024), Eq. 3 and Sec. 6; "
                        "sources/ldr_highlight.py")

#: What the values of an EXR source are (exr_sequence.UNITS).
EXR_UNITS = tuple(exr_sequence.UNITS)


@dataclass(frozen=True)
class SourceSpec:
    """[source]: where the radiance comes from (`SOURCES`; each kind's keys, units and defaults
    are tabled in its module). NaN / "" / -1 mean "not given"."""

    kind: str = param("mitsuba", choices=SOURCES)
    frames: str = param("")                             # glob, relative to the scene's folder, sorted
    video: str = param("")                              # ldr_highlight: one video file (OpenCV)
    channel: str = param("Y")                           # exr_sequence: the EXR channel
    unit: str = param("", choices=EXR_UNITS)            # exr_sequence: what the values are (required)
    spectrum: str = param("")                           # SPD of the light (core/spectra.py source)
    scale: float = param(math.nan, gt=0)                # e- s-1 m-2 sr-1 per value (per linear 1: LDR)
    luminance_cd_per_m2: float = param(math.nan, gt=0)  # photometric anchor (with spectrum)
    reference_pixel: tuple[int, int] = param((-1, -1), length=2, min=0, unset=-1)   # [y, x], input px
    reference_frame: int = param(0, min=0)
    fps: float = param(math.nan, gt=0, max=1e7)         # frames per second of the sequence
    t0_s: float = param(0.0)                            # scene-clock time of frame 0 (may be < 0)
    times_csv: str = param("")                          # exr_sequence: per-frame times, CSV file,t_s
    subframes: str = param("linear", choices=SUBFRAME_MODES)   # how a radiance sample comes from frames
    guard_px: int = param(0, min=0, max=65536)          # exr_sequence: border beyond the field, input px
    boxes: str = param("")                              # plate boxes, CSV frame,x0,y0,x1,y1[,text]
    box: tuple[float, ...] = param(())                  # ldr_highlight: constant [x0, y0, x1, y1], input px
    text: str = param("")                               # ldr_highlight: plate text with `box`
    transfer: str = param("srgb", choices=ldr_highlight.TRANSFERS)
    gamma: float = param(2.2, gt=0, max=10.0)
    e: float = param(math.nan, min=0, max=1e9)          # Eq. 3 over-exposure rate E
    r_px: float = param(math.nan, gt=0, max=1e6)        # Eq. 3 radius R, px at 720x1280
    radius_rule: str = param("sigma", choices=ldr_highlight.RADIUS_RULES)
    e_domain: str = param("linear", choices=ldr_highlight.E_DOMAINS)   # Eq. 3 on linear or stored values

    @property
    def renders(self) -> bool:
        """True for the Mitsuba kind (the scene's XML is rendered), False for frame kinds."""
        return SOURCES[self.kind].open is None


def open_frames(scene, guard_px: int, sensor_qe: str) -> FrameSequenceSource:
    """A frame source (`[source] kind` other than mitsuba) on a mirror grid with `guard_px`
    mirrors beyond each edge of render.resolution; sensor_qe: the sensor's QE table (a
    core/spectra.py source), for units that need its response."""
    kind = SOURCES[scene.source.kind]
    if kind.open is None:
        raise ValueError(f"[source] kind {scene.source.kind!r} is rendered, not read: render/radiance.py opens it")
    return kind.open(scene, guard_px, sensor_qe)


def check_source(scene, guard_px: int, sensor_qe: str) -> SourcePlan:
    """Open a frame source and read every frame its run uses (sizes, values, times, boxes);
    frames.SourceError (one line: file and key) on the first problem."""
    return check_frames(open_frames(scene, guard_px, sensor_qe))


def source_files(scene) -> list[Path]:
    """The files a run's source reads besides the TOML (frames, CSVs, video); none for mitsuba."""
    return SOURCES[scene.source.kind].files(scene)
