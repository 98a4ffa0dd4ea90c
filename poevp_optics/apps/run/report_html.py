"""`report.html`: the run report a person looks at, written beside `report.json`.

One self-contained file (no network: inline CSS and JavaScript, images as base64 PNG data
URIs): a frame player (slider, play button) of scene / LDR twin / mask / encoded capture /
reconstruction side by side, the plate box (the run's ROI) zoomed (nearest neighbour) with its
known text and any OCR read the run recorded (a render run reads none: `poevp evaluate` runs the ALPR)
or, where the run recorded every plate in view (`render.roi_shape = "plates"`, apps/run/plates.py),
each plate's box zoomed from the encoded capture with its text, white (encoded, LDR twin), band
and MC error in that frame, per-frame
plots (saturated fraction, the plate's band) as inline SVG, the error budget, the timing
budget, the notes and the run's figures (timeline, DR curves, night-road band plot).

Sizes: every panel at most MAX_PANEL_W px wide (INTER_AREA downscale), at most MAX_FRAMES
frames in the player (an even stride through the run, first and last kept), figures at most
MAX_FIGURE_W px wide. `report.html#frame=K` opens at the K-th shown frame. Everything it shows is read from the run's files and report.json.
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

import cv2
import numpy as np

MAX_PANEL_W = 640
MAX_FIGURE_W = 1280
MAX_FRAMES = 48
PLATE_ZOOM_W = 320

#: (label, folder of a render run's frames, the chart run's single file)
COLUMNS = (("scene (tone-mapped)", "preview", None), ("LDR twin", "ldr", "ldr.png"),
           ("mask", "mask", "mask.png"), ("encoded capture", "capture", "encoded.png"),
           ("reconstruction (tone-mapped)", "preview_reconstruction", None))
#: captions of the figures a run may write (others are shown under their file name)
FIGURES = {"timeline_plot.png": "timeline: exposure, DMD window, compute and transfer per frame",
           "night_road.png": "night road: plate peak over saturation vs distance",
           "chart_curves.png": "DR chart: SNR and response per patch",
           "chart_images.png": "DR chart: scene, LDR, mask, encoded"}
MARKER = "poevp-report-ready"


def _to_u8(img: np.ndarray, max_code: int) -> np.ndarray:
    """An image as uint8 grey or RGB: 8-bit kept, deeper codes scaled by 255 / max_code."""
    a = np.asarray(img)
    if a.dtype == np.uint8:
        return a
    return np.clip(np.rint(a.astype(np.float64) * 255.0 / max(1, max_code)), 0, 255).astype(np.uint8)


def _fit(img: np.ndarray, max_w: int) -> np.ndarray:
    h, w = img.shape[:2]
    if w <= max_w:
        return img
    return cv2.resize(img, (max_w, max(1, round(h * max_w / w))), interpolation=cv2.INTER_AREA)


def png_data_uri(img: np.ndarray) -> str:
    """A uint8 grey or RGB image as a data:image/png;base64 URI."""
    a = img[..., ::-1] if img.ndim == 3 else img                  # OpenCV encodes BGR
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(a))
    if not ok:
        raise ValueError("could not encode a PNG")
    return "data:image/png;base64," + base64.b64encode(buf.tobytes()).decode("ascii")


def _read(path: Path, max_code: int) -> np.ndarray | None:
    """A frame file (PNG, or the DN EXR of a > 16-bit capture) as uint8, None if absent."""
    if path.with_suffix(".png").is_file():
        img = cv2.imread(str(path.with_suffix(".png")), cv2.IMREAD_UNCHANGED)
        if img is not None and img.ndim == 3:
            img = img[..., ::-1]
        return None if img is None else _to_u8(img, max_code)
    if path.with_suffix(".exr").is_file():
        from poevp_optics.core.io import read_exr

        chans, _ = read_exr(path.with_suffix(".exr"))
        return _to_u8(chans["DN"], max_code) if "DN" in chans else None
    return None


def shown_frames(n: int, most: int = MAX_FRAMES) -> list[int]:
    """Indices of the frames the player shows: all up to `most`, else an even stride with the
    first and the last."""
    if n <= most:
        return list(range(n))
    return sorted({int(round(k * (n - 1) / (most - 1))) for k in range(most)})


def _plate_crop(img: np.ndarray, box) -> np.ndarray | None:
    """The plate box with a quarter of its size around it, scaled up by an integer factor
    (nearest neighbour: the pixels stay visible)."""
    y0, x0, y1, x1 = (int(v) for v in box)
    my, mx = max(2, (y1 - y0) // 4), max(2, (x1 - x0) // 4)
    h, w = img.shape[:2]
    c = img[max(0, y0 - my):min(h, y1 + my), max(0, x0 - mx):min(w, x1 + mx)]
    if c.size == 0:
        return None
    k = max(1, PLATE_ZOOM_W // c.shape[1])
    return cv2.resize(c, (c.shape[1] * k, c.shape[0] * k), interpolation=cv2.INTER_NEAREST)


def _plate_numbers(p: dict, band) -> str:
    """One plate's line for a frame: text, distance, height, white (encoded capture, LDR twin;
    fractions of full scale) against the band, MC error; or that it is out of view."""
    head = f"{p.get('id', '?')} ({p.get('text') or 'no text'})"
    if not p.get("in_view") or not p.get("box"):
        return f"{head}: out of view"
    parts = []
    if isinstance(p.get("distance_m"), (int, float)):
        parts.append(f"{p['distance_m']:.1f} m")
    if isinstance(p.get("height_px"), (int, float)):
        parts.append(f"{p['height_px']:.0f} px tall")
    w = p.get("white") or {}
    if isinstance(w.get("encoded"), (int, float)):
        ldr = f", LDR twin {w['ldr']:.2f}" if isinstance(w.get("ldr"), (int, float)) else ""
        where = {True: "in band", False: "out of band"}.get(p.get("in_band"), "band not judged")
        rng = f" {band[0]:g}-{band[1]:g}" if band else ""
        parts.append(f"white {w['encoded']:.2f} of full scale{ldr} ({where}{rng})")
    rel = p.get("rel_error")
    parts.append("MC error " + (f"{rel * 100:.2f} %" if isinstance(rel, (int, float)) else "-"))
    return f"{head}: " + "; ".join(parts)


def _plate_zooms(rec: dict, capture: np.ndarray | None, band) -> list[dict]:
    """Every plate record of a frame (`plates`): {id, zoom (data URI of its box zoomed from the
    encoded capture; "" out of view), numbers (its line, `_plate_numbers`)}."""
    out = []
    for p in rec.get("plates") or []:
        zoom = ""
        if p.get("in_view") and p.get("box") and capture is not None:
            z = _plate_crop(capture, p["box"])
            zoom = png_data_uri(z) if z is not None else ""
        out.append({"id": str(p.get("id", "")), "zoom": zoom, "numbers": _plate_numbers(p, band)})
    return out


def _ocr_read(rec: dict) -> str | None:
    """The plate text an ALPR read for this frame, if the run recorded one."""
    for key in ("ocr", "alpr", "plate_read"):
        v = rec.get(key)
        if isinstance(v, dict):
            v = v.get("text")
        if isinstance(v, str):
            return v
    return None


def collect_frames(out_dir: Path, report: dict, plate_text: str = "") -> dict:
    """The player's data: column labels, per shown frame its panels (data URIs), caption and
    plate zooms."""
    max_code = (1 << int(report.get("sensor", {}).get("bits", 8))) - 1
    per_frame = report.get("per_frame") or [{}]
    folders = [c for c in COLUMNS if (out_dir / c[1]).is_dir()]
    single = not folders
    if single:                                       # a chart run: one frame of top-level files
        folders = [c for c in COLUMNS if c[2] and (out_dir / c[2]).is_file()]
    idx = shown_frames(len(per_frame)) if not single else [0]
    band = ((report.get("metrics") or {}).get("plates") or {}).get("band")
    frames = []
    for i in idx:
        rec = per_frame[i] if i < len(per_frame) else {}
        name = f"frame_{rec.get('index', i):04d}"
        panels, raw = [], {}
        for label, folder, single_file in folders:
            path = out_dir / single_file if single else out_dir / folder / name
            img = _read(path, max_code if folder in ("ldr", "capture") else 255)
            raw[folder] = img
            panels.append(png_data_uri(_fit(img, MAX_PANEL_W)) if img is not None else "")
        plate = []
        box = rec.get("roi")
        truth = rec.get("ground_truth") or {}
        text = (truth.get("text") if isinstance(truth, dict) else None) or plate_text
        if box:
            for folder in ("capture", "preview_reconstruction"):
                z = _plate_crop(raw[folder], box) if raw.get(folder) is not None else None
                if z is not None:
                    plate.append(png_data_uri(z))
        frames.append({"index": rec.get("index", i), "panels": panels, "plate": plate,
                       "plates": _plate_zooms(rec, raw.get("capture"), band),
                       "caption": _caption(rec), "text": text, "ocr": _ocr_read(rec)})
    return {"labels": [c[0] for c in folders], "frames": frames, "of": len(per_frame)}


def _caption(rec: dict) -> str:
    parts = []
    if "t_start_s" in rec:
        parts.append(f"t = {rec['t_start_s'] * 1e3:.1f} ms")
    if rec.get("init"):
        parts.append("white initialisation frame")
    sat = rec.get("saturated_fraction_roi")
    if isinstance(sat, dict):
        parts.append("ROI saturated: " + ", ".join(f"{k} {v * 100:.1f} %" for k, v in sat.items()
                                                    if isinstance(v, (int, float))))
    pw = rec.get("plate_white_fraction")
    if isinstance(pw, dict):
        parts.append("plate white: " + ", ".join(f"{k} {v:.2f}" for k, v in pw.items() if isinstance(v, (int, float)))
                     + " of full scale")
    if isinstance(rec.get("predict_seconds"), (int, float)):
        parts.append(f"predict {rec['predict_seconds'] * 1e3:.0f} ms")
    return "; ".join(parts)


def _fmt(v) -> str:
    if v is None:                       # a term without a target or time: an empty cell, not "None"
        return "-"
    if isinstance(v, bool):
        return html.escape(str(v))
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        return ", ".join(_fmt(x) for x in v)
    if isinstance(v, dict):
        return "; ".join(f"{html.escape(str(k))} {_fmt(x)}" for k, x in v.items())
    return html.escape(str(v))


def _error_budget(errors: dict) -> str:
    """The error budget as a table: each term's relative error, where, target, seconds."""
    if not errors:
        return ""
    rows = []
    for name, term in errors.items():
        if not isinstance(term, dict) or name == "total":
            continue
        rel = term.get("rel")
        rows.append(f"<tr><td>{html.escape(name)}</td><td>{'-' if rel is None else f'{rel * 100:.3g} %'}</td>"
                    f"<td>{_fmt(term.get('where', ''))}</td><td>{_fmt(term.get('target'))}</td>"
                    f"<td>{_fmt(term.get('met'))}</td><td>{_fmt(term.get('seconds'))}</td></tr>")
    total = errors.get("total") or {}
    foot = (f"<p>total {total.get('rel', 0) * 100:.3g} % ({_fmt(total.get('definition', ''))}); "
            f"dominant: {_fmt(errors.get('dominant'))}; advice: {_fmt(errors.get('advice'))}</p>"
            if total else "")
    return ("<h2>Error budget</h2><table><tr><th>term</th><th>relative error</th><th>where</th>"
            "<th>target</th><th>met</th><th>seconds</th></tr>" + "".join(rows) + "</table>" + foot)


def svg_lines(series: dict[str, list], *, band=None, y_label: str = "", width: int = 560,
              height: int = 200) -> str:
    """A small inline SVG line plot of per-frame series (None: gap) on a shared y axis from 0,
    with an optional shaded band (lo, hi)."""
    vals = [v for s in series.values() for v in s if isinstance(v, (int, float))]
    if not vals:
        return ""
    top = max(max(vals), band[1] if band else 0, 1e-12) * 1.05
    n = max(len(s) for s in series.values())
    pl, pr, pt, pb = 44, 10, 10, 28
    def x(i):
        return pl + (width - pl - pr) * (i / max(1, n - 1))
    def y(v):
        return pt + (height - pt - pb) * (1 - v / top)
    colours = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e")
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" role="img">',
           f'<rect x="{pl}" y="{pt}" width="{width - pl - pr}" height="{height - pt - pb}" fill="#fff" stroke="#999"/>']
    if band:
        out.append(f'<rect x="{pl}" y="{y(band[1]):.1f}" width="{width - pl - pr}" '
                   f'height="{y(band[0]) - y(band[1]):.1f}" fill="#2ca02c" opacity="0.15"/>')
    for frac in (0, 0.5, 1):
        out.append(f'<text x="{pl - 4}" y="{y(top * frac / 1.05) + 4:.1f}" font-size="10" text-anchor="end">'
                   f'{top * frac / 1.05:.3g}</text>')
    out.append(f'<text x="{pl}" y="{height - 6}" font-size="11">frame'
               f'{" - " + html.escape(y_label) if y_label else ""}</text>')
    for k, (name, s) in enumerate(series.items()):
        pts = " ".join(f"{x(i):.1f},{y(v):.1f}" for i, v in enumerate(s) if isinstance(v, (int, float)))
        c = colours[k % len(colours)]
        out.append(f'<polyline fill="none" stroke="{c}" stroke-width="1.5" points="{pts}"/>')
        out.append(f'<text x="{width - pr - 90 * (len(series) - k)}" y="{height - 6}" font-size="11" '
                   f'fill="{c}">{html.escape(name)}</text>')
    out.append("</svg>")
    return "".join(out)


def _plots(report: dict) -> str:
    per_frame = report.get("per_frame") or []
    parts = []
    sat = {k: [((f.get("saturated_fraction_roi") or {}).get(k)) for f in per_frame] for k in ("ldr", "encoded")}
    svg = svg_lines(sat, y_label="saturated fraction of the ROI")
    if svg:
        parts.append(f"<figure>{svg}<figcaption>saturated fraction of the ROI per frame (LDR twin, encoded "
                     f"capture)</figcaption></figure>")
    pw = (report.get("metrics") or {}).get("plate_white_after_init")
    if isinstance(pw, dict) and pw.get("band"):
        white = [f.get("plate_white_fraction") for f in per_frame]
        series = ({k: [w.get(k) if isinstance(w, dict) else None for w in white] for k in ("ldr", "encoded")}
                  if any(isinstance(w, dict) for w in white) else {"plate white": white})
        svg = svg_lines(series, band=tuple(pw["band"]), y_label="plate white, fraction of full scale")
        if svg:
            parts.append(f"<figure>{svg}<figcaption>the plate's white in the capture per frame and the "
                         f"controller's band ({_fmt(pw.get('definition', ''))}); in band after the white "
                         f"frames: {pw.get('in_band_fraction', 0) * 100:.0f} %</figcaption></figure>")
    return ("<h2>Per frame</h2>" + "".join(parts)) if parts else ""


def _figures(out_dir: Path) -> str:
    parts = []
    for p in sorted(out_dir.glob("*.png")):
        if p.name == "contact_sheet.png" or p.name in ("ldr.png", "mask.png", "encoded.png"):
            continue
        img = cv2.imread(str(p), cv2.IMREAD_COLOR)          # 8-bit BGR whatever the file holds
        if img is None:
            continue
        img = img[..., ::-1]
        parts.append(f'<figure><img class="fig" alt="{html.escape(p.name)}" src="{png_data_uri(_fit(img, MAX_FIGURE_W))}">'
                     f"<figcaption>{html.escape(FIGURES.get(p.name, p.name))}</figcaption></figure>")
    return ("<h2>Figures</h2>" + "".join(parts)) if parts else ""


def _summary(report: dict) -> str:
    rows = [("scene", report.get("scene")), ("frames", report.get("frames")),
            ("resolution", report.get("resolution")), ("seed", report.get("seed"))]
    mask, stages = report.get("mask") or {}, report.get("stages") or {}
    pred = stages.get("predict") or {}
    if mask:
        rows.append(("mask law", mask.get("law")))
    if pred:
        p = pred.get("predictor")
        rows += [("predictor", p.get("name") if isinstance(p, dict) else p), ("loop mode", pred.get("mode")),
                 ("white initialisation frames", pred.get("init_frames"))]
    if report.get("defaults_applied"):
        rows.append(("defaults applied (the scene chose none)", report["defaults_applied"]))
    tb = report.get("timing_budget") or {}
    if tb:
        rows.append(("timing budget", f"{tb.get('budget_s', 0) * 1e3:.3g} ms of a {tb.get('gap_s', 0) * 1e3:.3g} ms "
                     f"gap; late frames {len(tb.get('late_frames') or [])}; on-time up to "
                     f"{tb.get('on_time_fps', 0):.3g} fps"))
    for k in ("total_seconds",):
        if isinstance(report.get(k), (int, float)):
            rows.append(("run seconds", report[k]))
    metrics = report.get("metrics") or {}
    for k in ("saturated_fraction_roi", "entropy_roi"):
        if isinstance(metrics.get(k), dict):
            rows.append((k.replace("_", " "), metrics[k]))
    return "<table>" + "".join(f"<tr><th>{html.escape(str(k))}</th><td>{_fmt(v)}</td></tr>"
                               for k, v in rows if v is not None) + "</table>"


CSS = """body{font:14px/1.4 system-ui,sans-serif;margin:16px;color:#222;background:#fafafa}
h1{font-size:20px}h2{font-size:16px;margin-top:24px;border-bottom:1px solid #ccc}
table{border-collapse:collapse;margin:6px 0}td,th{border:1px solid #ddd;padding:3px 8px;text-align:left;vertical-align:top}
.row{display:flex;flex-wrap:wrap;gap:8px}.panel{display:flex;flex-direction:column;align-items:center}
.panel img{width:256px;image-rendering:pixelated;background:#000}.plate img{image-rendering:pixelated;max-width:320px}
.plate figure{margin:0;max-width:320px;display:flex;flex-direction:column;align-items:center}.plate figcaption{font-size:12px}
.fig{max-width:100%}#controls{margin:8px 0;display:flex;gap:10px;align-items:center}#slider{width:420px}
.note{color:#555}figure{margin:8px 0}"""

JS = """(function(){
var D=JSON.parse(document.getElementById('frames-data').textContent);
var n=D.frames.length,i=0,timer=null;
var imgs=document.querySelectorAll('#player .panel img'),pl=document.querySelectorAll('#plate img');
var s=document.getElementById('slider'),lab=document.getElementById('frame-label'),
    cap=document.getElementById('caption'),txt=document.getElementById('plate-text'),
    btn=document.getElementById('play'),pz=document.getElementById('plate-zooms');
function show(k){i=k;var f=D.frames[k];
 for(var c=0;c<imgs.length;c++){imgs[c].src=f.panels[c]||'';}
 for(var p=0;p<pl.length;p++){pl[p].src=f.plate[p]||'';pl[p].style.display=f.plate[p]?'':'none';}
 s.value=k;lab.textContent='frame '+f.index+' ('+(k+1)+' of '+n+' shown, '+D.of+' in the run)';
 cap.textContent=f.caption;
 if(pz){while(pz.firstChild){pz.removeChild(pz.firstChild);}
  for(var q=0;q<f.plates.length;q++){var P=f.plates[q],fig=document.createElement('figure'),
   im=document.createElement('img'),fc=document.createElement('figcaption');
   im.alt='plate '+P.id;if(P.zoom){im.src=P.zoom;}else{im.style.display='none';}
   fc.textContent=P.numbers;fig.appendChild(im);fig.appendChild(fc);pz.appendChild(fig);}}
 if(txt){txt.textContent=f.plate.length?('plate text (ground truth): '+(f.text||'not given')+'; OCR read: '+(f.ocr||'none recorded in this run (poevp evaluate runs the ALPR)')):'no plate box in this frame';}}
s.max=n-1;s.addEventListener('input',function(){show(parseInt(s.value,10));});
btn.addEventListener('click',function(){if(timer){clearInterval(timer);timer=null;btn.textContent='play';}
 else{timer=setInterval(function(){show((i+1)%n);},D.interval_ms);btn.textContent='pause';}});
var h=/frame=(\\d+)/.exec(location.hash);show(h?Math.min(n-1,parseInt(h[1],10)):0);var m=document.createElement('div');m.id='js-status';m.textContent='"""+MARKER+""" '+n+' frames';
document.getElementById('status').appendChild(m);})();"""


def render_html(out_dir: Path, report: dict, plate_text: str = "") -> str:
    """The page of the run in `out_dir` (its report.json as `report`; `plate_text`: the scene's
    [plate] text, shown as the ground truth where a frame has a plate box)."""
    from poevp_optics.apps.run.plates import plates_html   # every plate in view, when the run has them

    out_dir = Path(out_dir)
    data = collect_frames(out_dir, report, plate_text)
    fps = float((report.get("timing") or {}).get("fps") or 5.0)
    data["interval_ms"] = int(max(100, 1000.0 / min(fps, 10.0)))
    first = data["frames"][0] if data["frames"] else {"panels": [], "plate": []}
    panels = "".join(f'<div class="panel"><img alt="{html.escape(lab)}" src="{first["panels"][k]}">'
                     f"<span>{html.escape(lab)}</span></div>" for k, lab in enumerate(data["labels"]))
    has_plates = any(f["plates"] for f in data["frames"])
    has_plate = any(f["plate"] for f in data["frames"]) and not has_plates
    plate = ""
    if has_plates:                     # every plate in view: its own zoom and numbers per frame
        plate = ('<h2>Every plate in the frame (zoomed from the encoded capture)</h2>'
                 '<div id="plate-zooms" class="row plate"></div>')
    elif has_plate:
        plate = ('<h2>Plate (zoomed: encoded capture, reconstruction)</h2><div id="plate" class="row plate">'
                 + "".join(f'<img alt="plate {k}" src="">' for k in range(2))
                 + '</div><p id="plate-text"></p>')
    notes = "".join(f"<li>{html.escape(str(n))}</li>" for n in report.get("notes") or [])
    payload = json.dumps(data).replace("</", "<\\/")
    title = f"poevp run report: {report.get('scene', out_dir.name)}"
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<meta http-equiv="Content-Security-Policy" content="default-src 'none'; img-src data:; style-src 'unsafe-inline'; script-src 'unsafe-inline'">
<style>{CSS}</style></head><body>
<h1>{html.escape(title)}</h1><p class="note">{html.escape(str(report.get('description', '')))}</p>
{_summary(report)}
<h2>Frames</h2><div id="controls"><button id="play" type="button">play</button>
<input id="slider" type="range" min="0" max="{max(0, len(data['frames']) - 1)}" value="0"><span id="frame-label"></span></div>
<div id="player" class="row">{panels}</div><p id="caption" class="note"></p>
{plate}
{plates_html(report)}
{_plots(report)}
{_error_budget(report.get('errors') or {})}
{_figures(out_dir)}
{('<h2>Notes</h2><ul>' + notes + '</ul>') if notes else ''}
<div id="status" class="note"></div>
<script type="application/json" id="frames-data">{payload}</script>
<script>{JS}</script>
</body></html>
"""


def write_report_html(out_dir: Path, report: dict, plate_text: str = "") -> Path:
    """Write `report.html` beside report.json in `out_dir`; returns its path."""
    from poevp_optics.core.io import atomic_path

    path = Path(out_dir) / "report.html"
    with atomic_path(path) as tmp:
        Path(tmp).write_text(render_html(Path(out_dir), report, plate_text), encoding="utf-8")
    return path
