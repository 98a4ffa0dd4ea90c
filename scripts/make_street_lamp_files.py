"""Generate the shipped street-light photometric files (assets/lamps/street_*.ldt / .ies).

    .venv/bin/python scripts/make_street_lamp_files.py

Each luminaire is an analytic model (ours, not a measured product): it is designed by the
illuminance it puts on the road below it, and its candela follow from that. In the luminaire's
frame (type C photometry, LM-63 / EULUMDAT: gamma from the nadir, C = 0 along the road, C = 90
across it toward the carriageway), a ray toward (gamma, C) meets the road, h below, at the offset
h (u, v) with u = tan(gamma) cos(C) along and v = tan(gamma) sin(C) across the road. The designed
horizontal illuminance there is

    E(u, v) = E0 exp(-(|u| / u0)^4) k(v),  k(v) = exp(-(|v - v_c| / v_w)^4)

(a flat-topped footprint along the road, cut off before the horizon), and the intensity is
I(gamma, C) = E h^2 / cos^3(gamma) (E = I cos(gamma) / d^2, d = h / cos(gamma)). I is 0 at and
above the horizon (gamma >= 90 deg: a full cut-off luminaire, no light above the horizontal; EN
13201-2 / CIE 115 favour them against glare and sky glow). Values are absolute candela at the
nominal mounting height h = 10 m (street lights are typically 8-12 m high, FACTS.md); the files
are written for 1000 lm so that cd per 1000 lm are the candela themselves.

street_led.ldt: an LED luminaire (EULUMDAT), E0 = 12 lx, u0 = 1.8 (the footprint reaches +-18 m
along the road at 10 m), across v_c = 0.35, v_w = 0.75 (mostly over the carriageway): 5.3 klm,
peak 5.1 kcd, the output of a 40-50 W LED road luminaire; about 11 lx under it, so with the CIE R3
asphalt's average luminance coefficient q0 = 0.07 (CIE 144) a road luminance near 0.8 cd m-2
(EN 13201-2 classes M4-M3 ask 0.75-1.0; an estimate, not a lighting design). street_hps.ies: a
high-pressure sodium lantern (IES LM-63, type C), wider and flatter: E0 = 15 lx, u0 = 2.0, v_c =
0.3, v_w = 0.9: 8.9 klm, peak 7.8 kcd (a 100 W HPS lamp gives ~10 klm). Their spectra are the scene's `[spectra]` (LED: cie:LED-B3;
HPS: cie:HP1, CIE 015:2018's standard high-pressure sodium lamp).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "assets" / "lamps"
HEIGHT_M = 10.0
C_DEG = np.arange(0.0, 360.0, 5.0)
G_DEG = np.unique(np.concatenate([np.arange(0.0, 80.0, 2.5), np.arange(80.0, 90.0, 1.0), np.arange(90.0, 180.01, 10.0)]))
LUMINAIRES = {  # name: (E0 lx, u0, v_c, v_w)
    "street_led": (12.0, 1.8, 0.35, 0.75),
    "street_hps": (15.0, 2.0, 0.30, 0.90),
}


def candela(name, c_deg, g_deg):
    """I(gamma, C) in cd of the luminaire `name` (module docstring)."""
    e0, u0, vc, vw = LUMINAIRES[name]
    c, g = np.radians(c_deg), np.radians(g_deg)
    below = g_deg < 90.0
    cos_g = np.where(below, np.cos(g), 1.0)
    t = np.where(below, np.tan(np.where(below, g, 0.0)), 0.0)
    u, v = t * np.cos(c), t * np.sin(c)
    e = e0 * np.exp(-(np.abs(u) / u0) ** 4) * np.exp(-(np.abs(v - vc) / vw) ** 4)
    return np.where(below, e * HEIGHT_M ** 2 / cos_g ** 3, 0.0)


def flux_lm(name):
    """Luminous flux (lm) of the table, by the midpoint rule over the sphere."""
    c = np.radians(np.arange(0.0, 360.0, 0.5) + 0.25)
    g = np.radians(np.arange(0.0, 90.0, 0.05) + 0.025)
    cc, gg = np.meshgrid(c, g, indexing="ij")
    return float(np.sum(candela(name, np.degrees(cc), np.degrees(gg)) * np.sin(gg)) * np.radians(0.5) * np.radians(0.05))


def write_ldt(path, name):
    from pyldt import Ldt, LdtHeader, LdtWriter

    cc, gg = np.meshgrid(C_DEG, G_DEG, indexing="ij")
    values = np.round(candela(name, cc, gg), 2)
    header = LdtHeader(company="poevp_optics (synthetic)", ityp=3, isym=0, mc=len(C_DEG), dc=5.0, ng=len(G_DEG),
                       dg=0.0, report_number="scripts/make_street_lamp_files.py",
                       luminaire_name=f"{name} model (designed road illuminance, full cut-off)",
                       luminaire_number=name, file_name=path.name, date_user="2026-11-26",
                       dff=100.0, lorl=100.0, conv_factor=1.0, tilt=0.0, n_sets=1, num_lamps=[1],
                       lamp_types=["LED model"], lamp_flux=[1000.0], lamp_cct=["4000"], lamp_cri=["70"],
                       lamp_watt=[0.0], direct_ratios=[0.0] * 10, c_angles=list(C_DEG), g_angles=list(G_DEG))
    if path.exists():
        path.unlink()          # LdtWriter would otherwise write beside it under a new name
    LdtWriter.write(Ldt(header=header, intensities=values.tolist()), str(path))


def write_ies(path, name):
    from photompy import PhotometricType, create_ies

    c = np.append(C_DEG, 360.0)
    cc, gg = np.meshgrid(c, G_DEG, indexing="ij")
    values = np.round(candela(name, cc, gg), 2)
    ies = create_ies(G_DEG, c, values, photometric_type=PhotometricType.C, manufacturer="poevp_optics (synthetic)",
                     lumcat=f"{name} model", test="scripts/make_street_lamp_files.py: designed road illuminance, "
                     "full cut-off", testlab="none (generated, not measured)", issuedate="2026-11-26")
    ies.write(str(path))


def main() -> int:
    OUT.mkdir(parents=True, exist_ok=True)
    write_ldt(OUT / "street_led.ldt", "street_led")
    write_ies(OUT / "street_hps.ies", "street_hps")
    for name in LUMINAIRES:
        peak = float(candela(name, *np.meshgrid(C_DEG, G_DEG, indexing="ij")).max())
        print(f"{name}: flux {flux_lm(name):.0f} lm, peak {peak:.0f} cd (at h = {HEIGHT_M:g} m)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
