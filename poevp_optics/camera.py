"""One capture of the DMD camera: radiance sub-frames + mask -> DN (DMD -> relay -> sensor).

The optical path of the real camera (DESIGN.md): objective -> image on the DMD -> each mirror
sends light to the relay for its PWM share of the exposure -> relay lens (PSF) -> sensor. So the
relay PSF acts on (mask x scene), and the sensor sees the registered, blurred DMD-plane image.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from . import spectra
from .dmd import (DMD, Schedule, apply_registration, interval_transmission, registration_taps,
                  throughput_on, transmission_table)
from .relay import build_psf, convolve
from .scene import SceneSpec
from .sensor import NoiseSwitches, Sensor, pixel_etendue_m2_sr, resolve_sensor


def _sync(x):
    import drjit as dr

    dr.eval(x)
    dr.sync_thread()
    return x


@dataclass
class Capture:
    """A measured frame and what produced it (numpy arrays on the sensor grid)."""

    dn: np.ndarray                    # digital numbers, integer-valued float32
    exposure_s: np.ndarray            # effective exposure per pixel, s (DMD throughput incl.)
    signal_e: np.ndarray              # noise-free photo-electrons reaching each pixel
    seconds: dict = field(default_factory=dict)


class Camera:
    """The DMD camera of a scene: DMD, relay PSF and a sensor instance (fixed-pattern noise)."""

    def __init__(self, spec: SceneSpec, switches: NoiseSwitches | None = None):
        self.spec = spec
        self.shape = tuple(spec.render.resolution)
        self.params = resolve_sensor(spec.sensor)
        self.sensor = Sensor(self.params, self.shape, switches)
        self.dmd = DMD(spec.dmd) if spec.dmd.enabled else None
        qe = spectra.load_spectrum(self.params.qe, emissive=True)
        band_w = spectra.sensor_response_e_per_J(qe)
        self.psf = build_psf(spec.relay, pixel_pitch_m=self.params.pixel_pitch_m,
                             band_nm=spectra.WAVELENGTHS_NM, band_weights=band_w,
                             base_dir=spec.toml_path.parent, image_shape=self.shape)
        self.taps = registration_taps(spec.dmd.registration, self.shape, self.shape) if self.dmd else None
        self.etendue_m2_sr = pixel_etendue_m2_sr(self.params)
        # lens transmission (objective) x relay transmission; DMD throughput is in the exposure
        self.throughput = self.params.optical_throughput * (spec.relay.transmission if self.dmd else 1.0)

    @property
    def top_level(self) -> int:
        return self.dmd.levels if self.dmd else 255

    def schedule(self, frame_index: int) -> Schedule:
        return Schedule.for_frame(self.spec.dmd, self.spec.timing, self.spec.frame_start_s(frame_index))

    def level_exposure_s(self, frame_index: int) -> np.ndarray:
        """Effective exposure (s) of every mask level over the whole exposure (float64)."""
        levels = np.arange(self.top_level + 1)
        return transmission_table(levels, self.spec.dmd, self.schedule(frame_index), 1)[:, 0]

    def white_exposure_s(self, frame_index: int) -> float:
        if not self.dmd:
            return self.spec.timing.exposure_s
        return float(self.level_exposure_s(frame_index)[-1])

    def electrons_per_radiance(self) -> float:
        """Electrons per (e- s-1 m-2 sr-1) per second of effective exposure."""
        return self.etendue_m2_sr * self.throughput

    def basis_tables(self, frame_index: int, basis: tuple[str, ...], lit: bool) -> list[np.ndarray]:
        """Exposure (s) per DMD level of each emitter-group image: 'rest' sees the whole
        exposure; a PWM lamp only its drive: the exact integral over the lamp's on-intervals
        (plus off_fraction of the rest). `lit`: DMD levels in use (False: DMD off / absent)."""
        from .flicker import on_intervals

        sched = self.schedule(frame_index)
        t0, t1 = sched.exposure_start_s, sched.exposure_start_s + sched.exposure_s
        if lit:
            levels = np.arange(self.top_level + 1)
            span = lambda a, b: interval_transmission(levels, self.spec.dmd, sched, a, b)  # noqa: E731
        else:
            thr = throughput_on(self.spec.dmd) if self.dmd is not None else 1.0
            span = lambda a, b: np.array([(b - a) * thr])  # noqa: E731
        full = span(t0, t1)
        out = []
        for name in basis:
            if name == "rest":
                out.append(full)
                continue
            fl = self.spec.flicker[name]
            on = sum((span(a, b) for a, b in on_intervals(t0, t1, fl)), np.zeros_like(full))
            out.append(on + fl.off_fraction * (full - on))
        return out

    def capture(self, subframes, mask_levels, frame_index: int, seed: int,
                basis: tuple[str, ...] = ()) -> Capture:
        """Expose the sensor to K radiance sub-frames through `mask_levels` (None: no DMD).

        basis: when given, `subframes` are emitter-group images named by it (flickering lamps,
        `Camera.basis_tables`) rather than time samples: their exposures are exact integrals."""
        import drjit as dr
        from drjit.auto import Float

        k = len(subframes)
        h, w = self.shape
        secs = {}
        t0 = time.perf_counter()
        subs = [Float(np.ascontiguousarray(s, dtype=np.float32).ravel()) for s in subframes]
        if basis:
            lit = self.dmd is not None and mask_levels is not None
            tables = self.basis_tables(frame_index, tuple(basis), lit)
            if lit:
                weights = self.dmd.table_weights(mask_levels, tables)
            else:
                weights = [dr.full(Float, float(t[0]), h * w) for t in tables]
        elif self.dmd is not None and mask_levels is not None:
            weights, _ = self.dmd.exposure_weights(mask_levels, self.schedule(frame_index), k)
        else:
            dt = self.spec.timing.exposure_s / k
            thr = throughput_on(self.spec.dmd) if self.dmd is not None else 1.0
            weights = [dr.full(Float, dt * thr, h * w) for _ in range(k)]
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
            plane = apply_registration(plane, self.taps)
            expo = apply_registration(expo, self.taps)
        _sync((plane, expo))
        secs["dmd"] = time.perf_counter() - t0
        t1 = time.perf_counter()
        if self.psf is not None:
            plane = Float(convolve(np.array(plane, dtype=np.float64).reshape(h, w), self.psf).ravel().astype(np.float32))
        secs["relay"] = time.perf_counter() - t1
        t2 = time.perf_counter()
        signal = plane * float(self.electrons_per_radiance())
        dn, _ = self.sensor.capture(signal, self.spec.timing.exposure_s, seed)
        _sync(dn)
        secs["sensor"] = time.perf_counter() - t2
        return Capture(np.array(dn).reshape(h, w), np.array(expo).reshape(h, w),
                       np.array(signal).reshape(h, w), secs)

    def noise_free_dn(self, electrons: np.ndarray) -> np.ndarray:
        """Sensor transfer without noise: offset + gain min(e + dark, full well), clipped."""
        p = self.params
        e = np.minimum(electrons + p.dark_current_e_per_s * self.spec.timing.exposure_s, p.full_well_e)
        return np.clip(np.rint(p.offset_dn + p.gain_dn_per_e * e), 0, p.max_dn)
