"""Objective lens: the image it forms on the DMD (before the mirrors can do anything).

Stage order (camera.py): render (pinhole) -> objective -> DMD -> relay -> sensor. The renderer draws
a pinhole image of sensor-weighted photon radiance on the mirror grid. A real
objective blurs it by diffraction and by aberrations that grow over the field, dims the field's
edge (vignetting), and spreads a little of every source's light over the whole image (veiling
glare). All three happen before the DMD, so no mask can undo them: glare around a headlamp is a
floor under the mask's attenuation. `apply(image, params)` models them as

    out = (1 - g) B(V x) + g H * (V x)

x the pinhole image, V the relative illumination (vignetting) per pixel, B the field-dependent
PSF blur (each source's PSF sums to one: flux is conserved), H the glare spread function (unit
sum), g the glare fraction. The optical axis is at the image's centre (the camera's guard band
is symmetric). Units pass through unchanged (V, B and H are dimensionless).

Keys of [objective] (`ObjectiveSpec`; kind: physics, or accuracy: numerics only, ACCURACY_KEYS).
The stage resolves them into `ObjectiveParams` with what the camera knows: the f-number from the
optical layout (layout.py), the image-plane pitch (the DMD mirror pitch; the sensor pitch without a
DMD) and the sensor's QE.

| key                    | type   | unit  | default   | kind     | source / meaning |
|------------------------|--------|-------|-----------|----------|------------------|
| f_number               | float  | -     | NaN       | physics  | working f-number at the DMD; NaN: from sensor.f_number / M (layout.py) |
| psf                    | str    | -     | "delta"   | physics  | registry `OBJECTIVE_PSFS`: delta, gaussian, airy, prescription |
| focal_length_m         | float  | m     | 0.025     | physics  | effective focal length; sets field angle tan(theta) = r / f |
| prescription           | str    | -     | "double_gauss" | physics | registry `PRESCRIPTIONS`, scaled to focal_length_m, stopped to f_number |
| sigma_px               | float  | px    | 1.0       | physics  | sigma of the `gaussian` PSF |
| wavelengths_nm         | tuple  | nm    | ()        | physics  | explicit wavelengths, weighted by the sensor response there; () = the sensor band |
| vignetting             | str    | -     | "none"    | physics  | registry `VIGNETTING`: none, cos4, prescription |
| glare_fraction         | float  | -     | 0.0       | physics  | g: share of the image-plane energy in the glare halo (ISO 9358 VGI ~ 1-5 %) |
| glare_model            | str    | -     | "power_law" | physics | registry `GLARE_MODELS` (camera/glare.py): the halos the [objective] keys shape |
| glare_exponent         | float  | -     | 2.0       | physics  | n in the halo's r^-n (a Harvey-model slope typical of polished optics, Stover, Optical Scattering, 3rd ed.) |
| glare_core_radius_deg  | float  | deg   | 0.05      | physics  | halo flat inside this field angle from the source |
| glare_outer_radius_deg | float  | deg   | 30.0      | physics  | halo ends here (capped at the image's extent; the rest is reported as truncation) |
| field_samples          | int    | -     | 3         | accuracy | PSF nodes per quadrant and axis, axis and edge included (3: a 5 x 5 grid) |
| band_samples           | int    | -     | 3         | accuracy | wavelengths of the sensor band for the prescription (equal-weight quantiles) |
| pupil_rays             | int    | -     | 256       | accuracy | pupil samples per axis of optiland's FFT PSF (its field is lambda N (rays - 1) wide) |
| support_energy         | float  | -     | 0.999     | accuracy | PSF kernels keep the square holding this energy; the rest is reported |
| guard_max_px           | int    | px    | 256       | accuracy | widest guard band rendered for the objective's kernels |

Registries (core.registry, name -> entry with its source): `OBJECTIVE_PSFS`, `PRESCRIPTIONS`, `VIGNETTING`, and
the camera's one glare registry `GLARE_MODELS` (camera/glare.py, shared with the relay's Gaussian halo).
Adding one is one entry.

Spatially varying blur: the PSF is computed at a grid of field nodes and the image is blurred as
sum_n K_n * (w_n x), w_n the bilinear hat weights of node n (a partition of unity): each source
point's PSF is the bilinear interpolation of its four neighbouring node PSFs, so every source
keeps its flux and a constant PSF gives exactly the plain convolution (Nagy & O'Leary, SIAM J.
Sci. Comput. 19(4), 1998, "Restoring images degraded by spatially variant blur"). Each node
convolves the tile its weight covers (OpenCV filter2D, float64), the tiles overlap-added. The convolutions
are camera/convolution.py's, shared with the relay (`convolve_reflect`, `field_convolve`).

Borders, as in relay.convolve: the image is continued by reflection over the kernel's reach;
the camera renders a guard band of `radius_px(params, footprint)` around the sensor's footprint
and crops it afterwards. Kernels wider than the image are capped at its extent (the energy
beyond is reported as truncation).

Model limits (what the prescription path leaves out, and why it is acceptable here): the lens
is centred and rotationally symmetric (one optiland PSF per field radius, rotated to each node);
distortion changes the relative illumination but does not move pixels (the render is a pinhole
projection; kernels are centred on the band-mean chief ray, lateral colour kept); the band
weights assume a spectrum flat in energy across each band part (as the relay's Airy PSF does);
rays are aimed at the paraxial pupil (no pupil aberration); the bundled samples have no clear
apertures, so `prescription` vignetting holds no mechanical vignetting; polarisation and
spectral transmission are ignored; optiland's FFT PSF covers a field lambda N (rays - 1) wide,
and the diffraction wings beyond it are reported with the truncation (Airy asymptote).

The prescription PSF grid is cached on disk ($POEVP_CACHE_DIR/objective, default
~/.cache/poevp_optics/objective; core.runtime.cache_dir; cache.py), keyed by a SHA-256 of the parameters that shape it, the image
shape, cache.py's CACHE_VERSION and optiland's version (optiland import + numba JIT take
seconds).

One job per module (`from poevp_optics.camera.objective import X` serves every name, including those of
camera/convolution.py, camera/glare.py and camera/kernels.py it uses):

| module           | holds |
|------------------|-------|
| params.py        | `ObjectiveSpec`, `ObjectiveParams`, the registries, the sensor band (`band`, `sensor_band`) |
| prescriptions.py | `PRESCRIPTIONS` entries, the field check, the scaled and stopped optiland lens (`build_lens`) |
| psfs.py          | `PSFGrid` and the `OBJECTIVE_PSFS` builders (delta, gaussian, airy, prescription), `psf_grid` |
| cache.py         | the on-disk cache of PSF grids and RI tables (`cache_key`, `CACHE_VERSION`) |
| vignetting.py    | `VIGNETTING` entries, `relative_illumination`, `ri_profile` |
| glare.py         | the halo from camera/glare.py's `GLARE_MODELS`, `glare_kernel`, `glare_floor` (VGI) |
| stage.py         | `apply` (`apply_with_veil`: its glare term too), `radius_px` (guard band), `is_identity`, `summary` |
| memory.py        | `radius_bound_px`, `memory_bytes` (apps/run/memory.py's estimate) |
"""

from poevp_optics.camera.objective.params import (ACCURACY_KEYS, DEFAULT_F_NUMBER, OBJECTIVE_PSFS, PRESCRIPTIONS,
                                                  VIGNETTING, ObjectiveParamError, ObjectiveParams, ObjectiveSpec, band,
                                                  sensor_band, with_accuracy)
from poevp_optics.camera.objective.prescriptions import Prescription, build_lens, check_field, corner_radius_m
from poevp_optics.camera.objective.cache import CACHE_VERSION, cache_key
from poevp_optics.camera.kernels import max_radius_px, pixel_integrated_radial
from poevp_optics.camera.objective.psfs import PSFEntry, PSFGrid, airy_radius_px, node_positions_px, psf_grid
from poevp_optics.camera.objective.vignetting import (VignettingEntry, field_angle_rad, relative_illumination,
                                                      ri_profile)
from poevp_optics.camera.glare import (GLARE_MODELS, GlareKernel, glare_radii_px, power_law_energy_beyond,
                                       power_law_halo)
from poevp_optics.camera.objective.glare import glare_floor, glare_kernel
from poevp_optics.camera.convolution import convolve_reflect, field_convolve
from poevp_optics.camera.objective.stage import apply, apply_with_veil, is_identity, radius_px, summary
from poevp_optics.camera.objective.memory import memory_bytes, radius_bound_px

__all__ = [
    "ACCURACY_KEYS", "CACHE_VERSION", "DEFAULT_F_NUMBER", "GLARE_MODELS", "OBJECTIVE_PSFS", "PRESCRIPTIONS",
    "VIGNETTING", "GlareKernel", "ObjectiveParamError", "ObjectiveParams", "ObjectiveSpec", "PSFEntry", "PSFGrid",
    "Prescription", "VignettingEntry", "airy_radius_px", "apply", "apply_with_veil", "band", "build_lens", "cache_key", "check_field",
    "convolve_reflect", "corner_radius_m", "field_angle_rad", "field_convolve", "glare_floor", "glare_kernel",
    "glare_radii_px", "is_identity", "max_radius_px", "memory_bytes", "node_positions_px", "pixel_integrated_radial", "with_accuracy",
    "power_law_energy_beyond", "power_law_halo", "psf_grid", "radius_bound_px", "radius_px", "relative_illumination",
    "ri_profile", "sensor_band", "summary",
]
