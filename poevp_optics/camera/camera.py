"""One capture of the DMD camera: radiance sub-frames + mask -> DN (objective -> DMD -> relay -> sensor).

The optical path of the real camera (DESIGN.md): objective -> image on the DMD -> each mirror
sends light to the relay for its PWM share of the exposure -> relay lens (PSF) -> sensor. The
renderer draws a pinhole image; the objective stage (objective/: field-dependent PSF,
vignetting, veiling glare) turns it into the image the mirrors see, so the mask multiplies the
blurred, vignetted, glare-veiled image and cannot remove the glare. The relay PSF acts on
(mask x objective image), and the sensor sees the registered, blurred DMD-plane image.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from poevp_optics.camera.dmd import (DMD, DMDSpec, Schedule, displayed_levels, frame_schedule, interval_transmission,
                                     node_time_weights_s, throughput_on, transmission_table)
from poevp_optics.camera.layout import image_plane_pitch_m, layout_of
from poevp_optics.camera import objective as obj
from poevp_optics.camera.objective import ObjectiveParams, ObjectiveSpec
from poevp_optics.camera.registration import (apply_taps, apply_taps_numpy, box_to_sensor, forward_taps,
                                              is_identity, mirror_coords, to_mirror)
from poevp_optics.camera.relay import PSFContext, RelaySpec, build_psf, convolve, max_support_px
from poevp_optics.camera.sensor import (NoiseSwitches, Sensor, SensorParams, SensorSpec, pixel_etendue_m2_sr,
                                         resolve_sensor)
from poevp_optics.core.accuracy import Accuracy
from poevp_optics.core.grids import Grid, OnGrid
from poevp_optics.core.timing import TimingSpec
from poevp_optics.core import spectra


_IDENTITY = type("IdentityRegistration", (), {"scale": 1.0, "rotation_deg": 0.0, "offset_px": (0.0, 0.0)})()


def _sync(x):
    import drjit as dr

    dr.eval(x)
    dr.sync_thread()
    return x


@dataclass
class Capture:
    """A measured frame and what produced it (numpy arrays on the sensor grid, `grid`)."""

    dn: np.ndarray                    # digital numbers, integer-valued float32
    exposure_s: np.ndarray            # effective exposure per pixel, s (DMD throughput incl.)
    signal_e: np.ndarray              # noise-free photo-electrons reaching each pixel
    seconds: dict = field(default_factory=dict)
    exposure_blurred_s: np.ndarray | None = None   # exposure seen through the relay PSF (None: delta)
    grid: Grid | None = None          # the sensor grid the arrays are on (core/grids.py)
    frame_exposure: object | None = None   # the frame's exposure choice (control/exposure_time.py), None: the scene's

    def on_grid(self, name: str = "dn") -> OnGrid:
        """One of the capture's arrays (`dn`, `exposure_s`, `signal_e`, ...) tagged with its grid."""
        if self.grid is None:
            raise ValueError("this capture was built without its grid")
        return OnGrid(getattr(self, name), self.grid)


@dataclass(frozen=True)
class CameraParams:
    """Everything a `Camera` is built from, resolved from a scene by scene/resolve.py (no scene
    object below apps/): its stages' params, the sensor's (H, W), the accuracy settings, the folder
    relative files (a measured PSF) are read from and the lamps' PWM drives by emitter name."""

    sensor: SensorSpec
    dmd: DMDSpec
    relay: RelaySpec
    objective: ObjectiveSpec
    timing: TimingSpec
    shape: tuple[int, int]
    accuracy: Accuracy = Accuracy()
    base_dir: object = None
    flicker: object = None


def relay_psf_context(sensor: SensorParams, layout, shape, accuracy: Accuracy, base_dir) -> PSFContext:
    """What the relay PSF is built for (relay.py PSFContext): the sensor's pixel pitch and the
    relay's f-number on it (layout.py), the sensor's response as the band's weights, the support
    settings and the cap set by the image's (H, W). Read alike by the camera and the memory estimate."""
    qe = spectra.load_spectrum(sensor.qe, emissive=True)
    return PSFContext(pixel_pitch_m=sensor.pixel_pitch_m, f_number=layout.sensor_f_number,
                      band_nm=spectra.WAVELENGTHS_NM, band_weights=spectra.sensor_response_e_per_J(qe),
                      base_dir=base_dir, cap_px=max_support_px(shape), support_px=accuracy.psf_support_px,
                      support_energy=accuracy.psf_support_energy)


class Camera:
    """The DMD camera of a scene: DMD, relay PSF and a sensor instance (fixed-pattern noise).

    Grids: the sensor grid is `render.resolution` (`shape`); the mirror grid (`mirror_shape`) is
    what the renderer draws: the sensor's footprint on the DMD plus a guard band wide enough for
    the relay PSF and the objective's kernels (`guard_px` mirrors on each side: the larger of the
    two guards, each capped by its guard_max_px; registration.py), so light from beyond the
    sensor's field spills in through the blur as it does from the DMD's outer mirrors (beyond the
    guard, both stages continue the image by reflection); the guard is cropped before the sensor
    and never enters metrics.
    """

    def __init__(self, sensor: SensorSpec, dmd: DMDSpec, relay: RelaySpec, objective: ObjectiveSpec,
                 timing: TimingSpec, shape: tuple[int, int], accuracy: Accuracy = Accuracy(), *,
                 base_dir=None, flicker=None, switches: NoiseSwitches | None = None):
        """A camera from its stages' params (no scene file needed; `Camera.from_params` takes them
        as one `CameraParams`). shape: the sensor's (H, W); base_dir: where relative files (a
        measured PSF) are read; flicker: PWM-lamp drives by emitter name (basis_tables)."""
        self.timing, self.dmd_spec, self.relay_spec = timing, dmd, relay
        self.accuracy = accuracy
        objective = obj.with_accuracy(objective, accuracy)       # the run's numerics for the objective too
        self.flicker = dict(flicker or {})
        self.shape = tuple(shape)
        self.layout = layout_of(sensor, dmd, relay, objective)
        self.params = dataclasses.replace(resolve_sensor(sensor), f_number=self.layout.sensor_f_number,
                                          poisson_sampler=accuracy.poisson_sampler)
        self.sensor = Sensor(self.params, self.shape, switches)
        self.dmd = DMD(dmd, accuracy.dmd_full_table_max) if dmd.enabled else None
        self.psf = build_psf(relay, relay_psf_context(self.params, self.layout, self.shape, accuracy, base_dir))
        reg = dmd.registration if self.dmd else _IDENTITY
        self._init_objective(objective, dmd, self._relay_guards(reg)[1])
        self._init_grids(reg)
        self._build_objective()
        self.etendue_m2_sr = pixel_etendue_m2_sr(self.params)
        # lens transmission (objective) x relay transmission; DMD throughput is in the exposure
        self.throughput = self.params.optical_throughput * (relay.transmission if self.dmd else 1.0)

    @classmethod
    def from_params(cls, p: CameraParams, switches: NoiseSwitches | None = None) -> "Camera":
        """The camera `p` describes (scene/resolve.py builds `p` from a scene's [sensor], [dmd],
        [relay], [objective], [timing])."""
        return cls(p.sensor, p.dmd, p.relay, p.objective, p.timing, p.shape, p.accuracy, base_dir=p.base_dir,
                   flicker=p.flicker, switches=switches)

    def _init_objective(self, spec: ObjectiveSpec, dmd: DMDSpec, relay_guard_px: int) -> None:
        """The objective's resolved params (None: identity, the stage is skipped) and its guard
        band in mirrors (its widest kernel on the sensor's footprint, capped at guard_max_px;
        relay_guard_px: the mirrors the relay's guard renders anyway, where its search starts)."""
        self.objective_spec = spec
        self.objective = None
        self.objective_guard_px = 0
        self._objective_parts = None
        self._objective_memo: dict = {}
        self._kept_veil = None           # (radiance, its glare veil): `dmd_image(keep_veil=True)`
        if spec.is_identity:
            return
        pitch = image_plane_pitch_m(dmd, self.params)
        self.objective = ObjectiveParams.resolve(spec, f_number=self.layout.objective_f_number,
                                                 pixel_pitch_m=pitch, qe=self.params.qe)
        self.objective_guard_px = min(obj.radius_px(self.objective, self.shape, rendered_px=relay_guard_px,
                                                    cap_px=spec.guard_max_px), spec.guard_max_px)

    def _build_objective(self) -> None:
        """PSF grid, glare kernel and relative illumination for the mirror grid (built once)."""
        if self.objective is None:
            return
        p, shape = self.objective, self.mirror_shape
        self._objective_parts = {"grid": obj.psf_grid(p, shape), "glare": obj.glare_kernel(p, shape),
                                 "ri": obj.relative_illumination(p, shape)}

    def _relay_guards(self, reg) -> tuple[int, int]:
        """(sensor pixels, mirrors) of the guard band the relay PSF needs (capped at guard_max_px):
        the mirrors cover the sensor's guard ring through the affine map (+1 for sampling)."""
        radius = self.psf.kernel.shape[0] // 2 if self.psf is not None else 0
        sensor = min(radius, self.accuracy.guard_max_px)
        if is_identity(reg):
            return sensor, sensor
        return sensor, int(math.ceil(sensor / reg.scale)) + (1 if sensor else 0)

    def _init_grids(self, reg) -> None:
        """Sensor grid, guard band, mirror grid and the registration taps between them."""
        self.registration = reg
        self.sensor_guard_px, relay_mirrors = self._relay_guards(reg)
        h, w = self.shape
        if is_identity(reg):
            self.sensor_guard_px = max(self.sensor_guard_px, self.objective_guard_px)
            self.guard_px = self.sensor_guard_px
        else:
            self.guard_px = max(relay_mirrors, self.objective_guard_px)
        self.extended_shape = (h + 2 * self.sensor_guard_px, w + 2 * self.sensor_guard_px)
        self.mirror_shape = (h + 2 * self.guard_px, w + 2 * self.guard_px)
        o = self.accuracy.registration_oversample
        self.taps = forward_taps(reg, self.mirror_shape, self.extended_shape, o)
        self._sensor_taps = None

    # ------------------------------------------------------------------ objective
    def dmd_image(self, radiance: np.ndarray, keep_veil: bool = False) -> np.ndarray:
        """The image the objective forms on the DMD from a pinhole render (mirror grid, float32):
        (1 - g) B(V x) + g H * (V x) (objective/); the input itself when the stage is skipped.
        The last few results are kept by the input's identity (captures of one frame reuse them);
        keep_veil: its glare term g H * (V x) is kept too, for `glare_veil` of the same input
        (one at a time: a frame's time-averaged radiance)."""
        if self.objective is None:
            return radiance
        kept = self._kept_image(radiance)
        want_veil = keep_veil and self._objective_parts["glare"] is not None and self._veil_of(radiance) is None
        if kept is not None and not want_veil:
            return kept
        out, veil = self._form(radiance)
        if keep_veil and veil is not None:
            self._kept_veil = (radiance, veil)
        return out

    def dmd_image_of_average(self, radiance: np.ndarray, samples, weights, keep_veil: bool = False) -> np.ndarray:
        """`dmd_image(radiance)` for a radiance that is the weighted sum of `samples` (a moving
        scene's time average: RenderedExposure.subframe_weights), formed as the same sum of the
        samples' images: the stage is linear, and a capture forms those images anyway, so one
        convolution pass a sample serves both (float32 rounding apart, the same image). The
        result is kept by the identity of `radiance` as `dmd_image` keeps its own; keep_veil
        keeps the sum of the samples' glare terms likewise."""
        if self.objective is None:
            return radiance
        if len(samples) != len(weights) or not samples:
            raise ValueError(f"dmd_image_of_average: {len(samples)} samples, {len(weights)} weights")
        want_veil = keep_veil and self._objective_parts["glare"] is not None
        kept = self._kept_image(radiance)
        if kept is not None and not (want_veil and self._veil_of(radiance) is None):
            return kept
        total = veil_total = None
        for s, w in zip(samples, weights):
            img, veil = self._kept_image(s), None
            if img is None or want_veil:
                img, veil = self._form(s)
            part = float(w) * img.astype(np.float64)
            total = part if total is None else total + part
            if want_veil:
                veil_total = float(w) * veil if veil_total is None else veil_total + float(w) * veil
        out = total.astype(np.float32)
        self._remember(radiance, out)
        if want_veil:
            self._kept_veil = (radiance, veil_total)
        return out

    def _form(self, radiance: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(the objective's image of `radiance`, its float64 glare term or None), the image kept."""
        parts = self._objective_parts
        out, veil = obj.apply_with_veil(np.asarray(radiance, dtype=np.float32), self.objective, grid=parts["grid"],
                                        glare=parts["glare"], ri=parts["ri"])
        self._remember(radiance, out)
        return out, veil

    def _kept_image(self, radiance) -> np.ndarray | None:
        """The image kept for this very input (`_remember`), or None."""
        hit = self._objective_memo.get(id(radiance))
        return hit[1] if hit is not None and hit[0] is radiance else None

    def _remember(self, radiance, out) -> None:
        if len(self._objective_memo) >= 16:
            self._objective_memo.pop(next(iter(self._objective_memo)))
        self._objective_memo[id(radiance)] = (radiance, out)      # holds the input: ids stay unique

    def glare_veil(self, radiance: np.ndarray) -> np.ndarray | None:
        """The objective's veiling-glare part of `dmd_image` (mirror grid): g H * (V x); None
        without glare. No mask lowers it: it is in the image the mirrors see."""
        if self.objective is None or self._objective_parts["glare"] is None:
            return None
        kept = self._veil_of(radiance)
        if kept is not None:
            return kept
        x = np.asarray(radiance, dtype=np.float64)
        ri = self._objective_parts["ri"]
        v = x * ri if ri is not None else x
        return self.objective.glare_fraction * obj.convolve_reflect(v, self._objective_parts["glare"].kernel)

    def _veil_of(self, radiance) -> np.ndarray | None:
        kept = self._kept_veil
        return kept[1] if kept is not None and kept[0] is radiance else None

    def objective_summary(self) -> dict | None:
        """The objective stage for a report (objective.summary), or None when it is skipped."""
        if self.objective is None:
            return None
        return {**obj.summary(self.objective, self.mirror_shape), "guard_px": self.objective_guard_px}

    # ------------------------------------------------------------------ grids
    def _crop(self, img: np.ndarray) -> np.ndarray:
        g = self.sensor_guard_px
        h, w = self.shape
        return img[g:g + h, g:g + w]

    @property
    def sensor_grid(self) -> Grid:
        """The sensor's pixel grid (`shape`, the sensor's pixel pitch; core/grids.py)."""
        pitch = self.params.pixel_pitch_m
        return Grid("sensor", self.shape, pitch if math.isfinite(pitch) else None)

    @property
    def mirror_grid(self) -> Grid:
        """The DMD's mirror grid (`mirror_shape`: render grid, guard band included; the mirror
        pitch, or the sensor's pitch without a DMD: layout.image_plane_pitch_m)."""
        pitch = image_plane_pitch_m(self.dmd_spec, self.params)
        return Grid("mirror", self.mirror_shape, pitch if math.isfinite(pitch) else None)

    def to_sensor(self, mirror_image):
        """A mirror-grid (render-grid) image as the sensor pixels see it, without blur or noise
        (area-weighted registration; float64): the ground truth on the sensor grid. An `OnGrid`
        must be on the mirror grid (else GridError) and comes back on the sensor grid."""
        if isinstance(mirror_image, OnGrid):
            src = mirror_image.on(self.mirror_grid, "Camera.to_sensor's input")
            return OnGrid(self.to_sensor(src.array), self.sensor_grid)
        img = np.asarray(mirror_image, dtype=np.float64)
        if self.taps is None:
            g = self.guard_px
            h, w = self.shape
            return img[g:g + h, g:g + w]
        if self._sensor_taps is None:
            self._sensor_taps = forward_taps(self.registration, self.mirror_shape, self.shape,
                                             self.accuracy.registration_oversample)
        return apply_taps_numpy(img, self._sensor_taps, self.shape)

    def to_mirror(self, sensor_image):
        """A sensor-grid picture (a predicted frame) placed on the mirror grid (registration.py).
        An `OnGrid` must be on the sensor grid (else GridError) and comes back on the mirror grid."""
        if isinstance(sensor_image, OnGrid):
            src = sensor_image.on(self.sensor_grid, "Camera.to_mirror's input")
            return OnGrid(self.to_mirror(src.array), self.mirror_grid)
        return to_mirror(sensor_image, self.registration, self.mirror_shape, self.shape)

    def box_to_sensor(self, box):
        """A mirror-grid box (y0, x0, y1, x1) as the sensor-grid box holding its image."""
        return box_to_sensor(box, self.registration, self.mirror_shape, self.shape)

    def sensor_to_mirror(self, sx, sy):
        """Sensor-grid coordinates (px, arrays) -> the mirror-grid coordinates they image (mx, my)."""
        return mirror_coords(self.registration, sx, sy, self.mirror_shape, self.shape)

    def white_mask(self) -> np.ndarray | None:
        """All mirrors at the top level (the LDR twin), on the mirror grid; None without a DMD."""
        return np.full(self.mirror_shape, float(self.top_level)) if self.dmd else None

    @property
    def top_level(self) -> int:
        return self.dmd.levels if self.dmd else 255

    def schedule(self, frame_index: int, exposure=None) -> Schedule:
        """Frame's bit-plane schedule: the scene's [timing], or the frame's exposure choice
        `exposure` (control/exposure_time.py FrameExposure: its T_e and B, dmd.frame_schedule)."""
        return frame_schedule(self.dmd_spec, self.timing, self.timing.frame_start_s(frame_index), exposure)

    def exposure_time_s(self, exposure=None) -> float:
        """The sensor's exposure (s): timing.exposure_s, or the frame's choice."""
        return self.timing.exposure_s if exposure is None or exposure.nominal else float(exposure.exposure_s)

    def level_exposure_s(self, frame_index: int, exposure=None) -> np.ndarray:
        """Effective exposure (s) of every mask level over the whole exposure (float64), under the
        scene's schedule or the frame's exposure choice (a mirror shows its level's top B bits)."""
        sched = self.schedule(frame_index, exposure)
        levels = displayed_levels(np.arange(self.top_level + 1), self.dmd_spec.bits, sched.bits)
        return transmission_table(levels, self.dmd_spec, sched, 1)[:, 0]

    def white_exposure_s(self, frame_index: int, exposure=None) -> float:
        if not self.dmd:
            return self.timing.exposure_s
        return float(self.level_exposure_s(frame_index, exposure)[-1])

    def electrons_per_radiance(self) -> float:
        """Electrons per (e- s-1 m-2 sr-1) per second of effective exposure."""
        return self.etendue_m2_sr * self.throughput

    def basis_tables(self, frame_index: int, basis: tuple[str, ...], lit: bool, exposure=None) -> list[np.ndarray]:
        """Exposure (s) per DMD level of each emitter-group image: 'rest' sees the whole
        exposure; a PWM lamp only its drive: the exact integral over the lamp's on-intervals
        (plus off_fraction of the rest). `lit`: DMD levels in use (False: DMD off / absent);
        exposure: the frame's exposure choice (None: the scene's)."""
        from poevp_optics.core.flicker import on_intervals

        sched = self.schedule(frame_index, exposure)
        t0, t1 = sched.exposure_start_s, sched.exposure_start_s + sched.exposure_s
        if lit:
            levels = displayed_levels(np.arange(self.top_level + 1), self.dmd_spec.bits, sched.bits)
            span = lambda a, b: interval_transmission(levels, self.dmd_spec, sched, a, b)  # noqa: E731
        else:
            thr = throughput_on(self.dmd_spec) if self.dmd is not None else 1.0
            span = lambda a, b: np.array([(b - a) * thr])  # noqa: E731
        full = span(t0, t1)
        out = []
        for name in basis:
            if name == "rest":
                out.append(full)
                continue
            fl = self.flicker[name]
            on = sum((span(a, b) for a, b in on_intervals(t0, t1, fl)), np.zeros_like(full))
            out.append(on + fl.off_fraction * (full - on))
        return out

    def _check_inputs(self, subframes, mask_levels, frame_index: int, transmission: float = 1.0) -> None:
        """Radiance must be finite and >= 0 on the mirror grid, the attenuator's transmission in
        (0, 1]; clear errors, not a hung sampler."""
        if not 0.0 < transmission <= 1.0:
            raise ValueError(f"frame {frame_index}: attenuator transmission {transmission!r} is not in (0, 1]")
        for j, sub in enumerate(subframes):
            a = np.asarray(sub)
            if a.shape != self.mirror_shape:
                raise ValueError(f"frame {frame_index}: radiance sample {j} has shape {a.shape}, the "
                                 f"camera's mirror grid is {self.mirror_shape} (sensor {self.shape} + "
                                 f"guard {self.guard_px} px)")
            if not np.all(np.isfinite(a)):
                bad = int(np.count_nonzero(~np.isfinite(a)))
                raise ValueError(f"frame {frame_index}: radiance sample {j} has {bad} NaN/Inf pixels")
            if a.size and float(a.min()) < 0:
                raise ValueError(f"frame {frame_index}: radiance sample {j} is negative (min {a.min():.3g})")
        if mask_levels is not None and np.shape(mask_levels) != self.mirror_shape:
            raise ValueError(f"frame {frame_index}: mask has shape {np.shape(mask_levels)}, the mirror "
                             f"grid is {self.mirror_shape}")

    def _mirror_levels(self, mask_levels, switch):
        """The arrays of `capture`'s mask and late-mask levels: an `OnGrid` must be on the mirror
        grid (else GridError, core/grids.py); plain arrays pass as they are."""
        grid = self.mirror_grid
        if switch is not None:
            switch = (grid.take(switch[0], "Camera.capture's late mask levels"), switch[1])
        return grid.take(mask_levels, "Camera.capture's mask levels"), switch

    def nodes_rel(self, frame_index: int, k: int, times_s=None, exposure=None) -> np.ndarray | int:
        """Radiance node times relative to the frame's exposure start (s), or K (uniform). With a
        shortened exposure (`exposure`) the scene's nodes reach beyond it on both sides and the
        capture integrates their piecewise-linear radiance over the exposure alone (camera/dmd.py);
        K uniform nodes (times_s None) are then taken over the shortened exposure."""
        if times_s is None:
            return k
        start = (self.timing.exposure_window_s(frame_index)[0] if exposure is None or exposure.nominal
                 else self.schedule(frame_index, exposure).exposure_start_s)
        rel = np.asarray(times_s, dtype=np.float64) - start
        if rel.size != k:
            raise ValueError(f"frame {frame_index}: {k} radiance samples but {rel.size} sample times")
        return rel

    def capture_command(self, subframes, command, frame_index: int, seed: int, **timing) -> Capture:
        """`capture` through one frame's DMD command (control/loop_step.py DMDCommand: its mirror-grid
        `levels`, its late mask `switch` and the attenuator's `transmission`); timing: `basis` or
        `times_s` as for `capture`."""
        return self.capture(subframes, command.levels, frame_index, seed, switch=command.switch,
                            transmission=command.transmission, exposure=command.exposure, **timing)

    def _exposure_weights(self, mask_levels, frame_index: int, k: int, basis, times_s, switch, exposure):
        """Each of the K samples' exposure weight per mirror (s, DrJit Floats on the extended
        mirror grid): the late mask's, the emitter groups' exact tables, the PWM's, or the white
        exposure without a DMD (arguments as for `capture`)."""
        import drjit as dr
        from drjit.auto import Float

        n_mirrors = self.mirror_shape[0] * self.mirror_shape[1]
        if switch is not None:
            weights, _ = self.dmd.late_exposure_weights(mask_levels, switch[0], self.schedule(frame_index, exposure),
                                                        self.nodes_rel(frame_index, k, times_s, exposure), switch[1])
        elif basis:
            lit = self.dmd is not None and mask_levels is not None
            tables = self.basis_tables(frame_index, tuple(basis), lit, exposure)
            if lit:
                weights = self.dmd.table_weights(mask_levels, tables)
            else:
                weights = [dr.full(Float, float(t[0]), n_mirrors) for t in tables]
        elif self.dmd is not None and mask_levels is not None:
            weights, _ = self.dmd.exposure_weights(mask_levels, self.schedule(frame_index, exposure),
                                                   self.nodes_rel(frame_index, k, times_s, exposure))
        else:
            thr = throughput_on(self.dmd_spec) if self.dmd is not None else 1.0
            dt = node_time_weights_s(self.timing.exposure_s, self.nodes_rel(frame_index, k, times_s))
            weights = [dr.full(Float, float(d * thr), n_mirrors) for d in dt]
        return weights

    def capture(self, subframes, mask_levels, frame_index: int, seed: int,
                basis: tuple[str, ...] = (), times_s=None, switch=None, transmission: float = 1.0,
                exposure=None) -> Capture:
        """Expose the sensor to K radiance samples (mirror grid) through `mask_levels` (mirror grid,
        `_mirror_levels`; None: no DMD or all white without one). times_s: the samples' absolute
        times (the scene's `subframe_times_s`); None: K uniform nodes over the exposure.

        basis: when given, `subframes` are emitter-group images named by it (flickering lamps,
        `Camera.basis_tables`) rather than time samples: their exposures are exact integrals.
        switch: (new_levels, switch_s): a late mask (mirror grid) that replaces `mask_levels` for
        the bit-planes starting at or after switch_s (absolute, s; dmd.late_schedules).
        transmission: the global attenuator's setting for the frame (camera/attenuator.py): every
        mirror's exposure x transmission, in the capture's `exposure_s` too (so the
        reconstruction divides it out). exposure: the frame's exposure choice (control/exposure_time.py
        FrameExposure: the sensor's T_e and the DMD's B planes in a window equal to it); None or
        nominal: the scene's [timing]."""
        import drjit as dr
        from drjit.auto import Float

        mask_levels, switch = self._mirror_levels(mask_levels, switch)
        self._check_inputs(subframes, mask_levels, frame_index, transmission)
        k = len(subframes)
        h, w = self.shape
        secs = {}
        t_obj = time.perf_counter()
        subframes = [self.dmd_image(s) for s in subframes]       # objective: before the mirrors
        secs["objective"] = time.perf_counter() - t_obj
        t0 = time.perf_counter()
        subs = [Float(np.ascontiguousarray(s, dtype=np.float32).ravel()) for s in subframes]
        if switch is not None and (basis or self.dmd is None):
            raise ValueError(f"frame {frame_index}: a late mask needs a DMD and time samples, not "
                             "emitter-group images (flickering lamps)")
        weights = self._exposure_weights(mask_levels, frame_index, k, basis, times_s, switch, exposure)
        if transmission != 1.0:
            weights = [wt * float(transmission) for wt in weights]
        plane = weights[0] * subs[0]
        for j in range(1, k):
            plane = dr.fma(weights[j], subs[j], plane)
        if basis:                            # 'rest' is exposed over the whole window
            expo = weights[list(basis).index("rest")]
        else:
            expo = weights[0]
            for j in range(1, k):
                expo = expo + weights[j]
        if self.taps is not None:
            plane = apply_taps(plane, self.taps)
            expo = apply_taps(expo, self.taps)
        _sync((plane, expo))
        secs["dmd"] = time.perf_counter() - t0
        t1 = time.perf_counter()
        expo_np = np.array(expo).reshape(self.extended_shape)
        expo_blur = None
        if self.psf is not None:
            blurred = convolve(np.array(plane, dtype=np.float64).reshape(self.extended_shape), self.psf)
            plane = Float(np.ascontiguousarray(self._crop(blurred), dtype=np.float32).ravel())
            expo_blur = self._crop(convolve(expo_np.astype(np.float64), self.psf)).astype(np.float32)
        elif self.sensor_guard_px:
            plane = Float(np.ascontiguousarray(self._crop(np.array(plane).reshape(self.extended_shape))).ravel())
        secs["relay"] = time.perf_counter() - t1
        t2 = time.perf_counter()
        signal = plane * float(self.electrons_per_radiance())
        dn, _ = self.sensor.capture(signal, self.exposure_time_s(exposure), seed)
        _sync(dn)
        secs["sensor"] = time.perf_counter() - t2
        return Capture(np.array(dn).reshape(h, w), np.ascontiguousarray(self._crop(expo_np)),
                       np.array(signal).reshape(h, w), secs, expo_blur, self.sensor_grid,
                       exposure if exposure is not None and not exposure.nominal else None)

    def reconstruct(self, cap: Capture, frame_index: int):
        """(radiance estimate, flags, signal electrons) of a capture (reconstruct.py)."""
        from poevp_optics.camera.reconstruct import reconstruct

        fx = cap.frame_exposure
        return reconstruct(cap.dn, cap.exposure_s, self.params, self.etendue_m2_sr, self.throughput,
                           self.exposure_time_s(fx), self.sensor.switches.dark_current,
                           white_exposure_s=self.white_exposure_s(frame_index, fx),
                           exposure_blurred_s=cap.exposure_blurred_s,
                           crosstalk_tolerance=self.relay_spec.crosstalk_tolerance)

    def noise_free_dn(self, electrons: np.ndarray) -> np.ndarray:
        """Sensor transfer without noise: offset + gain min(e + dark, full well), clipped; dark
        current only when the sensor's switch has it on (as `Sensor.capture`)."""
        p = self.params
        dark = p.dark_current_e_per_s * self.timing.exposure_s if self.sensor.switches.dark_current else 0.0
        e = np.minimum(electrons + dark, p.full_well_e)
        return np.clip(np.rint(p.offset_dn + p.gain_dn_per_e * e), 0, p.max_dn)
