"""Every plate in view, one record each: with `render.roi_shape = "plates"` (render/roi.py) a
run's frame holds `plates`, one entry per vehicle plate of the scene, and report.json's
`metrics.plates` sums them up per plate; report.html shows the table and `plates.md` (written
beside it) holds the same in markdown.

Per frame and plate (`per_frame[i].plates[k]`):

| key              | unit | meaning |
|------------------|------|---------|
| id, text         | -    | the [vehicle.<id>] and its plate_text |
| in_view          | -    | its box lies on the film and the camera sees part of it |
| distance_m       | m    | camera to the plate's centre, averaged over the exposure's radiance samples |
| visible_fraction | -    | share of the plate's test points the camera sees (render/roi.py) |
| box              | px   | its box on the sensor grid (y0, x0, y1, x1), union over the exposure |
| height_px        | px   | that box's height on the sensor |
| white            | -    | 90th percentile of the plate's pixels in the box in the 8-bit capture / 255 (ldr, encoded: analysis/metrics.py plate_white_fraction): the sensor pixels whose centre images a mirror that shows the plate (render/roi.py `PlateView.pixels`), so a car hiding part of the plate is left out |
| in_band          | -    | encoded white within the mask's band [mask.band_low, mask.band_high] |
| rel_error        | -    | RMS Monte Carlo standard error / mean radiance over the plate's pixels in its box (render/progressive.py rel_error) |
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from poevp_optics.analysis.metrics import plate_white_fraction, to_8bit


def frame_plates(spec, camera, ex, ldr_dn, enc_dn) -> list[dict]:
    """The frame's per-plate records (module table) from the exposure's `plates`."""
    max_dn = camera.params.max_dn
    lo, hi = spec.mask.band_low, spec.mask.band_high
    ldr8, enc8 = to_8bit(ldr_dn, max_dn), to_8bit(enc_dn, max_dn)
    out = []
    for p in ex.plates:
        box = camera.box_to_sensor(tuple(p["box"])) if p.get("box") is not None else None
        rec = {"id": p["id"], "text": p["text"], "in_view": box is not None, "distance_m": p["distance_m"],
               "visible_fraction": p["visible_fraction"], "box": list(box) if box else None,
               "height_px": int(box[2] - box[0]) if box else None, "rel_error": p["rel_error"]}
        if box is not None:
            seen = seen_on_sensor(camera, p, box)
            w_ldr, w_enc = plate_white_fraction(ldr8, box, seen=seen), plate_white_fraction(enc8, box, seen=seen)
            rec["white"] = {"ldr": w_ldr, "encoded": w_enc}
            rec["in_band"] = bool(w_enc is not None and lo <= w_enc <= hi)
        else:
            rec["white"], rec["in_band"] = None, None
        out.append(rec)
    return out


def seen_on_sensor(camera, plate: dict, sensor_box) -> np.ndarray | None:
    """Which pixels of `sensor_box` show the plate: each sensor pixel's centre mapped onto the
    mirror grid (camera/registration.py, the relay's registration) and looked up in the plate's
    `seen` rows over its mirror-grid box (render/exposures.py PlateTrack.records). None where
    the exposure holds no such rows (a stored render without them: the whole box counts)."""
    rows = plate.get("seen")
    if rows is None or plate.get("box") is None:
        return None
    seen = np.array([[c == "1" for c in r] for r in rows], dtype=bool).reshape(len(rows), -1)
    my0, mx0 = plate["box"][0], plate["box"][1]
    y0, x0, y1, x1 = sensor_box
    sy, sx = np.meshgrid(np.arange(y0, y1) + 0.5, np.arange(x0, x1) + 0.5, indexing="ij")
    mx, my = camera.sensor_to_mirror(sx, sy)
    iy, ix = np.floor(my).astype(np.int64) - my0, np.floor(mx).astype(np.int64) - mx0
    ok = (iy >= 0) & (iy < seen.shape[0]) & (ix >= 0) & (ix < seen.shape[1])
    out = np.zeros(sy.shape, bool)
    out[ok] = seen[iy[ok], ix[ok]]
    return out


def _range(vals):
    vals = [v for v in vals if v is not None]
    return [float(min(vals)), float(max(vals))] if vals else None


def plate_summary(spec, per_frame) -> dict:
    """{plate id: summary} over the run: frames in view, distance and height ranges; over the
    frames after the white initialisation frames with the plate in view, the encoded white's
    mean and the fraction in band (None: no such frame); the mean and largest MC error."""
    ids = []
    for f in per_frame:
        for p in f.get("plates") or []:
            if p["id"] not in ids:
                ids.append(p["id"])
    out = {}
    for ident in ids:
        recs = [(f, p) for f in per_frame for p in f.get("plates") or [] if p["id"] == ident]
        seen = [(f, p) for f, p in recs if p["in_view"]]
        loop = [p for f, p in seen if not f.get("init")]
        errs = [p["rel_error"] for _, p in seen if p["rel_error"] is not None]
        whites = [p["white"]["encoded"] for p in loop if p["white"] and p["white"]["encoded"] is not None]
        out[ident] = {
            "text": recs[0][1]["text"], "frames": len(recs), "frames_in_view": len(seen),
            "distance_m": _range([p["distance_m"] for _, p in seen]),
            "height_px": _range([p["height_px"] for _, p in seen]),
            "white_encoded_mean": float(np.mean(whites)) if whites else None,
            "in_band_fraction_after_init": (float(np.mean([bool(p["in_band"]) for p in loop])) if loop else None),
            "frames_in_band_after_init": sum(bool(p["in_band"]) for p in loop),
            "frames_after_init_in_view": len(loop),
            "rel_error_mean": float(np.mean(errs)) if errs else None,
            "rel_error_max": float(np.max(errs)) if errs else None,
        }
    return {"band": [spec.mask.band_low, spec.mask.band_high], "per_plate": out,
            "definition": "white: 90th percentile of the plate's box in the 8-bit capture / 255; in band: "
                          "encoded white within [mask.band_low, mask.band_high], over the frames after the white "
                          "initialisation frames with the plate in view; rel_error: RMS MC standard error / mean "
                          "radiance over the plate's box"}


def _cells(ident, s) -> list[str]:
    def rng(r, fmt):
        return "-" if r is None else (fmt.format(r[0]) if r[0] == r[1] else f"{fmt.format(r[0])}-{fmt.format(r[1])}")

    def pct(v):
        return "-" if v is None else f"{v * 100:.3g} %"

    band = ("-" if s["in_band_fraction_after_init"] is None else
            f"{s['frames_in_band_after_init']}/{s['frames_after_init_in_view']} "
            f"({s['in_band_fraction_after_init'] * 100:.0f} %)")
    return [ident, s["text"] or "-", f"{s['frames_in_view']}/{s['frames']}", rng(s["distance_m"], "{:.1f}"),
            rng(s["height_px"], "{:.0f}"), "-" if s["white_encoded_mean"] is None else f"{s['white_encoded_mean']:.2f}",
            band, pct(s["rel_error_mean"]), pct(s["rel_error_max"])]


HEADER = ["plate", "text", "frames in view", "distance (m)", "height (px)", "white after init (mean)",
          "in band after init", "MC error (mean)", "MC error (max)"]


def plates_html(report: dict) -> str:
    """report.html's table of the plates (empty without `metrics.plates`)."""
    summary = (report.get("metrics") or {}).get("plates")
    if not summary:
        return ""
    rows = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in _cells(k, s)) + "</tr>"
                   for k, s in summary["per_plate"].items())
    lo, hi = summary["band"]
    return ("<h2>Plates in view</h2><table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in HEADER) + "</tr>"
            + rows + f"</table><p class=\"note\">band {lo:g}-{hi:g} of full scale; "
            + html.escape(summary["definition"]) + "</p>")


def plates_markdown(report: dict) -> str:
    """The same table in markdown."""
    summary = (report.get("metrics") or {}).get("plates")
    if not summary:
        return ""
    lo, hi = summary["band"]
    lines = [f"# Plates in view: {report.get('scene', '')}", "",
             "| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    lines += ["| " + " | ".join(_cells(k, s)) + " |" for k, s in summary["per_plate"].items()]
    lines += ["", f"Band {lo:g}-{hi:g} of full scale. {summary['definition']}.", ""]
    return "\n".join(lines)


def write_plates_markdown(out_dir: Path, report: dict) -> Path | None:
    """`plates.md` beside report.json when the run recorded plates; returns its path (None: none)."""
    text = plates_markdown(report)
    if not text:
        return None
    from poevp_optics.core.io import atomic_path

    path = Path(out_dir) / "plates.md"
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return path
