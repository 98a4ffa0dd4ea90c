"""Image sensor: parameters and presets (noise model: issue 3).

Conventions: electrons `_e`, digital numbers `_dn`; conversion gain `gain_dn_per_e` is DN per
electron (signal_dn = offset_dn + gain_dn_per_e * electrons).

Parameter table (`[sensor]`):

| key                  | type  | unit     | IMX253 preset | sweepable |
|----------------------|-------|----------|---------------|-----------|
| bits                 | int   | bit      | 8             | yes |
| full_well_e          | float | e-       | 10500         | yes |
| read_noise_e         | float | e- rms   | 2.6           | yes |
| gain_dn_per_e        | float | DN/e-    | 255/10500     | yes |
| offset_dn            | float | DN       | 0             | yes |
| dark_current_e_per_s | float | e-/s     | 3.0           | yes |
| prnu                 | float | fraction | 0.005         | yes |
| dsnu_e               | float | e- rms   | 0.8           | yes |
| pixel_pitch_m        | float | m        | 3.45e-6       | yes |
| f_number             | float | -        | 2.8           | yes |
| optical_throughput   | float | fraction | 0.9           | yes |
| qe                   | str   | e-/photon| IMX253 table  | no  |
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from .scene import SensorSpec


@dataclass(frozen=True)
class SensorParams:
    """Resolved sensor parameters (SI units in names)."""

    name: str
    bits: int
    full_well_e: float
    read_noise_e: float
    gain_dn_per_e: float
    offset_dn: float
    dark_current_e_per_s: float
    prnu: float
    dsnu_e: float
    pixel_pitch_m: float
    f_number: float
    optical_throughput: float
    qe: str
    noise: bool = True
    seed: int = 0

    @property
    def max_dn(self) -> int:
        return (1 << self.bits) - 1


#: Sony IMX253 as in the paper's FLIR GS3-U3-123S6M-C, read out at 8 bit (paper Sec. 7).
#: Saturation 10.5 ke-, temporal dark noise 2.6 e-, DR about 72 dB: EMVA 1288 reports of the
#: same-pixel Pregius family (IMX250/252/253, 3.45 um) in Matrix Vision mvBlueCOUGAR-X/XD
#: manuals (saturation 10.5-10.7 ke-, dark noise 2.3-2.9 e-, DR 71.2-71.3 dB; FACTS.md).
#: Dark current 3 e-/s, DSNU 0.8 e-, PRNU 0.5 %: same reports (order of magnitude at 25 C).
#: Gain maps full well to the top code. f/2.8 and 0.9 lens transmission: our default C-mount
#: lens (the paper does not state its lens).
IMX253 = SensorParams(
    name="IMX253", bits=8, full_well_e=10500.0, read_noise_e=2.6, gain_dn_per_e=255.0 / 10500.0,
    offset_dn=0.0, dark_current_e_per_s=3.0, prnu=0.005, dsnu_e=0.8, pixel_pitch_m=3.45e-6,
    f_number=2.8, optical_throughput=0.9, qe="file:spectra/imx253_mono_qe.csv")

#: A generic 12-bit machine-vision sensor (5.86 um, 32 ke-, 6 e- read noise; typical of
#: Sony IMX174-class EMVA data) with the same QE curve, for comparisons.
GENERIC = SensorParams(
    name="generic", bits=12, full_well_e=32000.0, read_noise_e=6.0, gain_dn_per_e=4095.0 / 32000.0,
    offset_dn=0.0, dark_current_e_per_s=10.0, prnu=0.01, dsnu_e=2.0, pixel_pitch_m=5.86e-6,
    f_number=2.8, optical_throughput=0.9, qe="file:spectra/imx253_mono_qe.csv")

PRESETS = {"IMX253": IMX253, "generic": GENERIC}


def resolve_sensor(spec: SensorSpec) -> SensorParams:
    """Preset values with the scene's overrides (NaN, -1 and "" mean "keep the preset")."""
    base = PRESETS[spec.preset]
    changes = {}
    for f in dataclasses.fields(SensorSpec):
        if f.name == "preset":
            continue
        v = getattr(spec, f.name)
        if (isinstance(v, float) and math.isnan(v)) or v == -1 or v == "":
            continue
        changes[f.name] = v
    return dataclasses.replace(base, **changes)
