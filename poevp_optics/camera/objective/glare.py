"""Veiling glare of the objective: its halo from the shared registry (camera/glare.py
`GLARE_MODELS`, shaped by the [objective] keys: power_law) and the glare floor it puts under a
dark spot (VGI, ISO 9358)."""

from __future__ import annotations

import functools
import math

from poevp_optics.camera.glare import GLARE_MODELS, GlareKernel, glare_radii_px
from poevp_optics.camera.kernels import capped_radius, max_radius_px
from poevp_optics.camera.objective.params import ObjectiveParams


def glare_halo(params: ObjectiveParams):
    """The objective's halo: the `objective.glare_model` entry shaped by the [objective] keys."""
    return GLARE_MODELS[params.glare_model].from_keys(params)


def glare_kernel(params: ObjectiveParams, image_shape) -> GlareKernel | None:
    """The glare spread function for an image of `image_shape` (support capped at its extent),
    or None when glare_fraction = 0. Kept for the last few (params, support) asked for (0.9 s at
    1920x1080, asked for by the guard band, the camera and the report): read-only."""
    if params.glare_fraction <= 0:
        return None
    return _kernel(params, max_radius_px((int(image_shape[0]), int(image_shape[1]))))


def glare_radius_px(params: ObjectiveParams, image_shape) -> int:
    """The radius (px) of `glare_kernel(params, image_shape)` without building it: the halo's
    own radius capped at the image's extent; 0 without glare."""
    if params.glare_fraction <= 0:
        return 0
    return capped_radius(glare_halo(params).radius_px(), max_radius_px((int(image_shape[0]), int(image_shape[1]))))


@functools.lru_cache(maxsize=4)
def _kernel(params: ObjectiveParams, cap_px: int) -> GlareKernel:
    k = glare_halo(params).kernel(cap_px)
    k.kernel.flags.writeable = False
    return k


def glare_floor(params: ObjectiveParams, image_shape, black_radius_px: float) -> dict:
    """The veiling-glare floor under a dark spot: a black disc of radius rho (px) in a uniform
    white field L gets g L E_H(> rho) at its centre (the halo's energy beyond rho, its entry's
    closed-form `energy_beyond`), while the white field keeps L (unit-sum kernels): the veiling
    glare index VGI = g E_H(> rho) (ISO 9358:1994; rho -> 0 gives g). The glare is in the image the
    mirrors see, so no mask lowers it: a scene's darkest-to-brightest ratio below VGI is veiled,
    and the encoded DR is capped at floor_db = -20 log10 VGI whatever the DMD's attenuation.
    The halo's kernel truncation at the image's extent is reported beside it."""
    g = params.glare_fraction
    if g <= 0:
        return {"glare_fraction": 0.0, "black_radius_px": float(black_radius_px), "vgi": 0.0,
                "floor_db": math.inf}
    rc, ro = glare_radii_px(params)
    vgi = g * glare_halo(params).energy_beyond(float(black_radius_px))
    kernel = glare_kernel(params, image_shape)
    return {"glare_fraction": g, "black_radius_px": float(black_radius_px), "vgi": vgi,
            "floor_db": float(-20 * math.log10(vgi)) if vgi > 0 else math.inf,
            "halo_radii_px": [rc, ro], "halo_truncation": kernel.truncation_error}
