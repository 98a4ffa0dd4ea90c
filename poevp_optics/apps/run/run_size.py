"""How big a run is before it starts: CPU time and the bytes of its outputs; refused above limits.

CPU time (upper estimate; the render dominates): startup + path samples + per-pixel pipeline,

    cpu_s = STARTUP_CPU_S + frames x K x P_render x spp x CPU_S_PER_SAMPLE x (2 if spectral)
            + frames x P x CPU_S_PER_PX_FRAME

with P_render the rendered grid (sensor + guard band, memory.rendered_grid), K radiance samples
per exposure (memory.radiance_samples), spp the scene's (`render.max_spp` for an error-targeted
render: its most). Coefficients measured with user + system CPU of `poevp render scenes/smoke`
(llvm_ad_mono, 2 cores, this machine): 48x64 spp 4: 4.8 s; 184x320 spp 16: 7.3 s; spp 64:
21.6 s (slope 1.9e-7 s per sample); 368x640 spp 16: 14.5 s. The formula gives 4.1, 8.9, 23.4
and 26 s: an upper estimate within 2x. The spectral path (llvm_ad_spectral) at 184x320 spp 16:
9.2 s, its samples 1.4x the mono path's cost; SPECTRAL_FACTOR = 2 keeps the bound.

Disk bytes (upper bound: raw pixel bytes x 1.1 for compression overhead on noise, plus 4 KiB
per file for headers): per frame radiance EXR 8 B/px (Y + mc_stderr float32; [outputs]
radiance_exr), capture and LDR twin 1/2/4 B/px (8-bit PNG, 16-bit PNG, float32 EXR by
sensor.bits), mask 1 B/px, exposure 4 B/px, reconstruction 8 B/px, two previews 3 B/px each
([outputs] previews), sub-frames K x 4 B/px of the rendered grid ([outputs] subframes_exr);
plus report.json (16 KiB + 4 KiB per frame), contact sheet and timeline plot (256 KiB). Measured:
scenes/smoke writes 236 kB, the bound says 0.7 MB.

Limits (a run above one is refused before any work, unless `--yes`): POEVP_MAX_CPU_HOURS
(default 4 CPU-hours) and POEVP_MAX_DISK (default 20G; bytes or K/M/G/T suffix). Free space
is checked separately (core/io.check_free_space) and `--yes` does not skip it.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

from poevp_optics.core.exceptions import UserError

STARTUP_CPU_S = 5.0
CPU_S_PER_SAMPLE = 2.0e-7
CPU_S_PER_PX_FRAME = 1.0e-6
#: Spectral path cost per sample relative to the pre-integrated mono path (1.4 measured, module
#: docstring; 2 as a bound).
SPECTRAL_FACTOR = 2.0
COMPRESSION_SLACK = 1.1
FILE_OVERHEAD = 4096
REPORT_BYTES, REPORT_BYTES_PER_FRAME = 16 << 10, 4 << 10
FIXED_PLOTS_BYTES = 256 << 10

DEFAULT_MAX_CPU_HOURS = 4.0
DEFAULT_MAX_DISK = 20 << 30
#: A sweep's grid: most runs (points x seeds) and most values of one --grid key.
MAX_SWEEP_RUNS = 10_000
MAX_SEEDS = 1_000


class RunTooLarge(UserError):
    """A run above a stated limit (CPU time, disk, sweep points): one line, `--yes` to go on."""


@dataclass(frozen=True)
class RunSize:
    cpu_seconds: float
    disk_bytes: int
    files: int

    def __add__(self, other: "RunSize") -> "RunSize":
        return RunSize(self.cpu_seconds + other.cpu_seconds, self.disk_bytes + other.disk_bytes,
                       self.files + other.files)

    def times(self, n: int) -> "RunSize":
        return RunSize(self.cpu_seconds * n, self.disk_bytes * n, self.files * n)

    def describe(self) -> str:
        return f"about {format_cpu(self.cpu_seconds)}, {format_bytes(self.disk_bytes)} on disk ({self.files} files)"


def format_cpu(s: float) -> str:
    if s < 120:
        return f"{s:.0f} CPU-s"
    if s < 7200:
        return f"{s / 60:.0f} CPU-min"
    return f"{s / 3600:.1f} CPU-h"


def format_bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} PiB"


def _parse_bytes(text: str, name: str) -> int:
    t = text.strip().upper().removesuffix("B").removesuffix("I")
    mult = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}.get(t[-1:], 1)
    try:
        value = float(t[:-1] if mult > 1 else t) * mult
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value <= 0:
        raise UserError(f"{name}={text}: expected a size in bytes, e.g. 50G or 800M")
    return int(value)


def limits() -> tuple[float, int]:
    """(CPU seconds, disk bytes) above which a run is refused without --yes."""
    cpu_h = os.environ.get("POEVP_MAX_CPU_HOURS")
    try:
        cpu = float(cpu_h) * 3600 if cpu_h is not None else DEFAULT_MAX_CPU_HOURS * 3600
    except ValueError:
        cpu = math.nan
    if not math.isfinite(cpu) or cpu <= 0:
        raise UserError(f"POEVP_MAX_CPU_HOURS={cpu_h}: expected a positive number of hours")
    disk = os.environ.get("POEVP_MAX_DISK")
    return cpu, (_parse_bytes(disk, "POEVP_MAX_DISK") if disk is not None else DEFAULT_MAX_DISK)


def _capture_bytes(spec) -> int:
    from poevp_optics.camera.sensor import SENSOR_PRESETS

    bits = spec.sensor.bits if spec.sensor.bits != -1 else SENSOR_PRESETS[spec.sensor.preset].bits
    return 1 if bits <= 8 else 2 if bits <= 16 else 4


def estimate(spec, job: str = "render", *, mode: str | None = None) -> RunSize:
    """The run's CPU time and output bytes (module docstring). mode: the render path
    ("mono"/"spectral", renderer.plan_spectra; None: mono)."""
    from poevp_optics.apps.run.memory import radiance_samples, rendered_grid

    h, w = spec.render.resolution
    px = h * w
    rh, rw = rendered_grid(spec)
    k = radiance_samples(spec)
    frames = spec.timing.frames
    r = spec.render
    spp = r.max_spp if r.target_rel_error > 0 else r.spp
    samples = frames * k * rh * rw * spp if spec.source.renders else 0
    cpu = STARTUP_CPU_S + samples * CPU_S_PER_SAMPLE * (SPECTRAL_FACTOR if mode == "spectral" else 1.0)
    cpu += frames * px * CPU_S_PER_PX_FRAME * (spec.chart.repeats if job == "chart" else 1)
    o = spec.outputs
    cap = _capture_bytes(spec)
    per_px = cap + 4 + 8                                   # capture, exposure, reconstruction
    files = 3
    if spec.dmd.enabled:
        per_px += cap + 1                                  # LDR twin, mask
        files += 2
    if o.radiance_exr:
        per_px, files = per_px + 8, files + 1
    if o.previews:
        per_px, files = per_px + 6, files + 2
    per_frame = px * per_px
    if o.subframes_exr:
        per_frame += k * rh * rw * 4
        files += k
    disk = frames * (per_frame * COMPRESSION_SLACK + files * FILE_OVERHEAD)
    disk += REPORT_BYTES + frames * REPORT_BYTES_PER_FRAME + FIXED_PLOTS_BYTES
    return RunSize(float(cpu), int(disk), frames * files + 4)


def check(size: RunSize, *, where: str, yes: bool, what: str = "this run") -> None:
    """Refuse (RunTooLarge) a run above limits() unless `yes`."""
    if yes:
        return
    max_cpu, max_disk = limits()
    over = []
    if size.cpu_seconds > max_cpu:
        over.append(f"{format_cpu(size.cpu_seconds)} of CPU (limit {format_cpu(max_cpu)}, POEVP_MAX_CPU_HOURS)")
    if size.disk_bytes > max_disk:
        over.append(f"{format_bytes(size.disk_bytes)} on disk (limit {format_bytes(max_disk)}, POEVP_MAX_DISK)")
    if over:
        raise RunTooLarge(f"{where}: {what} needs about {' and '.join(over)}; make it smaller "
                          "(--frames, --resolution, --spp, --grid, --seeds) or give --yes to run it anyway")
