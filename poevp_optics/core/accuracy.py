"""Numerical accuracy settings, kept apart from physics (STYLE.md 5, after GalSim's GSParams).

A sweep over physics keys never changes the numerics by accident, and an error-vs-time study
sweeps only these. Filled from the scene's stable keys by scene/resolve.py (`accuracy_of`; one
object, `ResolvedScene.accuracy`, shared by the render and the camera):

| field                   | scene key                | meaning |
|-------------------------|--------------------------|---------|
| spp                     | render.spp               | Mitsuba samples per pixel per radiance sample |
| subframes               | render.subframes         | K uniform radiance nodes per exposure (ends included) |
| pwm_nodes               | render.pwm_nodes         | join the DMD's switching times to the nodes |
| mc_splits               | render.mc_splits         | independent-seed renders behind the Monte Carlo error |
| temporal_spp            | render.temporal_spp      | spp of the temporal-error check (0: spp) |
| sampler                 | render.sampler           | Mitsuba sampler (render/samplers.py SAMPLERS) |
| light_selection         | render.light_selection   | emitters' sampling weights (render/lights.py LIGHT_SELECTIONS) |
| target_rel_error        | render.target_rel_error  | MC error (ROI, or frame) to render to; 0: render spp once |
| max_spp                 | render.max_spp           | cap of the error-targeted render per radiance sample |
| psf_support_energy      | relay.support_energy     | energy an automatic PSF support holds |
| psf_support_px          | relay.support_px         | explicit PSF support (0: from the energy) |
| guard_max_px            | relay.guard_max_px       | widest guard band rendered for the PSF |
| poisson_sampler         | sensor.poisson_sampler   | shot-noise sampler (camera/sensor.py POISSON_SAMPLERS) |
| objective_field_samples | objective.field_samples  | field points of the objective's PSF grid per axis (None: the [objective] spec's) |
| objective_band_samples  | objective.band_samples   | wavelength parts of its polychromatic PSF |
| objective_pupil_rays    | objective.pupil_rays     | pupil sampling of its wave-optics PSF (per side) |
| objective_support_energy| objective.support_energy | energy its PSF kernels hold |
| objective_guard_max_px  | objective.guard_max_px   | widest guard band rendered for its kernels |
| registration_oversample | -                        | sub-areas per sensor pixel side in the registration (4) |
| dmd_full_table_max      | -                        | levels x nodes up to which the DMD tabulates every level |
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Accuracy:
    """Numerical settings of one run (see the module table)."""

    spp: int = 16
    subframes: int = 4
    pwm_nodes: bool = True
    mc_splits: int = 2
    temporal_spp: int = 0
    sampler: str = "multijitter"
    light_selection: str = "power"
    target_rel_error: float = 0.0
    max_spp: int = 4096
    psf_support_energy: float = 0.999
    psf_support_px: int = 0
    guard_max_px: int = 256
    poisson_sampler: str = "exact"
    objective_field_samples: int | None = None
    objective_band_samples: int | None = None
    objective_pupil_rays: int | None = None
    objective_support_energy: float | None = None
    objective_guard_max_px: int | None = None
    registration_oversample: int = 4
    dmd_full_table_max: int = 1 << 22

    def objective_numerics(self) -> dict:
        """The objective's numerical keys this accuracy sets ({key: value}; keys of [objective]
        without the `objective_` prefix), for camera/objective/params.py `with_accuracy`."""
        out = {}
        for name in OBJECTIVE_KEYS:
            v = getattr(self, f"objective_{name}")
            if v is not None:
                out[name] = v
        return out


#: The [objective] keys that are numerics only (camera/objective/params.py ACCURACY_KEYS).
OBJECTIVE_KEYS = ("field_samples", "band_samples", "pupil_rays", "support_energy", "guard_max_px")
