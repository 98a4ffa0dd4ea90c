"""Memory a run will need, estimated before it starts; a run that does not fit is refused.

The estimate is an upper bound: the sum of each part's peak (they partly follow one another
in time), with coefficients measured on this code with peak RSS (`ru_maxrss`) of `poevp render`
on scenes/smoke (llvm_ad_mono, 2 cores, numpy 2, DrJit 1.x):

| part            | bytes                                                  | measured                     |
|-----------------|--------------------------------------------------------|------------------------------|
| libraries       | 640 MiB (Python, Mitsuba/DrJit LLVM, colour, OpenCV), + 180 MiB where a torch network runs (`dmvfn`, `dmvfn_lite`) | 345 MiB at 64x64 here, 523 MiB with torch loaded; the CI runner (2 cores) peaked 140 MB above this machine on the same 512^2 run |
| frame pipeline  | P (300 + 16 K): film, K sub-frames, MC splits, DMD weights, sensor draws, reconstruction, EXR/PNG/tone-map buffers | 280-300 B/px at K = 2 (256^2 ... 2048^2), +6.4 B/px per extra sub-frame; spp does not matter (one wavefront per pixel) |
| held exposures  | compare only: frames x P (4 K + 8)                     | the exposures list it keeps  |
| exposure ahead  | render only: P (4 K + 8), the next frame rendered while the camera runs this one (render/ahead.py) | one frame of the list above |
| PSF             | kernel n^2 x 16 + build strips + FFT buffers (`relay.fft_bytes`) | +27 MB at 1024^2, sigma 20 |
| objective       | `objective.memory_bytes`: PSF grid, field_convolve's float64 images and kept node spectra, PSF and glare FFTs, K float32 DMD-plane images | bound from `objective.radius_bound_px` |
| DMD tables      | 4 x V x S x (K + 1) x 8: V levels, S = bits + 3 segments (x2 with settle) | 2.9-3.7 copies (`transmission_table` alone, V = 256 ... 65536, K = 16 ... 4096) |
| error target    | P x 16 K: each radiance sample's running mean and squared deviations (float64) while the frame renders to `render.target_rel_error` (render/progressive.py) | counted, not measured |
| JIT kernels     | K x 200 KiB + K^2 x 600 B: DrJit traces one gather and one FMA per sub-frame into one kernel | +80 MB at K = 256, +780 MB at K = 1024 (8x8 px) |
| registration    | P x 400 (area-weighted taps and their construction; `to_mirror`'s two float32 sampling maps, 8 B a mirror, kept) | 345 B/px at 1024^2 (the taps) + 8 B/px (the maps) |
| predictor       | `DMVFNConfig.activation_bytes` (upper bound), flow 100 B/px, track and track_net 160 B/px (they keep the last four frames' regions and outlines between calls) | dmvfn_lite 50 B/px; peak of one call at 368x640 (tracemalloc): flow 94, track_net 111, track 132 B/px |
| chart captures  | chart only: repeats x P x 40 (stacked estimates, flags, electrons) | -                   |

P = pixels of the rendered grid (the sensor plus the PSF's guard band), K = radiance samples per
exposure (uniform nodes + the DMD's switching times; 1 for static scenes; emitter groups for PWM
lamps). Available memory: MemAvailable of /proc/meminfo, lowered by a cgroup limit
(memory.max - memory.current) and by the environment variable POEVP_MEMORY_LIMIT (bytes, or
with a K/M/G suffix) when those are smaller.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from poevp_optics.core.exceptions import UserError

MIB = 1 << 20
GIB = 1 << 30
LIBRARIES_BYTES = 640 * MIB
#: What loading torch adds to a process's peak (measured: the same smoke run with torch imported).
TORCH_BYTES = 180 * MIB
PIPELINE_BYTES_PER_PX = 300
PIPELINE_BYTES_PER_PX_SUBFRAME = 16
TARGET_BYTES_PER_PX_SUBFRAME = 16       # Replicates.mean + .m2, float64
REGISTRATION_BYTES_PER_PX = 400
FLOW_BYTES_PER_PX = 100
TRACK_BYTES_PER_PX = 160
CHART_BYTES_PER_PX_REPEAT = 40
DMD_TABLE_COPIES = 4
JIT_BYTES_PER_SUBFRAME = 200 << 10
JIT_BYTES_PER_SUBFRAME_SQUARED = 600


class InsufficientMemory(UserError):
    """The run's estimated memory exceeds what the machine has available."""


@dataclass(frozen=True)
class Part:
    """One part of the estimate: bytes, and the scene key that sizes it (for the message)."""

    bytes: int
    key: str


@dataclass(frozen=True)
class MemoryEstimate:
    """Estimated peak bytes of a run, by part."""

    parts: dict[str, Part]

    @property
    def total_bytes(self) -> int:
        return sum(p.bytes for p in self.parts.values())

    @property
    def dominant(self) -> str:
        return max((k for k in self.parts if k != "libraries"), key=lambda k: self.parts[k].bytes)

    def describe(self, top: int = 3) -> str:
        order = sorted(self.parts, key=lambda k: -self.parts[k].bytes)[:top]
        return ", ".join(f"{k} {format_bytes(self.parts[k].bytes)}" for k in order)


def format_bytes(n: float) -> str:
    for unit, size in (("TiB", 1 << 40), ("GiB", GIB), ("MiB", MIB)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n / 1024:.0f} KiB"


def parse_bytes(text: str) -> int:
    """'4G', '512M', '1.5GiB', '1000000' -> bytes (binary multiples)."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([KMGT]?)(i?B)?\s*", str(text), re.IGNORECASE)
    if not m:
        raise ValueError(f"not a byte count: {text!r}")
    mult = {"": 1, "K": 1 << 10, "M": MIB, "G": GIB, "T": 1 << 40}[m.group(2).upper()]
    return int(float(m.group(1)) * mult)


def _cgroup_free_bytes() -> int | None:
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit == "max":
            return None
        return int(limit) - int(Path("/sys/fs/cgroup/memory.current").read_text())
    except (OSError, ValueError):
        return None


def available_bytes() -> tuple[int, str]:
    """Bytes this run may use and where the number comes from (see the module docstring)."""
    found = []
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                found.append((int(line.split()[1]) * 1024, "MemAvailable in /proc/meminfo"))
    except (OSError, ValueError, IndexError):
        pass
    cg = _cgroup_free_bytes()
    if cg is not None:
        found.append((max(cg, 0), "cgroup memory.max - memory.current"))
    env = os.environ.get("POEVP_MEMORY_LIMIT")
    if env:
        try:
            found.append((parse_bytes(env), f"POEVP_MEMORY_LIMIT={env}"))
        except ValueError:
            raise UserError(f"POEVP_MEMORY_LIMIT={env}: expected bytes, e.g. 4G or 512M") from None
    if not found:                       # not Linux: no reliable number, do not refuse
        return 1 << 62, "unknown (no /proc/meminfo)"
    return min(found)


# ---------------------------------------------------------------------------- parts
def _subframes(spec) -> int:
    """Radiance images per exposure: the nodes (K uniform + the DMD's switching times) when
    moving, 1 when static, 1 + lamps for PWM lamps."""
    if spec.is_static:
        return 1
    if spec.geometry_static:
        return 1 + len(spec.flicker)
    return len(spec.subframe_times_s(0))


def _kernel_px(spec) -> int:
    """Width of the relay kernel (1 when the stage is skipped), from the camera's resolved params
    (`spec.resolved.camera`) and the PSF context the camera builds (`relay_psf_context`)."""
    from poevp_optics.camera.camera import relay_psf_context
    from poevp_optics.camera.layout import layout_of
    from poevp_optics.camera.relay import kernel_size_px
    from poevp_optics.camera.sensor import resolve_sensor

    cp = spec.resolved.camera
    if cp.relay.psf == "delta" and cp.relay.glare_fraction <= 0:
        return 1
    layout = layout_of(cp.sensor, cp.dmd, cp.relay, cp.objective)
    ctx = relay_psf_context(resolve_sensor(cp.sensor), layout, cp.shape, cp.accuracy, cp.base_dir)
    return kernel_size_px(cp.relay, ctx)


def _objective_params(spec):
    """The [objective] keys resolved as the camera resolves them (None: the stage is skipped)."""
    from poevp_optics.camera.layout import objective_params_of

    from poevp_optics.camera.objective import with_accuracy

    cp = spec.resolved.camera
    return objective_params_of(cp.sensor, cp.dmd, cp.relay, with_accuracy(cp.objective, cp.accuracy))


def _render_shape(spec) -> tuple[int, int]:
    """The rendered (mirror) grid: the sensor plus the larger of the relay's and the objective's
    guard bands on each side (camera.py; each at most its guard_max_px, the relay's more for a
    registration that shrinks the image; the objective's from objective.radius_bound_px)."""
    from poevp_optics.camera.objective import radius_bound_px

    cp = spec.resolved.camera
    h, w = cp.shape
    g = min(_kernel_px(spec) // 2, cp.accuracy.guard_max_px)
    reg = cp.dmd.registration
    if cp.dmd.enabled and g and reg.scale < 1.0:
        g = int(g / reg.scale) + 1
    o = _objective_params(spec)
    if o is not None:
        g = max(g, min(radius_bound_px(o, (h, w)), o.guard_max_px))
    return h + 2 * g, w + 2 * g


def rendered_grid(spec) -> tuple[int, int]:
    """The rendered (mirror) grid's (H, W), guard bands included (apps/run/run_size.py)."""
    return _render_shape(spec)


def radiance_samples(spec) -> int:
    """Radiance images rendered per exposure (apps/run/run_size.py)."""
    return _subframes(spec)


def _objective_part(spec, k: int) -> Part | None:
    from poevp_optics.camera.objective import memory_bytes

    o = _objective_params(spec)
    if o is None:
        return None
    key = "objective.pupil_rays" if o.psf == "prescription" else "objective.glare_outer_radius_deg"
    return Part(memory_bytes(o, _render_shape(spec), k), key)


def _psf_part(spec) -> Part | None:
    from poevp_optics.camera.relay import DIRECT_MAX_PX, STRIP_SAMPLES, fft_bytes

    relay = spec.relay
    if relay.psf == "delta" and relay.glare_fraction <= 0:
        return None
    shape = _render_shape(spec)
    n = _kernel_px(spec)
    px = shape[0] * shape[1]
    nbytes = 2 * n * n * 8 + min(n * n * 49, STRIP_SAMPLES) * 8 * 4
    nbytes += fft_bytes(shape, n) if n > DIRECT_MAX_PX else 2 * px * 8
    key = ("relay.glare_sigma_px" if relay.glare_fraction > 0 and relay.psf in ("delta", "gaussian")
           and relay.glare_sigma_px > relay.sigma_px else
           {"gaussian": "relay.sigma_px", "airy": "relay.support_px",
            "measured": "relay.measured_file"}.get(relay.psf, "relay.glare_sigma_px"))
    return Part(nbytes, key)


def _dmd_part(spec, k: int) -> Part | None:
    from poevp_optics.camera.dmd import DMD

    if not spec.dmd.enabled:
        return None
    levels = (1 << spec.dmd.bits)
    px = _render_shape(spec)[0] * _render_shape(spec)[1]
    k_table = 1 if spec.geometry_static else k
    v = levels if levels * k_table <= DMD.FULL_TABLE_MAX else min(levels, px)
    segments = (spec.dmd.bits + 3) * (2 if spec.dmd.settle_s > 0 else 1)
    return Part(DMD_TABLE_COPIES * v * segments * (k_table + 1) * 8,
                "dmd.bits" if spec.dmd.bits > 10 else "render.subframes")


def _predictor_part(spec, job: str) -> Part | None:
    uses = spec.dmd.enabled and spec.predictor.name != "oracle"
    if job == "chart":
        uses = spec.dmd.enabled and spec.chart.mask_source == "loop"
    if not uses:
        return None
    h, w = spec.predictor.resolution
    if spec.predictor.name in ("dmvfn", "dmvfn_lite"):
        from poevp_optics.control.predictors.dmvfn_config import FULL, LITE

        cfg = LITE if spec.predictor.name == "dmvfn_lite" else FULL
        return Part(cfg.activation_bytes(h, w) + TORCH_BYTES, "predictor.resolution")
    per_px = TRACK_BYTES_PER_PX if spec.predictor.name in ("track", "track_net") else FLOW_BYTES_PER_PX
    return Part(per_px * h * w, "predictor.resolution")


def estimate_run(spec, job: str = "render") -> MemoryEstimate:
    """Upper bound of a run's peak memory by part (module docstring). job: "render",
    "compare" (keeps every frame's exposures) or "chart" (repeated captures of one render)."""
    h, w = _render_shape(spec)
    px = h * w
    k = _subframes(spec)
    parts = {"libraries": Part(LIBRARIES_BYTES, ""),
             "frame pipeline": Part(px * (PIPELINE_BYTES_PER_PX + PIPELINE_BYTES_PER_PX_SUBFRAME * k),
                                    "render.resolution")}
    if spec.render.target_rel_error > 0:
        parts["error target"] = Part(px * TARGET_BYTES_PER_PX_SUBFRAME * k, "render.target_rel_error")
    if k > 16:
        parts["JIT kernels"] = Part(k * JIT_BYTES_PER_SUBFRAME + k * k * JIT_BYTES_PER_SUBFRAME_SQUARED,
                                    "render.subframes")
    if job == "compare":
        parts["held exposures"] = Part(spec.timing.frames * px * (4 * k + 8), "timing.frames")
    if job == "render":
        parts["exposure ahead"] = Part(px * (4 * k + 8), "render.resolution")
    if job == "chart":
        parts["chart captures"] = Part(spec.chart.repeats * px * CHART_BYTES_PER_PX_REPEAT, "chart.repeats")
    optional = {"PSF": _psf_part(spec), "objective": _objective_part(spec, k), "DMD tables": _dmd_part(spec, k),
                "predictor": _predictor_part(spec, job)}
    reg = spec.dmd.registration
    if spec.dmd.enabled and (reg.scale != 1.0 or reg.rotation_deg != 0.0 or tuple(reg.offset_px) != (0.0, 0.0)):
        optional["registration"] = Part(px * REGISTRATION_BYTES_PER_PX, "dmd.registration")
    parts.update({name: part for name, part in optional.items() if part is not None})
    return MemoryEstimate(parts)


def check_memory(spec, job: str = "render", *, workers: int = 1, where: str | None = None) -> MemoryEstimate:
    """Refuse (InsufficientMemory, one line with the estimate and the available memory) a run
    whose estimate, times `workers` runs at once, exceeds the available memory."""
    est = estimate_run(spec, job)
    need = est.total_bytes * workers
    have, source = available_bytes()
    if need > have:
        dom = est.dominant
        many = f" x {workers} workers" if workers > 1 else ""
        raise InsufficientMemory(
            f"{where or spec.origin or spec.toml_path}: {est.parts[dom].key}: this run needs about "
            f"{format_bytes(need)}{many} ({est.describe()}) but {format_bytes(have)} is available "
            f"({source}); the largest part is {dom}, sized by {est.parts[dom].key}")
    return est


def fits_note(est: MemoryEstimate) -> str:
    have, source = available_bytes()
    return (f"memory: about {format_bytes(est.total_bytes)} estimated ({est.describe()}), "
            f"{format_bytes(have)} available" if have < (1 << 62) else
            f"memory: about {format_bytes(est.total_bytes)} estimated")

