"""Temporal quadrature error of the encoded capture against K, per mask level, before and after.

The encoded pixel of a mirror at level v is int m_v(t) L(t) dt over the exposure. Three rules:

* midpoint: K samples at the midpoints of K equal sub-intervals, each weighted by the
  exact on-time of the level in its sub-interval: first order in 1/K when a level's few short
  bit-planes sit off a sub-interval's centre.
* uniform: K nodes including the exposure's ends, each weighted by the exact integral of m_v
  against its hat function (the piecewise-linear interpolant of L: dmd.on_time_table).
* uniform + PWM: the same nodes joined by the DMD's switching times (render.pwm_nodes, the
  default): a level lit by its low bits integrates L(t) over ~1 ms, which uniform nodes resolve
  only for K >> 30.

Part A: a smooth synthetic highlight moving across the frame (Gaussian, noise-free): the
asymptotic order of each rule per level. Part B: rendered plates (`highbeam_plate` frame 8, the
plate closing at 6 m/s; `fast_pass` frame 1, a plate sweeping the frame within one exposure) at
184x320, 256 radiance samples rendered with ONE seed (common random numbers: differences between
rules are nearly free of Monte Carlo noise), L(t) at any time by linear interpolation between
them; the reference is the uniform rule on those 256 samples (one bit-plane LSB step apart).
Errors: relative RMS over the plate box. Part C: the run's own estimate (apps.run.temporal_check.temporal_error:
independent seeds at the scene's spp, the frame's oracle mask) against the true error.

    .venv/bin/python -m benchmarks.subframes_error [--results]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from benchmarks.common import add_results_flag, machine_line, markdown_table, output_folder, save_figure, save_text

LEVELS = (1, 14, 128, 255)
N_DENSE = 256
KS = (3, 5, 9, 17, 33, 65)           # uniform nodes (intervals 2 ... 64); before: K - 1 sub-intervals
CACHE = Path(os.environ.get("POEVP_CACHE_DIR", Path.home() / ".cache" / "poevp_optics")) / "bench"


def _rel_err(a, b, box=None):
    if box is not None:
        y0, x0, y1, x1 = box
        a, b = a[..., y0:y1, x0:x1], b[..., y0:y1, x0:x1]
    return np.sqrt(np.mean((a - b) ** 2, axis=(-2, -1))) / np.mean(b, axis=(-2, -1))


def _slope(ks, errs):
    ks, errs = np.asarray(ks, float), np.asarray(errs, float)
    sel = (ks >= 8) & (errs > 1e-12)
    return float(np.polyfit(np.log(ks[sel]), np.log(errs[sel]), 1)[0]) if sel.sum() >= 2 else float("nan")


class Rules:
    """The three quadratures of int m_v L dt for a schedule, given L(t) as a function of time
    relative to the exposure start (returns (H, W) arrays)."""

    def __init__(self, sched, levels):
        from poevp_optics.camera.dmd import switch_times_s

        self.sched, self.levels = sched, np.asarray(levels)
        self.T = sched.exposure_s
        self.switch = switch_times_s(sched) - sched.exposure_start_s

    def nodes(self, k, pwm):
        from poevp_optics.camera.dmd import node_times_s

        return node_times_s(0.0, self.T, k, self.switch if pwm else ())

    def plane(self, L, nodes, levels=None):
        from poevp_optics.camera.dmd import on_time_table

        w = on_time_table(self.levels if levels is None else levels, self.sched, nodes)
        return np.einsum("vk,khw->vhw", w, np.stack([L(t) for t in nodes]))

    def before(self, L, k):
        from poevp_optics.camera.dmd import interval_on_time_table

        w = interval_on_time_table(self.levels, self.sched, k)
        mids = (np.arange(k) + 0.5) * self.T / k
        return np.einsum("vk,khw->vhw", w, np.stack([L(t) for t in mids]))


def part_a():
    """Smooth synthetic highlight: order of each rule per level (noise-free)."""
    from poevp_optics.camera.dmd import Schedule
    from poevp_optics.camera.dmd import DMDSpec
    from poevp_optics.core.timing import TimingSpec
    h, w = 24, 96
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)

    def L(t):                       # 1500 px/s: 45 px in a 30 ms exposure, sigma 4 px
        return 1.0 + 300.0 * np.exp(-((x - 25 - 1500.0 * t) ** 2 + (y - h / 2) ** 2) / (2 * 4.0 ** 2))

    sched = Schedule.for_frame(DMDSpec(), TimingSpec(fps=30.0, exposure_s=0.03, dmd_window_s=0.03), 0.0)
    rules = Rules(sched, LEVELS)
    ref = rules.plane(L, rules.nodes(2049, False))
    rows = []
    for name, fn in (("before", lambda k: rules.before(L, k - 1)), ("uniform", lambda k: rules.plane(L, rules.nodes(k, False))),
                     ("uniform + PWM", lambda k: rules.plane(L, rules.nodes(k, True)))):
        errs = np.array([_rel_err(fn(k), ref) for k in KS])
        for j, v in enumerate(LEVELS):
            rows.append([name, v, *[float(e) for e in errs[:, j]], _slope(np.array(KS) - 1, errs[:, j])])
    return rows


def _dense(name, frame, res, spp):
    """256 common-random-number renders of one exposure (cached) and the plate box."""
    from poevp_optics.camera.camera import Camera
    from poevp_optics.camera.dmd import node_times_s
    from poevp_optics.render.renderer import Renderer
    from poevp_optics.scene.load import load_scene
    spec = load_scene(f"scenes/{name}", [f"render.resolution={list(res)}", f"timing.frames={frame + 1}"])
    path = CACHE / f"dense_{name}_{frame}_{res[0]}x{res[1]}_{spp}.npz"
    if path.is_file():
        z = np.load(path)
        return spec, z["imgs"].astype(np.float64), z["times"], tuple(int(v) for v in z["box"])
    cam = Camera.from_params(spec.resolved.camera)
    r = Renderer(spec.resolved.render, guard_px=cam.guard_px)
    t0, t1 = spec.exposure_window_s(frame)
    times = node_times_s(t0, t1, N_DENSE)
    imgs, box = [], None
    for t in times:
        r.set_time(float(t))
        imgs.append(r.render_once(12345, spp))
        b = r.roi_box()
        box = b if box is None else (min(box[0], b[0]), min(box[1], b[1]), max(box[2], b[2]), max(box[3], b[3]))
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, imgs=np.stack(imgs), times=times, box=np.array(box))
    return spec, np.stack(imgs).astype(np.float64), times, box


def part_b(name, frame, res, spp):
    from poevp_optics.camera.camera import Camera
    from poevp_optics.control.loop_step import oracle_mask

    spec, imgs, times, box = _dense(name, frame, res, spp)
    rel = times - times[0]

    def L(t):
        j = min(int(np.searchsorted(rel, t, side="right")) - 1, len(rel) - 2)
        a = (t - rel[j]) / (rel[j + 1] - rel[j])
        return (1 - a) * imgs[j] + a * imgs[j + 1]

    cam = Camera.from_params(spec.resolved.camera)
    rules = Rules(cam.schedule(frame), LEVELS)
    ref = rules.plane(lambda t: L(t), rel)
    rows, curves = [], {}
    for rname, fn in (("before", lambda k: rules.before(L, k - 1)), ("uniform", lambda k: rules.plane(L, rules.nodes(k, False))),
                      ("uniform + PWM", lambda k: rules.plane(L, rules.nodes(k, True)))):
        errs = np.array([_rel_err(fn(k), ref, box) for k in KS])
        for j, v in enumerate(LEVELS):
            curves[(rname, v)] = errs[:, j]
            rows.append([name, rname, v, *[float(e) for e in errs[:, j]], _slope(np.array(KS) - 1, errs[:, j])])
    # the encoded plate with the frame's oracle mask, at the scene's K
    w_t = np.gradient(rel)
    truth = np.einsum("k,khw->hw", w_t / w_t.sum(), imgs)
    mask = oracle_mask(cam, spec.resolved.loop.mask, truth, frame)
    lv = np.rint(mask).astype(int)
    uq, inv = np.unique(lv, return_inverse=True)
    inv = inv.reshape(lv.shape)
    rules_m = Rules(cam.schedule(frame), uq)

    def encoded(nodes):
        from poevp_optics.camera.dmd import on_time_table

        wt = on_time_table(uq, cam.schedule(frame), nodes)[inv]
        return np.einsum("hwk,khw->hw", wt, np.stack([L(t) for t in nodes]))

    e_ref = encoded(rel)
    k = spec.render.subframes
    enc = {"K": k, "uniform": float(_rel_err(encoded(rules_m.nodes(k, False)), e_ref, box)),
           "uniform + PWM": float(_rel_err(encoded(rules_m.nodes(k, True)), e_ref, box)),
           "nodes": len(rules_m.nodes(k, True))}
    enc["plate_levels"] = f"{int(lv[box[0]:box[2], box[1]:box[3]].min())}-{int(lv[box[0]:box[2], box[1]:box[3]].max())}"
    return spec, rows, curves, enc, (L, rel, box, mask)


def part_c(spec, frame, dense, spps=(128, 512)):
    """The run's own estimate (independent seeds, this frame's oracle mask, temporal_spp 64)
    against the true error of the encoded plate. The truth: the rule on the run's nodes against
    one-bit-plane-step samples of the window in which the plate's mask levels are lit, rendered
    with common random numbers at two spp (a, b); what is left of the CRN noise in the
    difference falls as 1/spp, so true^2 = (b e_b^2 - a e_a^2) / (b - a)."""
    import dataclasses

    from poevp_optics.camera.camera import Camera
    from poevp_optics.camera.dmd import node_times_s, on_time_table
    from poevp_optics.apps.run.temporal_check import temporal_error
    from poevp_optics.render.exposures import render_exposures
    from poevp_optics.render.renderer import Renderer

    _, _, box, mask = dense
    spec = dataclasses.replace(spec, render=dataclasses.replace(spec.render, temporal_spp=64))
    cam = Camera.from_params(spec.resolved.camera)
    r = Renderer(spec.resolved.render, guard_px=cam.guard_px)
    ex = list(render_exposures(spec.resolved.render, r, progress=False))[frame]
    est = temporal_error(spec, r, cam, ex, mask)
    sched = cam.schedule(frame)
    t0 = spec.exposure_window_s(frame)[0]
    y0, x0, y1, x1 = box
    lv = np.rint(mask).astype(int)
    used = np.unique(lv[y0:y1, x0:x1])
    ends = [b1 for b, _, b1 in sched.plane_intervals() if np.any((used >> b) & 1)]
    lit_end = (max(ends) - sched.exposure_start_s) if ends and not sched.outside_on else sched.exposure_s
    fine = np.asarray(ex.subframe_times_s) - t0
    fine = fine[fine <= lit_end + 1e-12]
    dense_t = node_times_s(0.0, sched.exposure_s, N_DENSE)
    dense_t = dense_t[dense_t <= lit_end + 1e-12]
    uq, inv = np.unique(lv, return_inverse=True)
    inv = inv.reshape(lv.shape)

    def encoded(nodes, images):
        # int over [0, lit_end]: the hat rule restricted to the lit window (both rules share it)
        from poevp_optics.camera.dmd import Schedule

        sub = dataclasses.replace(sched, exposure_s=float(nodes[-1]))
        wt = on_time_table(uq, sub, nodes)[inv]
        return np.einsum("hwk,khw->hw", wt, np.stack([images[round(float(t) / lit_end * 1e9)] for t in nodes]))

    errs = {}
    lo, hi = spps
    for spp in spps:
        imgs = {}
        for t in np.unique(np.concatenate([dense_t, fine])):
            r.set_time(float(t0 + t))
            imgs[round(float(t) / lit_end * 1e9)] = r.render_once(4242, spp).astype(np.float64)
        a, b = encoded(fine, imgs), encoded(dense_t, imgs)
        errs[spp] = float(_rel_err(a, b, box))
    true2 = (hi * errs[hi] ** 2 - lo * errs[lo] ** 2) / (hi - lo)
    true = float(np.sqrt(max(true2, 0.0)))
    # the rest of the exposure (leakage only for these levels) is integrated alike by both rules
    return {"scene": spec.name, "nodes": len(ex.subframe_times_s), "estimate": est["rel"],
            "resolved": est["resolved"], "true": true, "true_lo": errs[lo], "true_hi": errs[hi], "spps": spps,
            "ratio": est["rel"] / true if est["rel"] and true else None, "spp": est["spp"],
            "estimate_seconds": est["seconds"]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_results_flag(ap)
    dest = output_folder(ap.parse_args(argv).results)
    header_k = [f"{k - 1} int." for k in KS]
    rows_a = part_a()
    text = (f"# Encoded temporal error vs K, per mask level: midpoint samples and trapezoid nodes\n\n"
            f"Machine: {machine_line()}. Columns: number of intervals (before: K - 1 sub-intervals with "
            f"midpoint samples; uniform: K nodes; uniform + PWM: the same K nodes plus the DMD's "
            f"switching times). Slope of log error vs log intervals, from 8 intervals on.\n\n"
            f"## A. Smooth synthetic highlight (noise-free, 45 px per exposure)\n\n"
            + markdown_table(["rule", "level", *header_k, "slope"], rows_a) + "\n\n")
    cases = [("highbeam_plate", 8, (184, 320), 32, (128, 512)), ("fast_pass", 1, (184, 320), 32, (32, 128))]
    # part B's references use 32 spp: the plate's CRN noise floor is ~3e-3 there (part C)
    all_rows, encs, checks, all_curves = [], [], [], {}
    for name, frame, res, spp, spps in cases:
        spec, rows, curves, enc, dense = part_b(name, frame, res, spp)
        all_rows += rows
        encs.append([name, enc["K"], enc["nodes"], enc["plate_levels"], enc["uniform"], enc["uniform + PWM"]])
        all_curves[name] = curves
        checks.append(part_c(spec, frame, dense, spps))
        print(checks[-1])
    text += ("## B. Rendered plates (184x320, 256 common-random-number samples as reference)\n\n"
             + markdown_table(["scene", "rule", "level", *header_k, "slope"], all_rows)
             + "\n\nEncoded plate with the frame's oracle mask at the scene's K:\n\n"
             + markdown_table(["scene", "K uniform", "nodes with PWM", "plate mask levels", "uniform",
                               "uniform + PWM"], encs)
             + "\n\n## C. The run's temporal-error estimate vs the true error (oracle mask, scene K, PWM nodes)\n\n"
             + "Estimate: apps.run.temporal_check.temporal_error at render.temporal_spp = 64. True: the same nodes against "
               "samples one LSB bit-plane apart over the window in which the plate's levels are lit, "
               "common random numbers at two spp, the CRN noise (~1/spp) extrapolated out.\n\n"
             + markdown_table(["scene", "nodes", "spp", "estimate", "resolved", "true",
                               "CRN error at the two spp", "estimate / true", "seconds"],
                              [[c["scene"], c["nodes"], c["spp"], c["estimate"], c["resolved"], c["true"],
                                f"{c['true_lo']:.4g} @ {c['spps'][0]} / {c['true_hi']:.4g} @ {c['spps'][1]}",
                                c["ratio"], c["estimate_seconds"]] for c in checks])
             + "\n\nRendered L(t) is not smooth: a texture edge crossing a box-filtered pixel puts kinks in "
               "L(t), so the asymptotic order on a real plate lies between 1 and 2 (part B), while on a "
               "smooth L(t) every level converges at order 2 with hat weights and the midpoint rule's "
               "low levels only at order 1 (part A). What decides the plate's error at practical K is "
               "whether the nodes resolve the window in which the plate's mask level is lit: the PWM "
               "nodes do that for every level at the cost of the DMD's B - 1 inner switching times.\n")
    save_text(dest / "subframes_error.md", text)
    print(text)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(cases), figsize=(6 * len(cases), 4.2))
    for ax, (name, *_rest) in zip(axes, cases):  # noqa: B007
        for (rname, v), errs in all_curves[name].items():
            style = {"before": "x--", "uniform": "o:", "uniform + PWM": "s-"}[rname]
            ax.loglog(np.array(KS) - 1, errs, style, c=f"C{LEVELS.index(v)}", label=f"{rname}, level {v}", ms=3)
        ax.set(xlabel="intervals", ylabel="relative RMS error, plate", title=name)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6, ncol=2)
    print("wrote", save_figure(fig, dest / "subframes_error.png"))


if __name__ == "__main__":
    main()
