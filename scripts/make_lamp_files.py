"""Generate the shipped headlamp photometric files and their plots (assets/lamps/).

    python scripts/make_lamp_files.py        # writes high_beam.ies, low_beam.ies, low_beam.ldt, *.png

Each beam is a smooth analytic candela model, tabulated on a fine grid, then checked against the
regulation test points below: the script stops if any point misses its limit. The models are ours
(not measured lamps); the points and limits are what the files are built to honour.

Angles: H (+ right), V (+ up), degrees, seen from behind the lamp; right-hand traffic.

Low beam (passing beam), UN Regulation No. 112 (headlamps emitting an asymmetrical passing beam),
Annex 3 test points, as transcribed here (check against the regulation's current series before
relying on a number):
    B50L  0.57U 3.43L  <= 350 cd      (eyes of an oncoming driver at 50 m)
    75R   0.57D 1.15R  >= 10 100 cd
    75L   0.57D 3.43L  <= 10 600 cd
    50L   0.86D 3.43L  <= 13 200 cd
    50R   0.86D 1.72R  >= 10 100 cd
    50V   0.86D 0      >= 5 100 cd
    25L   1.72D 9L     >= 1 700 cd
    25R   1.72D 9R     >= 1 700 cd
    zone III (above the cut-off: here from 0.5 deg above it to 4U, 8L-8R) <= 625 cd
and FMVSS No. 108 (49 CFR 571.108) lower beam 10U-90U <= 125 cd over the whole width (NHTSA
interpretation letter to Herr Spingler, 1999: the area 90L-90R, 10U-90U).
The cut-off: horizontal at 0.57D left of V, rising at 15 deg to the right up to 0.57U (the UN R112 "elbow"),
10-90 % within 0.2 deg; ~300 cd above it and tens of kcd below (FACTS.md "Headlamp photometry").

High beam (driving beam): peak 100 kcd on H-V (typical lamps 40-150 kcd; UN R48 caps the sum of
a vehicle's driving-beam maxima at 430 kcd, FACTS.md); UN R112 driving-beam spread as
transcribed here: H-2.5L/R >= Imax / 2 and H-5L/R >= Imax / 4 ... I_max within [40 500, 215 000] cd.

Files: IES LM-63-2002 photometric type A (the automotive convention; H, V as above), written
with photompy; the low beam also as EULUMDAT (type C, gamma = 90 deg horizontal, C = 0 ahead,
C = 90 to the left), written and read with eulumdat-py.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "assets" / "lamps"

HIGH_PEAK_CD = 100_000.0

LOW_BEAM_POINTS = [  # (name, V deg (+up), H deg (+right), op, limit cd, source)
    ("B50L", 0.57, -3.43, "<=", 350.0, "UN R112"),
    ("75R", -0.57, 1.15, ">=", 10_100.0, "UN R112"),
    ("75L", -0.57, -3.43, "<=", 10_600.0, "UN R112"),
    ("50L", -0.86, -3.43, "<=", 13_200.0, "UN R112"),
    ("50R", -0.86, 1.72, ">=", 10_100.0, "UN R112"),
    ("50V", -0.86, 0.0, ">=", 5_100.0, "UN R112"),
    ("25L", -1.72, -9.0, ">=", 1_700.0, "UN R112"),
    ("25R", -1.72, 9.0, ">=", 1_700.0, "UN R112"),
]
HIGH_BEAM_POINTS = [
    ("HV", 0.0, 0.0, ">=", 40_500.0, "UN R112 (I_max at H-V)"),
    ("HV max", 0.0, 0.0, "<=", 215_000.0, "UN R112"),
    ("H-2.5L", 0.0, -2.5, ">=", HIGH_PEAK_CD / 2, "UN R112"),
    ("H-2.5R", 0.0, 2.5, ">=", HIGH_PEAK_CD / 2, "UN R112"),
    ("H-5L", 0.0, -5.0, ">=", HIGH_PEAK_CD / 4, "UN R112"),
    ("H-5R", 0.0, 5.0, ">=", HIGH_PEAK_CD / 4, "UN R112"),
]


def _grid(fine_step, fine_half, coarse):
    fine = np.arange(-fine_half, fine_half + 1e-9, fine_step)
    return np.unique(np.round(np.concatenate([fine, coarse, -coarse]), 6))


H_DEG = _grid(0.25, 12.0, np.array([14, 16, 18, 20, 25, 30, 35, 40, 45, 50, 60, 70, 80, 90.0]))
V_DEG = _grid(0.05, 3.0, np.array([3.5, 4, 5, 6, 8, 10, 12, 15, 20, 30, 45, 60, 75, 90.0]))


def high_beam_cd(h, v):
    """Driving beam: an elliptical hot spot on H-V and a wide, low fill."""
    core = np.exp(-0.5 * (h / 4.5) ** 2 - 0.5 * (v / 1.8) ** 2)
    fill = 0.06 * np.exp(-0.5 * (h / 18.0) ** 2 - 0.5 * ((v + 1.0) / 5.0) ** 2)
    edge = np.clip((90.0 - np.abs(h)) / 10.0, 0, 1) * np.clip((90.0 - np.abs(v)) / 10.0, 0, 1)
    return HIGH_PEAK_CD * (core + fill) / (1 + 0.06 * math.exp(-0.5 * 0.04)) * edge


def cutoff_deg(h):
    """UN R112 asymmetric cut-off: 0.57D left of V, rising at 15 deg to the right up to 0.57U."""
    return np.minimum(-0.57 + np.maximum(h, 0.0) * math.tan(math.radians(15.0)), 0.57)


def low_beam_cd(h, v):
    """Passing beam: hot spot below and right of H-V, wide foreground fill, sharp cut-off."""
    below = (19_000.0 * np.exp(-0.5 * ((h - 2.0) / 3.2) ** 2 - 0.5 * ((v + 1.6) / 1.0) ** 2)
             + 5_500.0 * np.exp(-0.5 * (h / 16.0) ** 2 - 0.5 * ((v + 2.2) / 2.5) ** 2))
    above = 300.0 * np.exp(-np.maximum(v, 0.0) / 3.0) * np.exp(-0.5 * (h / 30.0) ** 2)
    step = 0.5 * (1.0 + np.tanh((cutoff_deg(h) - v) / 0.09))    # logistic: 10-90 % over 0.2 deg
    edge = np.clip((90.0 - np.abs(h)) / 10.0, 0, 1) * np.clip((90.0 - np.abs(v)) / 10.0, 0, 1)
    return (above + step * below) * edge


def check(points, table_fn, name):
    ok = True
    for label, v, h, op, limit, src in points:
        value = float(table_fn(h, v))
        good = value <= limit if op == "<=" else value >= limit
        ok &= good
        print(f"  {name} {label:7s} V={v:+.2f} H={h:+.2f}: {value:9.0f} cd {op} {limit:7.0f} ({src})"
              f"{'' if good else '   <-- FAILS'}")
    return ok


def zone_checks(table_fn):
    hh, vv = np.meshgrid(np.linspace(-8, 8, 65), np.linspace(0.0, 4, 81))
    zone3 = float(np.max(np.where(vv >= cutoff_deg(hh) + 0.5, table_fn(hh, vv), 0.0)))
    hh, vv = np.meshgrid(np.linspace(-90, 90, 181), np.linspace(10, 90, 81))
    up = float(np.max(table_fn(hh, vv)))
    print(f"  low zone III (0.5 deg above the cut-off to 4U, 8L-8R) max {zone3:.0f} cd <= 625 (UN R112); 10U-90U max {up:.0f} cd <= 125 (FMVSS 108)")
    return zone3 <= 625 and up <= 125


def _header(kind):
    return dict(manufacturer="poevp_optics (synthetic)", lumcat=f"{kind}-beam model",
                test=f"scripts/make_lamp_files.py: analytic {kind} beam honouring UN R112 / FMVSS 108 test points",
                testlab="none (generated, not measured)", issuedate="2026-11-23")


def write_ies(path, cd_fn, kind):
    from photompy import PhotometricType, create_ies

    hh, vv = np.meshgrid(H_DEG, V_DEG, indexing="ij")
    values = np.round(cd_fn(hh, vv), 1)
    ies = create_ies(V_DEG, H_DEG, values, photometric_type=PhotometricType.A, **_header(kind))
    ies.write(str(path))
    return values


def write_ldt_low(path):
    """EULUMDAT (type C): C planes every 1 deg, gamma in 0.1-deg steps near the horizon. Written
    with eulumdat-py: photompy 0.3.1's LDT writer leaves out each lamp set's colour temperature,
    colour rendering and wattage lines and the ten direct ratios, so its files do not follow the
    EULUMDAT layout (LiTG 1990) and other readers mis-parse them."""
    from pyldt import Ldt, LdtHeader, LdtWriter

    c = np.arange(0.0, 360.0, 1.0)
    g = np.unique(np.round(np.concatenate([np.arange(0, 180.01, 2.5), np.arange(85, 95.001, 0.1)]), 4))
    cc, gg = np.meshgrid(c, g, indexing="ij")
    cr, gr = np.radians(cc), np.radians(gg)
    d = np.stack([np.sin(gr) * np.sin(cr), -np.cos(gr), np.sin(gr) * np.cos(cr)], axis=-1)
    h = np.degrees(np.arctan2(-d[..., 0], d[..., 2]))
    v = np.degrees(np.arcsin(np.clip(d[..., 1], -1, 1)))
    values = np.round(low_beam_cd(h, v) * (np.abs(h) <= 90), 1)
    # one lamp of 1000 lm nominal flux: the file's cd per 1000 lm are then the candela themselves
    header = LdtHeader(company="poevp_optics (synthetic)", ityp=1, isym=0, mc=len(c), dc=1.0, ng=len(g),
                       dg=0.0, report_number="scripts/make_lamp_files.py",
                       luminaire_name="low-beam model (UN R112 / FMVSS 108 test points)",
                       luminaire_number="low_beam", file_name=path.name, date_user="2026-11-23",
                       dff=0.0, lorl=100.0, conv_factor=1.0, tilt=0.0, n_sets=1, num_lamps=[1],
                       lamp_types=["LED model"], lamp_flux=[1000.0], lamp_cct=["5109"], lamp_cri=["-"],
                       lamp_watt=[0.0], direct_ratios=[0.0] * 10, c_angles=list(c), g_angles=list(g))
    if path.exists():
        path.unlink()          # LdtWriter would otherwise write beside it under a new name
    LdtWriter.write(Ldt(header=header, intensities=values.tolist()), str(path))


def plot(path, cd_fn, title, points):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    h = np.linspace(-30, 30, 601)
    v = np.linspace(-8, 6, 281)
    hh, vv = np.meshgrid(h, v)
    cd = cd_fn(hh, vv)
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.2), gridspec_kw={"width_ratios": [2.2, 1]})
    im = ax[0].pcolormesh(hh, vv, np.log10(np.maximum(cd, 1.0)), shading="auto", cmap="inferno")
    cs = ax[0].contour(hh, vv, cd, levels=[125, 625, 1000, 5000, 10000, 20000, 50000], colors="w", linewidths=0.6)
    ax[0].clabel(cs, fmt="%d", fontsize=7)
    for label, pv, ph, op, limit, _ in points:
        ax[0].plot(ph, pv, "c+", ms=8)
        ax[0].annotate(f"{label} {op}{limit:.0f}", (ph, pv), fontsize=6, color="c", xytext=(3, 3),
                       textcoords="offset points")
    ax[0].set(xlabel="H (deg, + right)", ylabel="V (deg, + up)", title=f"{title}: log10 cd")
    fig.colorbar(im, ax=ax[0])
    for vcut in (-2.0, -0.86, 0.0, 0.57):
        ax[1].semilogy(h, np.maximum(cd_fn(h, vcut), 1.0), label=f"V = {vcut:+.2f}")
    ax[1].set(xlabel="H (deg)", ylabel="cd", title="horizontal sections")
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    OUT.mkdir(parents=True, exist_ok=True)
    print("high beam:")
    ok = check(HIGH_BEAM_POINTS, high_beam_cd, "high")
    print("low beam:")
    ok &= check(LOW_BEAM_POINTS, low_beam_cd, "low")
    ok &= zone_checks(low_beam_cd)
    if not ok:
        print("a regulation test point is missed: files not written", file=sys.stderr)
        return 1
    write_ies(OUT / "high_beam.ies", high_beam_cd, "high")
    write_ies(OUT / "low_beam.ies", low_beam_cd, "low")
    write_ldt_low(OUT / "low_beam.ldt")
    plot(OUT / "high_beam.png", high_beam_cd, "high beam (high_beam.ies)", HIGH_BEAM_POINTS)
    plot(OUT / "low_beam.png", low_beam_cd, "low beam (low_beam.ies / .ldt)", LOW_BEAM_POINTS)
    print(f"wrote {', '.join(sorted(p.name for p in OUT.iterdir()))} in {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
