"""The [objective] keys: `ObjectiveSpec` (the scene section), `ObjectiveParams` (resolved for one
camera), the stage's registries, and the band of wavelengths the objective is evaluated at.
The key table is in the package docstring (camera/objective/__init__.py)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import get_type_hints

import numpy as np

from poevp_optics.camera.glare import models_of
from poevp_optics.core.accuracy import OBJECTIVE_KEYS, Accuracy
from poevp_optics.core import spectra
from poevp_optics.core.exceptions import ParamError
from poevp_optics.core.params import Where, check_value, param
from poevp_optics.core.registry import Registry

#: Parameters that change numerics only (they belong to the run's Accuracy settings).
ACCURACY_KEYS = OBJECTIVE_KEYS          # numerics only: carried by core/accuracy.py Accuracy (objective_*)

#: Default image-side f-number of `ObjectiveParams`: the sensor preset's f/2.8 divided by the relay
#: magnification M = sensor pitch / mirror pitch = 3.45 um / 7.56 um (layout.py, 1:1 registration).
DEFAULT_F_NUMBER = 2.8 / (3.45e-6 / 7.56e-6)

OBJECTIVE_PSFS = Registry("objective PSF")
PRESCRIPTIONS = Registry("lens prescription")
VIGNETTING = Registry("vignetting model")
#: objective.glare_model's choices: the entries of camera/glare.py's `GLARE_MODELS` (the one
#: glare registry, re-exported here) that the [objective] keys shape.
OBJECTIVE_GLARE_MODELS = models_of("objective")


class ObjectiveParamError(ParamError):
    """A parameter out of range; the message names `objective.<key>` and the allowed range."""


@dataclass(frozen=True)
class ObjectiveSpec:
    """[objective]: the lens that images the scene onto the DMD (table in the module docstring)."""

    f_number: float = param(math.nan, gt=0, max=1000.0)  # at the DMD; NaN: from sensor.f_number
    psf: str = param("delta", choices=OBJECTIVE_PSFS)
    focal_length_m: float = param(0.025, gt=1e-4, max=10.0)
    prescription: str = param("double_gauss", choices=PRESCRIPTIONS)
    sigma_px: float = param(1.0, gt=1e-3, max=4096.0)
    wavelengths_nm: tuple[float, ...] = param((), min=spectra.WAVELENGTH_MIN_NM, max=spectra.WAVELENGTH_MAX_NM)
    vignetting: str = param("none", choices=VIGNETTING)
    glare_fraction: float = param(0.0, min=0.0, max=0.5)
    glare_model: str = param("power_law", choices=OBJECTIVE_GLARE_MODELS)
    glare_exponent: float = param(2.0, gt=0.5, max=6.0)
    glare_core_radius_deg: float = param(0.05, gt=1e-4, max=10.0)
    glare_outer_radius_deg: float = param(30.0, gt=1e-4, max=89.0)
    field_samples: int = param(3, min=1, max=16)           # accuracy
    band_samples: int = param(3, min=1, max=32)            # accuracy
    pupil_rays: int = param(256, min=32, max=2048)         # accuracy
    support_energy: float = param(0.999, min=0.5, lt=1.0)  # accuracy
    guard_max_px: int = param(256, min=0, max=4096)        # accuracy: widest guard band rendered (px)

    def check(self) -> None:
        """Cross-key rule (ObjectiveParamError naming the key); the scene validator calls it."""
        if self.glare_outer_radius_deg < self.glare_core_radius_deg:
            raise ObjectiveParamError(
                f"objective.glare_outer_radius_deg = {self.glare_outer_radius_deg!r}: must be >= "
                f"glare_core_radius_deg = {self.glare_core_radius_deg!r}")

    @property
    def is_identity(self) -> bool:
        """True when the stage changes nothing (delta PSF, no vignetting, no glare)."""
        return self.psf == "delta" and self.vignetting == "none" and self.glare_fraction <= 0


@dataclass(frozen=True)
class ObjectiveParams(ObjectiveSpec):
    """The [objective] keys resolved for one camera: f_number from the layout, the image-plane
    pitch (m) and the sensor QE (a spectra.py source). Every field is checked against its bounds
    (ObjectiveParamError naming `objective.<key>`); the defaults are the DLP6500 + IMX253 set-up."""

    f_number: float = param(DEFAULT_F_NUMBER, min=0.5, max=1000.0)
    pixel_pitch_m: float = param(7.56e-6, gt=1e-7, max=1e-3)   # DMD mirror pitch (DLP6500)
    qe: str = param("file:spectra/imx253_mono_qe.csv")

    def __post_init__(self):
        object.__setattr__(self, "wavelengths_nm", tuple(float(w) for w in self.wavelengths_nm))
        hints = get_type_hints(type(self))
        where = Where(error=ObjectiveParamError)
        for f in dataclasses.fields(self):
            check_value(where, f"objective.{f.name}", getattr(self, f.name), hints[f.name], f.metadata)
        self.check()

    @classmethod
    def resolve(cls, spec: ObjectiveSpec, *, f_number: float, pixel_pitch_m: float, qe: str) -> "ObjectiveParams":
        """The spec's keys with what the camera knows (class docstring)."""
        keys = {f.name: getattr(spec, f.name) for f in dataclasses.fields(ObjectiveSpec)}
        return cls(**{**keys, "f_number": f_number, "pixel_pitch_m": pixel_pitch_m, "qe": qe})


# ---------------------------------------------------------------------------------------------
# Band: which wavelengths the objective is evaluated at, with the sensor's weights
# ---------------------------------------------------------------------------------------------

def sensor_band(params: ObjectiveParams) -> tuple[np.ndarray, np.ndarray]:
    """(wavelengths_nm, weights summing to 1) on spectra's 5 nm grid: the sensor response
    S = QE lambda / (h c) (`spectra.sensor_response_e_per_J`), i.e. the share of the signal of an
    equal-energy spectrum that each wavelength carries."""
    s = spectra.sensor_response_e_per_J(spectra.load_spectrum(params.qe, emissive=True))
    sel = s > 0
    return spectra.WAVELENGTHS_NM[sel], s[sel] / s[sel].sum()


def band(params: ObjectiveParams) -> tuple[np.ndarray, np.ndarray]:
    """Wavelength nodes (nm) and weights (sum 1) for the prescription PSF.

    `wavelengths_nm` given: those, weighted by the sensor response S there. Otherwise the sensor
    band split into `band_samples` parts of equal signal (quantiles of the cumulative S), each
    represented by its S-weighted mean wavelength with its share of the signal: a quadrature
    exact for anything linear in lambda within each part."""
    s_grid = spectra.sensor_response_e_per_J(spectra.load_spectrum(params.qe, emissive=True))
    wl_grid = spectra.WAVELENGTHS_NM
    if params.wavelengths_nm:
        wl = np.asarray(params.wavelengths_nm, float)
        w = np.interp(wl, wl_grid, s_grid)
        if not w.sum() > 0:
            raise ObjectiveParamError(f"objective.wavelengths_nm = {params.wavelengths_nm}: the sensor "
                                      f"({params.qe}) does not respond there")
        return wl, w / w.sum()
    fine = np.arange(wl_grid[0], wl_grid[-1] + 1e-9, 0.1)
    sf = np.interp(fine, wl_grid, s_grid)
    cum = np.cumsum(sf)
    part = np.minimum((params.band_samples * (cum - 0.5 * sf) / cum[-1]).astype(int), params.band_samples - 1)
    wl, w = [], []
    for k in range(params.band_samples):
        m = part == k
        if sf[m].sum() > 0:
            wl.append(float(np.sum(fine[m] * sf[m]) / sf[m].sum()))
            w.append(float(sf[m].sum()))
    w = np.asarray(w)
    return np.asarray(wl), w / w.sum()


def with_accuracy(spec: ObjectiveSpec, accuracy: Accuracy) -> ObjectiveSpec:
    """`spec` with the numerical keys `accuracy` sets (its `objective_*` fields; the rest as in
    `spec`): the run's one Accuracy decides the objective's numerics too (scene/resolve.py fills
    them from [objective])."""
    keys = accuracy.objective_numerics()
    return dataclasses.replace(spec, **keys) if keys else spec
