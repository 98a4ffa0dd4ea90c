"""Lens prescriptions (optiland): the `PRESCRIPTIONS` registry, the field they cover, and the lens
scaled to the objective's focal length and stopped to its f-number (`build_lens`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from poevp_optics.camera.objective.params import PRESCRIPTIONS, ObjectiveParamError, ObjectiveParams

@dataclass(frozen=True)
class Prescription:
    """A lens design: `build()` returns an optiland Optic at its design scale; `field_deg` is the
    half field angle it was designed for (larger fields are refused)."""

    build: Callable
    field_deg: float
    source: str


def _double_gauss():
    from optiland.samples.objectives import DoubleGauss

    return DoubleGauss()


def _cooke_triplet():
    from optiland.samples.objectives import CookeTriplet

    return CookeTriplet()


def _perfect_lens():
    import optiland.backend as be
    from optiland import optic

    lens = optic.Optic()
    lens.surfaces.add(index=0, radius=be.inf, thickness=be.inf)
    lens.surfaces.add(index=1, surface_type="paraxial", f=100.0, thickness=100.0, is_stop=True)
    lens.surfaces.add(index=2)
    lens.set_aperture(aperture_type="imageFNO", value=5.0)
    lens.wavelengths.add(value=0.55, is_primary=True)
    return lens


def _register_prescription(name: str, build: Callable, field_deg: float, source: str) -> None:
    PRESCRIPTIONS.register(name, Prescription(build, field_deg, source), source=source)


_register_prescription("double_gauss", _double_gauss, 14.0,
                       "optiland.samples.objectives.DoubleGauss (optiland 0.6.3): f = 100 mm, f/5, half field "
                       "14 deg, six elements (N-SSK2, N-SK2, F5, N-SK16)")
_register_prescription("cooke_triplet", _cooke_triplet, 20.0,
                       "optiland.samples.objectives.CookeTriplet (optiland 0.6.3): EPD 10 mm, f ~ 50 mm, half "
                       "field 20 deg (SK16 / F2 / SK16)")
_register_prescription("perfect", _perfect_lens, 45.0,
                       "optiland paraxial (thin-lens phase) surface, stop at the lens: a diffraction-limited "
                       "Airy PSF on axis (Born & Wolf 8.5.2)")


def corner_radius_m(params: ObjectiveParams, image_shape) -> float:
    """Distance (m) from the optical axis (image centre) to the farthest pixel centre."""
    h, w = int(image_shape[0]), int(image_shape[1])
    return math.hypot((h - 1) / 2, (w - 1) / 2) * params.pixel_pitch_m


def check_field(params: ObjectiveParams, field_max_deg: float) -> None:
    """Refuse a field wider than the prescription was designed for (ObjectiveParamError)."""
    pres = PRESCRIPTIONS[params.prescription]
    if field_max_deg > pres.field_deg * (1 + 1e-9):
        raise ObjectiveParamError(
            f"objective.focal_length_m = {params.focal_length_m:g}: the image's corner is {field_max_deg:.2f} deg "
            f"off axis, beyond the {params.prescription!r} design field of {pres.field_deg:g} deg; use a "
            "longer focal length or a smaller image")


def build_lens(params: ObjectiveParams, wl_nm: np.ndarray, field_max_deg: float):
    """The prescription at the band's wavelengths (primary: the one nearest the band's mean),
    scaled to `focal_length_m` at the primary wavelength, stopped to image-side `f_number`
    (paraxial F/# = f / EPD, optiland's 'imageFNO'), with angle fields 0 .. field_max_deg."""
    check_field(params, field_max_deg)
    lens = PRESCRIPTIONS[params.prescription].build()
    for i in reversed(range(len(lens.wavelengths))):
        lens.wavelengths.remove(i)
    primary = int(np.argmin(np.abs(wl_nm - np.mean(wl_nm))))
    for i, wl in enumerate(wl_nm):
        lens.wavelengths.add(value=float(wl) * 1e-3, is_primary=(i == primary))
    scale = params.focal_length_m * 1e3 / float(lens.paraxial.f2())
    lens.updater.scale_system(scale)
    for surf in lens.surfaces:                 # optiland's scale_system leaves thin-lens focal lengths
        model = getattr(surf, "interaction_model", None)
        if type(model).__name__ == "ThinLensInteractionModel":
            model.f = model.f * scale
    lens.update()
    f_mm = float(lens.paraxial.f2())
    if abs(f_mm / (params.focal_length_m * 1e3) - 1) > 1e-6:
        raise RuntimeError(f"scaling {params.prescription!r} gave f = {f_mm} mm, not {params.focal_length_m * 1e3} mm")
    lens.set_aperture(aperture_type="imageFNO", value=params.f_number)
    for i in reversed(range(len(lens.fields))):
        lens.fields.remove(i)
    lens.fields.set_type(field_type="angle")
    lens.fields.add(y=0.0)
    lens.fields.add(y=max(field_max_deg, 1e-6))
    return lens
