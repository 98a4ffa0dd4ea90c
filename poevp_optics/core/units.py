"""Physical constants and unit helpers. SI inside; names carry units (`_m`, `_s`, `_nm`, `_e`).

Constants are the exact SI 2019 values (BIPM SI brochure, 9th ed.); K_m is the CIE maximum
luminous efficacy of radiation for photopic vision, 683.002 lm W-1 (CIE 018:2019; the SI
definition fixes 683 lm W-1 at 540 THz, i.e. 555.016 nm, which rounds to 683.002 at the
CIE 1924 V(lambda) peak of 555 nm).
"""

import numpy as np

PLANCK_J_S = 6.62607015e-34
SPEED_OF_LIGHT_M_PER_S = 299792458.0
LUMINOUS_EFFICACY_MAX_LM_PER_W = 683.002
NM_PER_M = 1e9

#: Unit string of the rendered quantity: sensor-weighted photon radiance, i.e. photo-electrons
#: per second per square metre of pupil-projected area per steradian (DESIGN.md).
PHOTON_RADIANCE_UNIT = "e- s-1 m-2 sr-1"


def photons_per_joule(wavelength_nm):
    """Photons per joule of radiant energy at `wavelength_nm` (array-like): lambda / (h c)."""
    return (wavelength_nm / NM_PER_M) / (PLANCK_J_S * SPEED_OF_LIGHT_M_PER_S)


def to_8bit(dn: np.ndarray, max_dn: int) -> np.ndarray:
    """Scale DN of any bit depth to the 0-255 range (for entropy and previews); float64."""
    return np.clip(np.asarray(dn, dtype=np.float64) * (255.0 / max_dn), 0, 255)
