"""`poevp evaluate`'s tables: read rates per cell with Wilson 95 % intervals (both readings), the
findings the benchmark exists for, and the paper's Tables 2 and 4 beside ours.

A cell is (motion kind, speed px/frame, E, method); its frames are every scored frame of every
sequence in it. Files: evaluation.md (tables and findings), evaluation.csv (one row per cell),
frames.csv (one row per read), report.json (cells, findings, configuration, paper tables).
"""

from __future__ import annotations

import csv
import json
import dataclasses
import io as _io
from collections import defaultdict
from pathlib import Path

import numpy as np

from poevp_optics.analysis.statistics import lag_frames, wilson_interval
from poevp_optics.core.io import atomic_path, write_json
from poevp_optics.core.paths import REPO_ROOT
from poevp_optics.core.report import counted

CAUSAL = ("hold", "flow", "dmvfn", "dmvfn_lite", "track", "track_net")
#: Paper Table 2 (accuracy %, ms per frame); E-averaged, its own data and an RTX 3090.
PAPER = {"fusion_classic": (65.07, 135.261), "fusion_deghost": (88.56, 424.831),
         "deep_optics": (21.64, 1161.458), "poevp": (94.86, 16.928)}
#: Paper Table 4 (its prototype, real scenes): frames, LDR acc %, HDR acc %, LDR/HDR entropy, ms.
PAPER_TABLE4 = {"JingN F9H28": (28, 0.0, 92.86, 1.2018, 6.9323, 16.807),
                "JingL J7629": (39, 0.0, 97.44, 1.2038, 7.2774, 14.317),
                "average": (None, 0.0, 95.15, 1.2028, 7.1049, 15.562)}


def _pct(k: int, n: int) -> dict:
    lo, hi = wilson_interval(k, n)
    return {"read": k, "pct": 100.0 * k / n if n else float("nan"), "ci95": [100.0 * lo, 100.0 * hi]}


def summarise(rows: list[dict]) -> dict:
    """{'kind|speed|E|method': cell} with frames, ALPR and recognition-only read rates (Wilson
    95 %), mean plate entropy (bits), median method ms and the measured image speed."""
    groups = defaultdict(list)
    for r in rows:
        groups[(r["kind"], float(r["speed_px"]), float(r["E"]), r["method"])].append(r)
    cells = {}
    for (kind, v, e, m), sel in groups.items():
        n = len(sel)
        cells[f"{kind}|{v:g}|{e:g}|{m}"] = {
            "kind": kind, "speed_px": v, "E": e, "method": m, "frames": n,
            "alpr": _pct(sum(bool(r["alpr_ok"]) for r in sel), n),
            "recognition_only": _pct(sum(bool(r["rec_ok"]) for r in sel), n),
            "entropy_bits": float(np.mean([r["entropy"] for r in sel])),
            "method_ms": float(np.median([r["method_ms"] for r in sel])),
            "measured_px_per_frame": float(np.median([r["measured_px_per_frame"] for r in sel]))}
    return cells


def lags(rows: list[dict]) -> dict:
    """Reversal lag per method: frames after the turn until the plate reads again (ALPR), per
    sequence, and how many sequences never read again."""
    seqs = defaultdict(dict)
    for r in rows:
        if r["kind"] == "reversal":
            seqs[(r["method"], r["text"], float(r["speed_px"]), float(r["E"]), int(r["change"]))][int(r["frame"])] = bool(r["alpr_ok"])
    out = defaultdict(lambda: {"lags": [], "never": 0})
    for (m, _text, _v, _e, change), reads in seqs.items():
        series = [reads.get(t, False) for t in range(max(reads) + 1)]
        lag = lag_frames(series, change)
        if lag is None:
            out[m]["never"] += 1
        else:
            out[m]["lags"].append(lag)
    return {m: {**d, "mean_lag_frames": float(np.mean(d["lags"])) if d["lags"] else None} for m, d in out.items()}


def _cell(cells, kind, v, e, m):
    return cells.get(f"{kind}|{float(v):g}|{float(e):g}|{m}")


def findings(cells: dict, cfg) -> dict:
    """The benchmark's questions: the separating speed per E (hold < 50 % while flow or dmvfn
    > 80 %, ALPR), oracle >= every causal predictor within its interval, LDR <= 10 % at E >= 9."""
    sep = {}
    for e in cfg.e_levels:
        sep[f"{e:g}"] = None
        for v in sorted(cfg.speeds_px):
            hold = _cell(cells, "lateral", v, e, "hold")
            best = [c for c in (_cell(cells, "lateral", v, e, p) for p in ("flow", "dmvfn", "dmvfn_lite", "track", "track_net")) if c]
            if hold and best and hold["alpr"]["pct"] < 50 and max(c["alpr"]["pct"] for c in best) > 80:
                sep[f"{e:g}"] = v
                break
    violations = []
    for c in cells.values():
        if c["method"] in CAUSAL:
            o = _cell(cells, c["kind"], c["speed_px"], c["E"], "oracle")
            if o and o["alpr"]["ci95"][1] < c["alpr"]["ci95"][0]:       # the intervals do not overlap
                violations.append(f"{c['kind']} {c['speed_px']:g} px E={c['E']:g}: oracle "
                                  f"{o['alpr']['pct']:.0f} % < {c['method']} {c['alpr']['pct']:.0f} %")
    ldr = defaultdict(list)
    for c in cells.values():
        if c["method"] == "ldr":
            ldr[f"{c['E']:g}"].append((c["alpr"]["pct"], c["kind"], c["speed_px"]))
    return {"separating_speed_px": sep, "oracle_violations": violations,
            "ldr_max_pct_by_E": {e: max(v) for e, v in sorted(ldr.items(), key=lambda kv: float(kv[0]))}}


def _fmt(c) -> str:
    if c is None:
        return "-"
    a, r = c["alpr"], c["recognition_only"]
    return f"{a['pct']:.0f} [{a['ci95'][0]:.0f}-{a['ci95'][1]:.0f}] / {r['pct']:.0f}"


def _table(header, rows) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header),
            *("| " + " | ".join(r) + " |" for r in rows)]


def markdown_tables(cells: dict, lag: dict, cfg) -> list[str]:
    """The speed, E and motion tables (each cell: ALPR % [Wilson 95 %] / recognition-only %)."""
    out = []
    for e in cfg.e_levels:
        out += [f"\n### Lateral motion, E = {e:g}: accuracy vs plate speed (px/frame)\n"]
        out += _table(["method", *(f"{v:g}" for v in cfg.speeds_px)],
                      [[m, *(_fmt(_cell(cells, "lateral", v, e, m)) for v in cfg.speeds_px)] for m in cfg.methods])
    out += [f"\n### Lateral motion at {cfg.e_speed_px:g} px/frame: accuracy vs over-exposure E\n"]
    out += _table(["method", *(f"E={e:g}" for e in cfg.e_sweep)],
                  [[m, *(_fmt(_cell(cells, "lateral", cfg.e_speed_px, e, m)) for e in cfg.e_sweep)] for m in cfg.methods])
    out += [f"\n### Motion kinds at {cfg.motion_speed_px:g} px/frame, E = {cfg.motion_e:g} "
            "(last column: reversal lag, mean frames after the turn until the plate reads again)\n"]
    rows = []
    for m in cfg.methods:
        lg = lag.get(m)
        lag_s = "-" if not lg else (f"{lg['mean_lag_frames']:.1f}" if lg["mean_lag_frames"] is not None else "never") + (
            f" ({lg['never']} never)" if lg and lg["never"] and lg["mean_lag_frames"] is not None else "")
        rows.append([m, *(_fmt(_cell(cells, k, cfg.motion_speed_px, cfg.motion_e, m)) for k in cfg.kinds), lag_s])
    out += _table(["method", *cfg.kinds, "reversal lag"], rows)
    return out


def paper_tables(cells: dict, cfg) -> list[str]:
    """Paper Table 2 and Table 4 beside ours (ours: lateral cells at the paper's E = 9, 29, 49
    where run, pooled)."""
    def pooled(m):
        sel = [c for c in cells.values() if c["method"] == m and c["kind"] == "lateral" and c["E"] in (9, 29, 49)]
        k, n = sum(c["alpr"]["read"] for c in sel), sum(c["frames"] for c in sel)
        if not n:
            return "-", "-"
        p = _pct(k, n)
        return f"{p['pct']:.1f} [{p['ci95'][0]:.0f}-{p['ci95'][1]:.0f}] (n={n})", f"{np.median([c['method_ms'] for c in sel]):.1f}"

    rows = [("Exposure fusion (classical)", "fusion_classic", PAPER["fusion_classic"]),
            ("Exposure fusion (artifact reduced)", "fusion_deghost", PAPER["fusion_deghost"]),
            ("Deep optics", None, PAPER["deep_optics"]),
            *((f"POE-VP ({p})", p, PAPER["poevp"] if p == "dmvfn" else None) for p in cfg.predictors)]
    if "dmvfn" not in cfg.predictors:
        rows.append(("POE-VP (paper: DMVFN)", "", PAPER["poevp"]))
    t2 = []
    for name, ours, paper in rows:
        acc, ms = pooled(ours) if ours else (("out of scope" if ours is None else "not run"), "-")
        t2.append([name, f"{paper[0]:.2f}" if paper else "-", f"{paper[1]:.1f}" if paper else "-", acc, ms])
    out = ["\n### Paper Table 2 (its simulation, E = 9/29/49 averaged, RTX 3090) beside ours "
           "(lateral cells at E = 9, 29, 49, ALPR, pooled; ms on this CPU)\n"]
    out += _table(["method", "paper acc %", "paper ms", "ours acc % [95 %]", "ours ms"], t2)
    out += ["\n### Paper Table 4 (its DMD prototype, two real plates)\n"]
    out += _table(["plate", "frames", "LDR acc %", "HDR acc %", "LDR entropy", "HDR entropy", "ms"],
                  [[k, str(v[0] or "-"), *(f"{x:g}" for x in v[1:])] for k, v in PAPER_TABLE4.items()])
    return out


def write_tables(out: Path, rows: list[dict], cfg, seconds: float, extra_text: str = "") -> dict:
    """Write evaluation.md/.csv, frames.csv and report.json; return the report dict."""
    cells = summarise(rows)
    lag = lags(rows)
    find = findings(cells, cfg)
    _write_csv(out / "frames.csv", rows)
    flat = [{"kind": c["kind"], "speed_px": c["speed_px"], "E": c["E"], "method": c["method"], "frames": c["frames"],
             "alpr_read": c["alpr"]["read"], "alpr_pct": round(c["alpr"]["pct"], 2),
             "alpr_ci95_lo": round(c["alpr"]["ci95"][0], 2), "alpr_ci95_hi": round(c["alpr"]["ci95"][1], 2),
             "rec_read": c["recognition_only"]["read"], "rec_pct": round(c["recognition_only"]["pct"], 2),
             "rec_ci95_lo": round(c["recognition_only"]["ci95"][0], 2),
             "rec_ci95_hi": round(c["recognition_only"]["ci95"][1], 2),
             "entropy_bits": round(c["entropy_bits"], 3), "method_ms": round(c["method_ms"], 2),
             "measured_px_per_frame": c["measured_px_per_frame"]} for c in cells.values()]
    _write_csv(out / "evaluation.csv", flat)
    zero = zero_read_reason(rows)
    text = "\n".join([f"# Plate recognition over speed, over-exposure and motion: LDR vs fusion vs POE-VP\n",
                      *([f"**{zero}**\n"] if zero else []), _intro(cfg, rows, seconds, _scene_law(cfg)), *markdown_tables(cells, lag, cfg), "\n## Findings\n",
                      _findings_text(find, cfg), extra_text, *paper_tables(cells, cfg)]) + "\n"
    with atomic_path(out / "evaluation.md") as tmp:
        Path(tmp).write_text(text)
    report = {"cells": cells, "reversal_lag": lag, "findings": find, "seconds": seconds, "zero_reads": zero,
              "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in dataclasses.asdict(cfg).items()}}
    write_json(out / "report.json", report)
    return report


#: A plate box counts as clipped when at least this share of it reads 255, as dark when its 90th
#: percentile is below DARK_P90 of 255 (a quarter of full scale: glyph contrast of a few codes).
CLIPPED_SHARE, DARK_P90 = 0.25, 64.0
#: Eq. 2's readings that cannot dim a prediction clipped at 255 below saturation (control/masks.py).
UNCLIPPABLE_LAWS = ("threshold_ratio", "threshold_exp")
#: The methods that are not POE-VP: the LDR twin and the two exposure fusions (evaluate.py runs them).
BASELINES = ("ldr", "fusion_classic", "fusion_deghost")


def zero_read_reason(rows: list[dict], law: str = "") -> str | None:
    """None when a POE-VP frame reads (full ALPR); else one paragraph saying why no method (or no
    POE-VP method, the oracle included) reads: the plate clipped or dark in most frames of each
    (medians over its frames), or the plate legible but not found by the detector, or what the
    OCR read instead."""
    poevp = [r for r in rows if r["method"] not in BASELINES]
    if any(r["alpr_ok"] for r in rows):
        if not poevp or any(r["alpr_ok"] for r in poevp):
            return None
        rows, who = poevp, "Every POE-VP method"
    else:
        who = "Every method"
    if not rows:
        return None
    by: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        by[r["method"]].append(r)
    clipped = {m: float(np.median([r.get("plate_clipped", 0.0) for r in v])) for m, v in by.items()}
    p90 = {m: float(np.median([r.get("plate_p90", 255.0) for r in v])) for m, v in by.items()}
    shown = ", ".join(f"{m} {100 * clipped[m]:.0f} %" for m in by)
    head = f"{who} reads 0 % ({len(rows)} reads of {', '.join(by)}): "
    if all(c >= CLIPPED_SHARE for c in clipped.values()):
        why = (f"the plate stays clipped in every method (median share of its box at 255: {shown}), so "
               "no character survives")
        if law in UNCLIPPABLE_LAWS:
            why += (f"; the mask law `{law}` cannot dim a prediction clipped at 255 below saturation "
                    "(control/masks.py), so even the oracle stays clipped: `--paper-law threshold_linear` is "
                    "Eq. 2's reading that reproduces the paper, `exposure_controller` the camera's own law")
        return head + why + "."
    if all(v < DARK_P90 for v in p90.values()):
        levels = ", ".join(f"{m} {p90[m]:.0f}" for m in by)
        return (head + f"the plate is dark in every method (median 90th percentile of its box: {levels} of "
                "255): its glyphs differ by a few codes, below what the detector finds.")
    rec = sum(r["rec_ok"] for r in rows)
    if rec:
        return (head + f"recognition on the plate box reads {rec} of {len(rows)} frames, so the plate is "
                "legible, but the detector finds no text over it (full ALPR searches the whole frame).")
    clip_m = [m for m in by if clipped[m] >= CLIPPED_SHARE]
    dark_m = [m for m in by if m not in clip_m and p90[m] < DARK_P90]
    rest = [m for m in by if m not in clip_m and m not in dark_m]
    parts = []
    if clip_m:
        parts.append("the plate stays clipped in " + ", ".join(f"{m} ({100 * clipped[m]:.0f} % of its box at 255)"
                                                               for m in clip_m))
    if dark_m:
        parts.append("dark in " + ", ".join(f"{m} (90th percentile {p90[m]:.0f} of 255)" for m in dark_m))
    if not rest:                       # each method either clipped or dark
        return head + "; ".join(parts) + "."
    r = next((r for r in rows if r["method"] in rest and (r.get("alpr_text") or r.get("rec_text"))),
             next(r for r in rows if r["method"] in rest))
    parts.append(f"{'in ' + ', '.join(rest) if clip_m or dark_m else 'in every method'} it is neither clipped "
                 f"nor dark, and the OCR reads other text: e.g. {r['method']} frame {r['frame']} "
                 f"'{r.get('alpr_text', '')}' (ALPR) / '{r.get('rec_text', '')}' (plate box) for '{r['text']}'")
    return head + "; ".join(parts) + "."


def _write_csv(path: Path, rows: list[dict]) -> None:
    buf = _io.StringIO()
    if rows:
        w = csv.DictWriter(buf, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    with atomic_path(path) as tmp:
        Path(tmp).write_text(buf.getvalue())


def _scene_law(cfg) -> str:
    """The scene's mask law and relay PSF, for the header."""
    from poevp_optics.scene.load import load_scene

    spec = load_scene(cfg.scene, list(getattr(cfg, "overrides", ())))
    return f"{spec.mask.law}`, relay `{spec.relay.psf}"


def _e_text(cfg) -> str:
    """How E sets the plate's peak (apps/evaluate/evaluate.py peak_gain)."""
    from poevp_optics.apps.evaluate.eval_sequences import peak_gain

    reading = getattr(cfg, "e_reading", "display")
    if reading == "linear":
        return "E read in linear radiance: the plate's peak is (E + 1) x the LDR saturation level. "
    return ("E read as the paper's Eq. 3 does, on 8-bit display values (Sec. 4.A, 'pixel values ... beyond "
            "255'): the plate's peak code value is 255 (E + 1), decoded by extended sRGB, so its linear "
            f"radiance is {peak_gain(9):.0f}x / {peak_gain(49):.0f}x the LDR saturation level at E = 9 / 49. ")


def _intro(cfg, rows, seconds, law: str = "") -> str:
    n_seq = len({(r["text"], r["kind"], r["speed_px"]) for r in rows})
    return (_e_text(cfg) + (f"Mask law `{law}` (the scene's). " if law else "") + f"{'Quick' if cfg.quick else 'Default'} set: scene `{scene_name(cfg.scene)}`, {counted(len(cfg.texts), 'text')} "
            f"({', '.join(cfg.texts)}), {counted(n_seq, 'rendered sequence')} at {cfg.resolution[0]}x{cfg.resolution[1]}, "
            f"{cfg.spp} spp, 2 ms exposure; loop mode `{cfg.loop_mode}`; frames < 2 (the loop's white start) "
            f"not scored. Each cell: **full ALPR % [Wilson 95 %] / recognition-only %** (PP-OCRv4 detection + "
            f"recognition on the {'whole frame' if cfg.search == 'frame' else 'vehicle window'}; recognition "
            f"alone on the plate box); a frame counts when every character matches (paper Eq. 4). "
            f"{len(rows)} reads, {seconds:.0f} s."
            + (f" Scene keys set for every run: {', '.join(f'`{o}`' for o in cfg.overrides)}."
               if getattr(cfg, "overrides", ()) else ""))


def _findings_text(find: dict, cfg) -> str:
    lines = []
    for e, v in find["separating_speed_px"].items():
        lines.append(f"- E = {e}: " + (f"from {v:g} px/frame, hold reads < 50 % while flow or dmvfn read > 80 % (ALPR)."
                                       if v is not None else "no speed in the sweep where hold reads < 50 % "
                                       "while flow or dmvfn read > 80 % (ALPR)."))
    v = find["oracle_violations"]
    lines.append("- Oracle >= every causal predictor within the 95 % intervals (no cell where the oracle's "
                 "interval lies wholly below a causal predictor's)." if not v else
                 "- Oracle below a causal predictor, intervals disjoint, in: " + "; ".join(v) + ".")
    for e, (pct, kind, speed) in find["ldr_max_pct_by_E"].items():
        lines.append(f"- LDR at E = {e}: at most {pct:.0f} % in any cell (worst: {kind} {speed:g} px/frame).")
    return "\n".join(lines) + "\n"


#: The physically rendered benchmark whose pooled rows sit beside the paper protocol's: the report
#: of `poevp evaluate`'s default run (its default output folder).
RENDERED_REPORT = REPO_ROOT / "out" / "evaluate" / "report.json"


def pooled_alpr(cells: dict, method: str, kind: str, e_levels=(9, 29, 49)) -> dict | None:
    """ALPR reads pooled over a method's cells of one motion kind at the given E (Wilson 95 %)."""
    sel = [c for c in cells.values() if c["method"] == method and c["kind"] == kind and c["E"] in e_levels]
    n = sum(c["frames"] for c in sel)
    if not n:
        return None
    return {**_pct(sum(c["alpr"]["read"] for c in sel), n), "frames": n,
            "method_ms": float(np.median([c["method_ms"] for c in sel]))}


def _pooled_fmt(p: dict | None) -> str:
    return "-" if p is None else f"{p['pct']:.1f} [{p['ci95'][0]:.0f}-{p['ci95'][1]:.0f}] (n={p['frames']})"


def paper_protocol_findings(cells: dict, e_levels) -> dict:
    """Per E: LDR's and the oracle's ALPR reads, and whether LDR <= oracle (reads)."""
    out = {}
    for e in e_levels:
        ldr, orc = _cell(cells, "paper", 0, e, "ldr"), _cell(cells, "paper", 0, e, "oracle")
        if ldr and orc:
            out[f"{e:g}"] = {"ldr_pct": ldr["alpr"]["pct"], "oracle_pct": orc["alpr"]["pct"],
                             "ldr_le_oracle": ldr["alpr"]["read"] <= orc["alpr"]["read"]}
    return out


def _paper_protocol_md(cells: dict, cfg, e_levels, rendered: dict) -> list[str]:
    out = ["\n### The paper's protocol: accuracy per E (ALPR % [Wilson 95 %] / recognition-only %)\n"]
    out += _table(["method", *(f"E={e:g}" for e in e_levels), "pooled ALPR % [95 %]"],
                  [[m, *(_fmt(_cell(cells, "paper", 0, e, m)) for e in e_levels),
                    _pooled_fmt(pooled_alpr(cells, m, "paper", e_levels))] for m in cfg.methods])
    names = {"fusion_classic": "Exposure fusion (classical)", "fusion_deghost": "Exposure fusion (artifact reduced)"}
    rows = [["LDR", "-", "-", "-", _pooled_fmt(pooled_alpr(cells, "ldr", "paper", e_levels)),
             _pooled_fmt(pooled_alpr(rendered, "ldr", "lateral"))]]
    for m in (*cfg.baselines, "deep_optics", *cfg.predictors):
        if m == "ldr":
            continue
        paper = PAPER.get(m) or (PAPER["poevp"] if m == "dmvfn" else None)
        if m == "deep_optics":
            rows.append(["Deep optics", f"{paper[0]:.2f}", f"{paper[1]:.1f}", "-", "out of scope", "out of scope"])
            continue
        mine = pooled_alpr(cells, m, "paper", e_levels)
        rows.append([names.get(m, f"POE-VP ({m})"), f"{paper[0]:.2f}" if paper else "-",
                     f"{paper[1]:.1f}" if paper else "-", f"{mine['method_ms']:.1f}" if mine else "-",
                     _pooled_fmt(mine), _pooled_fmt(pooled_alpr(rendered, m, "lateral"))])
    if "dmvfn" not in cfg.predictors:
        rows.append(["POE-VP (paper: DMVFN)", f"{PAPER['poevp'][0]:.2f}", f"{PAPER['poevp'][1]:.1f}", "-",
                     "not run", _pooled_fmt(pooled_alpr(rendered, "dmvfn", "lateral"))])
    out += ["\n### Paper Table 2 beside ours: the paper's protocol here, and the physically rendered "
            "benchmark (`poevp evaluate`'s default run, lateral cells at E = 9, 29, 49 pooled; "
            + ("present" if rendered else "absent: run `poevp evaluate` first") + ")\n"]
    out += _table(["method", "paper acc %", "paper ms", "ours ms", "paper protocol acc % [95 %]",
                   "physically rendered acc % [95 %]"], rows)
    return out


def scene_name(scene) -> str:
    """The scene's folder name (a path to its scene.toml gives the folder's)."""
    p = Path(scene)
    return p.parent.name if p.suffix == ".toml" else p.name


def law_text(law: str) -> str:
    """The paper protocol's mask law, labelled paper or ours, with Eq. 2's floor for the paper's."""
    from poevp_optics.apps.evaluate.eval_paper import PAPER_A, PAPER_LAWS, PAPER_VS

    if law not in PAPER_LAWS:
        return (f"mask law `{law}` (ours, not the paper's Eq. 2: the same frames, highlight and loop, the "
                "project's law in place of Eq. 2)")
    floor = PAPER_A * PAPER_VS / 255.0
    extra = ""
    if law == "threshold_ratio":
        ink = ", ".join(f"{255.0 / (floor * (e + 1.0)):.0f}" for e in (9, 29, 49))
        extra = (f"; on a prediction clipped at 255 it dims by at most a Vs / 255 = {floor:.2f}, so a pixel of "
                 f"stored value O stays clipped where 0.71 O (E G + 1) > 255: at the highlight's centre "
                 f"any O above {ink} at E = 9, 29, 49 (plate ink is ~45 here)")
    if law == "threshold_linear":
        keep = 255.0 / (1.0 - PAPER_A)
        extra = (f"; it dims every pixel above Vs tenfold (transmission 1 - a = {1.0 - PAPER_A:.1f}), so a pixel "
                 f"stays clipped only where O (E G + 1) > {keep:.0f}")
    return f"mask law Eq. 2 (`{law}` reading) with (Vs, a, b) = (200, 0.9, 0){extra}"


def camera_text(cfg) -> str:
    """Which camera formed the paper protocol's images (evaluate --camera)."""
    if getattr(cfg, "camera", "physical") == "paper":
        extra = f", plus {', '.join(cfg.paper_effects)}" if cfg.paper_effects else ""
        return ("the paper's own simulation (apps/evaluate/paper_camera.py: code values, noiseless per-pixel Hadamard "
                f"product, cut off at 255, no smoothing, no DMD floor{extra})")
    keys = getattr(cfg, "overrides", ())
    extra = f", scene keys set: {', '.join(f'`{o}`' for o in keys)}" if keys else ""
    return f"this project's DMD and sensor (noise, ADC) in place of the paper's noiseless cut-off at 255{extra}"


def write_paper_tables(out: Path, rows: list[dict], cfg, seconds: float) -> dict:
    """evaluation.md/.csv, frames.csv and report.json of the paper protocol (apps/evaluate/eval_paper.py)."""
    e_levels = sorted({float(r["E"]) for r in rows})
    cells = summarise(rows)
    rendered = {}
    if RENDERED_REPORT.is_file():
        rendered = json.loads(RENDERED_REPORT.read_text()).get("cells", {})
    find = {"separating_speed_px": {}, "paper_protocol": paper_protocol_findings(cells, e_levels)}
    _write_csv(out / "frames.csv", rows)
    _write_csv(out / "evaluation.csv", [{"E": c["E"], "method": c["method"], "frames": c["frames"],
                                         "alpr_read": c["alpr"]["read"], "alpr_pct": round(c["alpr"]["pct"], 2),
                                         "alpr_ci95_lo": round(c["alpr"]["ci95"][0], 2),
                                         "alpr_ci95_hi": round(c["alpr"]["ci95"][1], 2),
                                         "rec_read": c["recognition_only"]["read"],
                                         "entropy_bits": round(c["entropy_bits"], 3),
                                         "method_ms": round(c["method_ms"], 2),
                                         "measured_px_per_frame": c["measured_px_per_frame"]} for c in cells.values()])
    texts = sorted({r["text"] for r in rows})
    lines = [f"- E = {e}: LDR {v['ldr_pct']:.0f} %, oracle {v['oracle_pct']:.0f} % (ALPR)"
             + ("" if v["ldr_le_oracle"] else " - LDR above the oracle") for e, v in find["paper_protocol"].items()]
    zero = zero_read_reason(rows, cfg.paper_law)
    text = "\n".join([
        "# Plate recognition, the paper's simulation protocol (Sec. 6): LDR vs fusion vs POE-VP\n",
        *([f"**{zero}**\n"] if zero else []),
        f"Scene `{scene_name(cfg.scene)}` (`[source] kind = \"ldr_highlight\"`): its LDR frames with Eq. 3's "
        f"highlight H = O (E G + 1) formed on the stored 8-bit values as the paper does (Sec. 4.A), then "
        f"sRGB-decoded, E = 9, 29, 49, R = 50 px at 720x1280; {law_text(cfg.paper_law)}; loop `open` (paper Fig. 3); "
        f"plate text and boxes from the source's CSV ({', '.join(texts)}; the plate moves "
        f"{np.median([r['measured_px_per_frame'] for r in rows]):g} px/frame); frames < 2 (the loop's "
        f"white start) not scored; {camera_text(cfg)}. {len(rows)} reads, {seconds:.0f} s. Cells: full ALPR (PP-OCRv4 "
        "detection + recognition on the whole frame) "
        "[Wilson 95 %] / recognition only (plate box).",
        *_paper_protocol_md(cells, cfg, e_levels, rendered), "\n## Findings\n", "\n".join(lines) + "\n"]) + "\n"
    with atomic_path(out / "evaluation.md") as tmp:
        Path(tmp).write_text(text)
    report = {"protocol": "paper", "cells": cells, "findings": find, "seconds": seconds, "zero_reads": zero,
              "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in dataclasses.asdict(cfg).items()}}
    write_json(out / "report.json", report)
    return report
