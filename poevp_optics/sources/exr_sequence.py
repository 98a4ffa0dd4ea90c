"""[source] kind = "exr_sequence": HDR radiance frames from another renderer or an HDR camera.

| key                 | type       | unit                      | default  | what |
|---------------------|------------|---------------------------|----------|------|
| frames              | str        | -                         | required | glob of OpenEXR files, relative to the scene's folder, read in sorted order |
| channel             | str        | -                         | "Y"      | the channel read |
| unit                | str        | -                         | required | what the values are (`UNITS` below) |
| spectrum            | str        | -                         | -        | SPD of the light (core/spectra.py source): `radiance_w`, and `relative` with a luminance |
| scale               | float      | e- s-1 m-2 sr-1 per value | -        | `relative`: photon radiance of the value 1 |
| luminance_cd_per_m2 | float      | cd m-2                    | -        | `relative`: luminance at `reference_pixel` |
| reference_pixel     | [int, int] | input px [y, x]           | -        | `relative`: where that luminance is |
| reference_frame     | int        | -                         | 0        | `relative`: in which frame (sorted index) |
| fps                 | float      | frames s-1                | -        | frame j shows t0_s + j / fps (or `times_csv`) |
| t0_s                | float      | s                         | 0        | scene-clock time of frame 0 |
| times_csv           | str        | -                         | -        | per-frame times instead of fps: CSV `file,t_s` |
| subframes           | str        | -                         | "linear" | nearest, linear or integrate (frames.py) |
| guard_px            | int        | input px                  | 0        | border beyond the sensor's field the frames hold, each side |
| boxes               | str        | -                         | -        | plate boxes, CSV `frame,x0,y0,x1,y1[,text]`: ROI and ground truth |

`UNITS` (S = QE lambda / (h c), the scene's sensor response, spectra.sensor_response_e_per_J;
QE: the sensor's table, handed over by whoever opens the source, render/radiance.py):

| unit            | the values are                                              | photon radiance = |
|-----------------|-------------------------------------------------------------|-------------------|
| photon_radiance | sensor-weighted photon radiance, e- s-1 m-2 sr-1, for this scene's sensor (what `poevp render` writes) | value |
| radiance_w      | radiance, W m-2 sr-1 over 360-830 nm, of light with SPD `spectrum` | value x integral(S spd) / integral(spd) |
| relative        | proportional to radiance                                    | value x scale, or value x luminance_cd_per_m2 x integral(S spd) / (K_m integral(V spd)) / value at reference_pixel |

Reference: OpenEXR (Academy Software Foundation), read with its Python binding (core/io.py read_exr).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Iterable

import numpy as np

from poevp_optics.sources import spectra
from poevp_optics.sources.frames import (Clock, FrameSequenceSource, SourceError, SourceKeyError,
                                         check_clock_keys, check_file_keys, check_spectrum_key, frame_files,
                                         photon_radiance_per_cd_per_m2, photon_radiance_per_w, read_boxes_csv,
                                         read_times_csv, resolve_path)

KEYS = ("frames", "channel", "unit", "spectrum", "scale", "luminance_cd_per_m2", "reference_pixel",
        "reference_frame", "fps", "t0_s", "times_csv", "subframes", "guard_px", "boxes")

#: What the values of an EXR source are (module docstring).
UNITS = {
    "photon_radiance": "sensor-weighted photon radiance, e- s-1 m-2 sr-1 (this scene's sensor)",
    "radiance_w": "radiance, W m-2 sr-1, of light with SPD `spectrum`",
    "relative": "proportional to radiance: `scale`, or `luminance_cd_per_m2` at `reference_pixel` + `spectrum`",
}

_ANCHORS = ("spectrum", "scale", "luminance_cd_per_m2", "reference_pixel", "reference_frame")


def check_keys(src, given: frozenset[str], base_dir: Path) -> None:
    """The combinations of keys a unit needs; the files named exist."""
    if "frames" not in given:
        raise SourceKeyError("frames", "required for kind = 'exr_sequence': a glob of EXR files, "
                             "e.g. 'frames/*.exr' (relative to the scene's folder)")
    if "unit" not in given:
        raise SourceKeyError("unit", "required for kind = 'exr_sequence': what the values are: "
                             + "; ".join(f"{k!r} = {v}" for k, v in UNITS.items()))
    if src.unit == "photon_radiance":
        allowed = ()
    elif src.unit == "radiance_w":
        allowed = ("spectrum",)
        if "spectrum" not in given:
            raise SourceKeyError("spectrum", "required for unit = 'radiance_w': the SPD of the light "
                                 "(a spectra.py source such as 'cie:LED-B4'), to weight W by the sensor's response")
    else:
        if ("scale" in given) == ("luminance_cd_per_m2" in given):
            raise SourceKeyError("scale", "unit = 'relative' needs one absolute anchor: scale (e- s-1 "
                                 "m-2 sr-1 per value) or luminance_cd_per_m2 (with reference_pixel and spectrum)")
        if "scale" in given:
            allowed = ("scale",)
        else:
            allowed = ("luminance_cd_per_m2", "reference_pixel", "reference_frame", "spectrum")
            for k in ("reference_pixel", "spectrum"):
                if k not in given:
                    raise SourceKeyError(k, "required with luminance_cd_per_m2 (the pixel [y, x] whose "
                                         "luminance it is, and the light's SPD)")
    extra = [k for k in _ANCHORS if k in given and k not in allowed]
    if extra:
        raise SourceKeyError(extra[0], f"does not apply to unit = {src.unit!r}")
    if "spectrum" in given:
        check_spectrum_key(src.spectrum)
    check_clock_keys(src, given, times_csv=True)
    check_file_keys(src, given, base_dir, ("times_csv", "boxes"))


def _header(path: Path, channel: str) -> tuple[int, int]:
    """(H, W) of an EXR file's data window; the file must hold `channel`."""
    import OpenEXR

    from poevp_optics.core.failures import quiet_native_stderr

    try:
        with quiet_native_stderr() as printed:                 # OpenEXR's own lines go in ours
            with OpenEXR.File(str(path), header_only=True) as f:   # read the header while open
                header = f.parts[0].header
                names = [c.name for c in header.get("channels", [])]
                lo, hi = (np.asarray(v).copy() for v in header["dataWindow"])
    except Exception as e:  # noqa: BLE001 - the binding raises RuntimeError/OSError variants
        msg = " ".join(f"{e} {' '.join(printed)}".split())[:300]
        raise SourceError(f"{path}: source.frames: not an OpenEXR file that can be read ({msg})") from None
    if channel not in names:
        raise SourceError(f"{path}: source.channel: no channel {channel!r} (channels: {', '.join(names) or 'none'})")
    return int(hi[1] - lo[1] + 1), int(hi[0] - lo[0] + 1)


def read_values(path: Path, channel: str, shape: tuple[int, int] | None = None) -> np.ndarray:
    """One channel of an EXR frame (float64), checked: readable, the expected size, finite, >= 0."""
    from poevp_optics.core.io import read_exr

    try:
        chans, _ = read_exr(path)
    except Exception as e:  # noqa: BLE001
        raise SourceError(f"{path}: source.frames: not an OpenEXR file that can be read ({e})") from None
    if channel not in chans:
        raise SourceError(f"{path}: source.channel: no channel {channel!r} (channels: {', '.join(chans) or 'none'})")
    v = chans[channel]
    if shape is not None and v.shape != tuple(shape):
        raise SourceError(f"{path}: source.frames: {v.shape[0]}x{v.shape[1]} px, but the first frame is "
                          f"{shape[0]}x{shape[1]}: every frame must have one size")
    bad = ~np.isfinite(v)
    if bad.any():
        raise SourceError(f"{path}: source.frames: {int(bad.sum())} NaN/Inf values in channel {channel!r}")
    neg = v < 0
    if neg.any():
        raise SourceError(f"{path}: source.frames: {int(neg.sum())} negative values in channel {channel!r} "
                          f"(min {float(v.min()):.4g}): radiance is >= 0")
    return v.astype(np.float64)


class ExrSequenceSource(FrameSequenceSource):
    """EXR frames read as absolute photon radiance (module docstring); `sensor_qe`: the
    sensor's QE table (a spectra.py source) for the units that need the sensor's response."""

    kind = "exr_sequence"

    def __init__(self, scene, guard_px: int, sensor_qe: str):
        src = scene.source
        base = scene.toml_path.parent
        where = str(scene.origin or scene.toml_path)
        files = frame_files(base, src.frames)
        if not files:
            raise SourceError(f"{where}: source.frames: no file matches {src.frames!r} (relative to {base})")
        shape = _header(files[0], src.channel)
        for f in files[1:]:
            s = _header(f, src.channel)
            if s != shape:
                raise SourceError(f"{f}: source.frames: {s[0]}x{s[1]} px, but {files[0].name} is "
                                  f"{shape[0]}x{shape[1]}: every frame must have one size")
        self.shape_in = shape
        if src.times_csv:
            clock = Clock.from_times(read_times_csv(resolve_path(base, src.times_csv), files))
            when = f"times from {src.times_csv}"
        else:
            if len(files) == 1 and src.subframes == "linear":
                raise SourceError(f"{where}: source.subframes: 'linear' needs two frames or more; "
                                  "one frame: 'nearest' (it then stands for 1/fps)")
            clock = Clock.uniform(len(files), src.fps, src.t0_s)
            when = f"{src.fps:g} fps from t0_s = {src.t0_s:g} s"
        boxes = read_boxes_csv(resolve_path(base, src.boxes), len(files), shape) if src.boxes else {}
        self.factor, how = self._unit_factor(scene, files, shape, sensor_qe)
        reason = (f"{len(files)} EXR frames {shape[0]}x{shape[1]} ({src.frames}, channel {src.channel!r}), "
                  f"unit {src.unit}: {how}; {when}; samples by {src.subframes!r}")
        super().__init__(scene, guard_px, files, clock, shape, src.guard_px, boxes, reason)

    def _unit_factor(self, scene, files, shape, sensor_qe: str) -> tuple[float, str]:
        """Photon radiance per value (e- s-1 m-2 sr-1 per unit of the file) and how it was found."""
        src = scene.source
        if src.unit == "photon_radiance":
            return 1.0, "values are photon radiance"
        response = spectra.sensor_response_e_per_J(spectra.load_spectrum(sensor_qe, emissive=True))
        if src.unit == "radiance_w":
            k = photon_radiance_per_w(src.spectrum, response)
            return k, f"x {k:.6g} e- J-1 (sensor response over the SPD {src.spectrum})"
        if not math.isnan(src.scale):
            return src.scale, f"x scale = {src.scale:g}"
        where = str(scene.origin or scene.toml_path)
        if src.reference_frame >= len(files):
            raise SourceError(f"{where}: source.reference_frame: {src.reference_frame} is not one of the "
                              f"{len(files)} frames")
        y, x = src.reference_pixel
        if not (0 <= y < shape[0] and 0 <= x < shape[1]):
            raise SourceError(f"{where}: source.reference_pixel: [{y}, {x}] lies outside the "
                              f"{shape[0]}x{shape[1]} frames")
        ref_file = files[src.reference_frame]
        v = float(read_values(ref_file, src.channel, shape)[y, x])
        if not v > 0:
            raise SourceError(f"{ref_file}: source.reference_pixel: the value at [{y}, {x}] is {v:g}: "
                              "a luminance anchor needs a pixel with light")
        k = src.luminance_cd_per_m2 * photon_radiance_per_cd_per_m2(src.spectrum, response) / v
        return k, (f"x {k:.6g} ({src.luminance_cd_per_m2:g} cd m-2 of {src.spectrum} at [{y}, {x}] of "
                   f"{ref_file.name}, value {v:g})")

    def load(self, j: int) -> np.ndarray:
        v = read_values(self.files[j], self.scene.source.channel, self.shape_in)
        return v if self.factor == 1.0 else v * self.factor


def open_source(scene, guard_px: int, sensor_qe: str) -> ExrSequenceSource:
    return ExrSequenceSource(scene, guard_px, sensor_qe)


def input_files(scene) -> list[Path]:
    """The files a run of this source reads (for sweep records)."""
    src, base = scene.source, scene.toml_path.parent
    return frame_files(base, src.frames) + [resolve_path(base, n) for n in (src.times_csv, src.boxes) if n]


# ---------------------------------------------------------------------------- export
def export_exr_sequence(exposures: Iterable, folder: Path, *, guard_px: int, plate_text: str = "",
                        scene_name: str = "") -> dict:
    """Write every radiance sample of `exposures` (core.frame.RenderedExposure, mirror grid) as an
    `exr_sequence` source: `folder/sample_IIII_KKK.exr` (channel Y, photon radiance, float32),
    `folder/times.csv` (each sample's time, exact: repr of the float) and `folder/boxes.csv` (each
    sample's exposure ROI, plate_text). Returns the [source] keys (paths relative to folder's
    parent) that replay them: with `nearest` or `linear` the run gets back exactly these samples.

    Raises ValueError for exposures that are not time samples (emitter-group images of PWM
    lamps) or whose sample times repeat (exposures that touch: one time, two renders)."""
    from poevp_optics.core.io import atomic_path, write_exr
    from poevp_optics.core.units import PHOTON_RADIANCE_UNIT

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    times, boxes, last = [], [], -math.inf
    for ex in exposures:
        if ex.basis:
            raise ValueError(f"frame {ex.index}: emitter-group images (PWM lamps), not time samples")
        for k, (t, sub) in enumerate(zip(ex.subframe_times_s, ex.subframes)):
            t = float(t)
            if not t > last:
                raise ValueError(f"frame {ex.index}: sample time {t!r} s does not follow {last!r} s: "
                                 "exposures that touch or overlap cannot be one time sequence")
            last = t
            name = f"sample_{ex.index:04d}_{k:03d}.exr"
            write_exr(folder / name, {"Y": sub},
                      {"poevp_quantity": "sensor-weighted photon radiance sample (mirror grid, guard band included)",
                       "poevp_unit": PHOTON_RADIANCE_UNIT, "poevp_t_s": repr(t), "poevp_frame": str(ex.index),
                       "poevp_scene": scene_name, "poevp_guard_px": str(guard_px)})
            times.append((name, t))
            if ex.roi is not None:
                y0, x0, y1, x1 = ex.roi
                boxes.append((len(times) - 1, x0, y0, x1, y1))
    with atomic_path(folder / "times.csv") as tmp:
        tmp.write_text("file,t_s\n" + "".join(f"{n},{t!r}\n" for n, t in times))
    text = plate_text.replace(",", " ")
    with atomic_path(folder / "boxes.csv") as tmp:
        tmp.write_text("frame,x0,y0,x1,y1,text\n" + "".join(f"{j},{x0},{y0},{x1},{y1},{text}\n"
                                                            for j, x0, y0, x1, y1 in boxes))
    rel = folder.name
    return {"kind": "exr_sequence", "frames": f"{rel}/sample_*.exr", "channel": "Y",
            "unit": "photon_radiance", "times_csv": f"{rel}/times.csv", "boxes": f"{rel}/boxes.csv",
            "guard_px": int(guard_px), "subframes": "nearest"}
