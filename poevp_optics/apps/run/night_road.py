"""The night-road report (scenes/night_road, a [road] scene: sources/road.py).

Per frame (at the exposure's mid-time): the plate's distance, each of our headlamps' observation
and entrance angles at the plate, its candela toward the plate and E_perp, R_A from the sheeting
table, the closed-form retroreflected luminance sum R_A E_perp / cos theta_v, and how far above
saturation the plate is: the peak of the LDR twin's noise-free signal electrons in the plate's
box over the sensor's saturation capacity (the image the objective forms, through a white DMD),
beside the closed form's luminance over the saturation luminance of the lamps' spectrum.

Summary: the DR the scene demands of the DMD (the attenuation that brings the plate's peak, and
the whole frame's peak, down to saturation: 20 log10 of peak over saturation) beside the DMD's
attenuation floor (mask bit depth: the darkest usable level's PWM share, 20 log10 255 = 48.1 dB
for 8 bits; contrast ratio: off-state leakage, 1/CR; together dmd.attenuation_parts) and the
objective's glare floor (the veil g H * (V x) that the objective lays on the plate, over the
plate's peak: it is in the image the mirrors see, so no mask lowers it; camera/objective/), and which
binds: the DMD when the demand exceeds its floor (the plate stays saturated by the difference),
the glare when the veil over the plate is above the printed ink's closed-form luminance (the
characters lose their contrast whatever the mask).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from poevp_optics.analysis.metrics import crop
from poevp_optics.sources.road import plate_centre_m, plate_geometry


def scene_laws(spec):
    """(candela(h, v), R_A(alpha, beta)) of a road scene: our high beam's file scaled to its
    `intensity_cd` peak, and the plate's sheeting law (retroreflective.py)."""
    from poevp_optics.render.materials.photometric_lamp import load_distribution, resolve_distribution
    from poevp_optics.render.materials.retroreflective import parse_sheeting, retro_law, sheeting_string

    road, base = spec.road, spec.toml_path.parent
    lamp = spec.spectra[road.highbeam]
    dist = load_distribution(str(resolve_distribution(lamp.distribution, base)))
    law = retro_law(parse_sheeting(sheeting_string(spec.sheeting[road.sheeting], base)))

    def candela(h, v):
        return float(dist.relative([h], [v])[0]) * lamp.intensity_cd

    def ra(alpha, beta):
        return float(np.asarray(law.ra_numpy(np.array([alpha]), np.array([beta]))).ravel()[0])

    return candela, ra


def saturation_luminance_cd_m2(spec, camera, frame_index: int) -> float:
    """Luminance (cd m-2) of a surface with the high beams' spectrum (LED light reflected by a
    flat sheeting) that fills the saturation capacity through a white DMD in one exposure."""
    from poevp_optics.sources import spectra

    lamp = spec.spectra[spec.road.highbeam]
    unit = spectra.scale_to_photometric(spectra.load_spectrum(lamp.source, emissive=True), 1.0)
    qe = spectra.load_spectrum(camera.params.qe, emissive=True)
    per_cd = spectra.integrate(spectra.sensor_response_e_per_J(qe) * unit)
    e_per_cd = per_cd * camera.electrons_per_radiance() * camera.white_exposure_s(frame_index)
    return camera.params.saturation_capacity_e / e_per_cd


def frame_record(spec, camera, fc, laws) -> dict:
    """The plate's per-frame numbers (module docstring); `laws` from sources.road.scene_laws."""
    ex = fc.exposure
    t0, t1 = spec.timing.exposure_window_s(ex.index)
    geo = plate_geometry(spec.road, plate_centre_m(spec.resolved.render, 0.5 * (t0 + t1)), *laws)
    box = fc.box
    sat_e = camera.params.saturation_capacity_e
    rec = {"distance_m": geo["camera_distance_m"], "viewing_deg": geo["viewing_deg"], "lamps": geo["lamps"],
           "retro_luminance_cd_m2": geo["retro_luminance_cd_m2"]}
    l_sat = saturation_luminance_cd_m2(spec, camera, ex.index)
    rec["saturation_luminance_cd_m2"] = l_sat
    rec["closed_form_over_saturation"] = geo["retro_luminance_cd_m2"] / l_sat
    if box:
        roi = crop(fc.ldr.signal_e, box)
        rec["peak_over_saturation"] = float(np.max(roi)) / sat_e
        rec["p90_over_saturation"] = float(np.percentile(roi, 90)) / sat_e     # the sheeting, away from the ink
        veil = camera.glare_veil(ex.radiance.data)
        if veil is not None:
            v = crop(camera.to_sensor(veil), box)
            peak = float(np.max(crop(fc.truth_s, box)))
            rec["glare_veil_over_peak"] = float(np.mean(v)) / peak if peak > 0 else None
    rec["frame_peak_over_saturation"] = float(np.max(fc.ldr.signal_e)) / sat_e
    return rec


def _ink_over_sheeting(spec, rec) -> float:
    """Closed form: the printed ink's diffuse luminance rho E cos(beta) / pi (rho its mean
    reflectance) over the sheeting's retroreflected luminance, summed over our lamps."""
    from poevp_optics.sources import spectra

    rho = float(np.mean(spectra.load_spectrum(spec.spectra["ink_black"].source, emissive=False)))
    ink = sum(rho * v["illuminance_perp_lx"] * math.cos(math.radians(v["entrance_deg"])) / math.pi
              for v in rec["lamps"].values())
    return ink / rec["retro_luminance_cd_m2"] if rec["retro_luminance_cd_m2"] > 0 else math.inf


def summary(spec, camera, per_frame: list[dict]) -> dict:
    """DR demand beside the DMD's floor and the objective's glare floor, and which binds."""
    from poevp_optics.camera.dmd import attenuation_parts

    recs = [f["plate"] for f in per_frame if "plate" in f]
    peaks = [r["peak_over_saturation"] for r in recs if "peak_over_saturation" in r]
    demand_db = 20 * math.log10(max(peaks)) if peaks and max(peaks) > 0 else 0.0
    frame_db = 20 * math.log10(max(r["frame_peak_over_saturation"] for r in recs))
    out = {"per_frame": [{"index": f["index"], **f["plate"]} for f in per_frame if "plate" in f],
           "plate_demand_db": demand_db, "frame_demand_db": frame_db}
    if camera.dmd is not None:
        parts = attenuation_parts(spec.dmd, camera.schedule(0), min(spec.mask.min_level, camera.top_level))
        out["dmd_floor_db"] = parts["gain_db"]
        out["dmd_floor_parts_db"] = {k: (-20 * math.log10(v) if v > 0 else None) for k, v in parts["parts"].items()}
        out["dmd_binding_part"] = parts["binding"]
    veils = [r["glare_veil_over_peak"] for r in recs if r.get("glare_veil_over_peak")]
    if veils:
        out["glare_floor_db"] = -20 * math.log10(max(veils))
        ink = min(_ink_over_sheeting(spec, r) for r in recs)
        out["ink_over_sheeting_db"] = -20 * math.log10(ink)
    out["binding"], out["statement"] = _binding(out)
    return out


def _binding(s: dict) -> tuple[str, str]:
    dmd, glare, need = s.get("dmd_floor_db"), s.get("glare_floor_db"), s["plate_demand_db"]
    text = (f"the plate peaks {10 ** (need / 20):.0f}x above saturation ({need:.1f} dB of attenuation "
            f"needed; the whole frame {s['frame_demand_db']:.1f} dB)")
    if dmd is not None:
        text += f"; the DMD's floor is {dmd:.1f} dB ({s['dmd_binding_part']} binds it)"
    if glare is not None:
        text += (f"; the objective's veil on the plate is {glare:.1f} dB below its peak, the printed ink "
                 f"{s['ink_over_sheeting_db']:.1f} dB below the sheeting")
    if dmd is not None and s["frame_demand_db"] > dmd:
        text += f"; the frame's brightest sources stay {s['frame_demand_db'] - dmd:.1f} dB saturated whatever the mask"
    if dmd is not None and need > dmd:
        return "dmd", text + f": the DMD floor binds, the plate stays {need - dmd:.1f} dB saturated"
    if glare is not None and glare < s["ink_over_sheeting_db"]:
        return "glare", text + ": the objective's glare binds: it veils the ink whatever the mask"
    return "none", text + ": neither binds on the plate"


def plot(path: Path, night: dict, title: str) -> None:
    """Peak over saturation vs distance: rendered (LDR twin) and closed form (retroreflection)."""
    from poevp_optics.core.io import atomic_path
    from poevp_optics.core.runtime import pyplot

    plt = pyplot()
    rows = night["per_frame"]
    d = [r["distance_m"] for r in rows]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.semilogy(d, [r.get("peak_over_saturation", np.nan) for r in rows], "o-", label="rendered plate peak (LDR twin)")
    ax.semilogy(d, [r.get("p90_over_saturation", np.nan) for r in rows], "^-", label="rendered plate, 90th percentile")
    ax.semilogy(d, [r["closed_form_over_saturation"] for r in rows], "s--",
                label="closed form: sum R_A E / cos(theta_v) / L_sat")
    ax.axhline(1.0, c="k", lw=0.8)
    if "dmd_floor_db" in night:
        ax.axhline(10 ** (night["dmd_floor_db"] / 20), c="C3", ls=":", label=f"DMD floor {night['dmd_floor_db']:.1f} dB")
    ax.set(xlabel="plate distance (m)", ylabel="peak / saturation", title=title)
    ax.invert_xaxis()
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
