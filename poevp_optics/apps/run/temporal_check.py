"""The temporal term of the error budget: the encoded capture's time-quadrature error, estimated
on one frame by rendering its nodes and their midpoints (analysis/error_budget.py composes the
budget; this module renders, so it lives with the apps)."""

from __future__ import annotations

import math
import time

import numpy as np

from poevp_optics.analysis.metrics import crop
from poevp_optics.camera.dmd import node_time_weights_s, throughput_on, transmission_table
from poevp_optics.core.seeds import render_seeds


def _plane_coefficients(camera, mask, frame_index: int, nodes_rel: np.ndarray) -> np.ndarray:
    """Per-pixel effective exposure of each radiance node (s): (H, W, K) for the mask's levels
    (mirror grid; white without a DMD)."""
    if camera.dmd is None or mask is None:
        thr = throughput_on(camera.dmd_spec) if camera.dmd is not None else 1.0
        w = node_time_weights_s(camera.timing.exposure_s, nodes_rel) * thr
        return np.broadcast_to(w, (*camera.mirror_shape, len(w)))
    lv = np.rint(mask).astype(np.int64)
    uniq, inv = np.unique(lv, return_inverse=True)
    table = transmission_table(uniq, camera.dmd_spec, camera.schedule(frame_index), nodes_rel)
    return table[inv.reshape(lv.shape)]


def temporal_error(spec, renderer, camera, ex=None, mask=None) -> dict:
    """Step-halving estimate of the time-quadrature error of the encoded capture on one frame.

    The capture of a mirror at level v is sum_j W_j(v) L_j over the frame's radiance nodes
    (dmd.py: exact PWM on-time against the piecewise-linear L(t)). The same sum over the nodes
    plus every interval's midpoint is the better rule; for an error of order 2 in the node
    spacing, E ~ (4/3) (P_nodes - P_refined). Both rules are rendered here for this one frame with
    common random numbers (one seed for every time, per MC split), so their difference is the
    quadrature's and not Monte Carlo noise; the residual noise of the difference (its spread over
    the splits) is subtracted in quadrature. Evaluated with the frame's actual mask (`rel`) and
    the white one (`rel_ldr`), over the ROI (or the frame): RMS over pixels relative to the mean.
    Rendered plates are not smooth in time (texture edges crossing pixels put kinks in L(t)):
    benchmarks/subframes_error.md measures this estimate against 256-sample references.
    Cost: 2 N - 1 renders at the scene's spp for one frame of N nodes.
    """
    k = spec.render.subframes
    if spec.geometry_static or ex is None or k < 2:
        why = ("static scene: one radiance sample is exact" if spec.is_static else
               "PWM lamps on static geometry: exact integration" if spec.geometry_static else
               f"K = {k}: one radiance sample per exposure, no rule to refine (raise render.subframes)"
               if k < 2 else "no frame to estimate it on")
        return {"rel": 0.0 if spec.geometry_static else None, "method": why, "seconds": 0.0}
    t_start = time.perf_counter()
    a, _ = spec.exposure_window_s(ex.index)
    fine_t = np.asarray(ex.subframe_times_s, dtype=np.float64)
    refined_t = np.sort(np.concatenate([fine_t, 0.5 * (fine_t[1:] + fine_t[:-1])]))
    fine_at = {float(t): j for j, t in enumerate(fine_t)}
    acc = spec.accuracy
    n = acc.mc_splits
    spp = spec.render.temporal_spp or acc.spp
    sizes = [spp // n + (1 if i < spp % n else 0) for i in range(n)]
    seeds = render_seeds(spec.render.seed, ex.index, 7000, n)
    planes = {}
    for key, m in (("rel", mask), ("rel_ldr", None)):
        cf = _plane_coefficients(camera, m, ex.index, fine_t - a)
        cr = _plane_coefficients(camera, m, ex.index, refined_t - a)
        planes[key] = (cf, cr, [0.0] * n, [0.0] * n)       # fine and refined plane per split
    for i, t in enumerate(refined_t):
        renderer.set_time(float(t))
        for sp in range(n):
            img = crop(renderer.render_once(seeds[sp], sizes[sp]).astype(np.float64), ex.roi)
            for cf, cr, pf, pr in planes.values():
                j = fine_at.get(float(t))
                if j is not None:
                    pf[sp] = pf[sp] + crop(cf[..., j], ex.roi) * img
                pr[sp] = pr[sp] + crop(cr[..., i], ex.roi) * img
    out = {"frame": ex.index, "nodes": len(fine_t), "nodes_refined": len(refined_t), "order": 2,
           "where": "ROI" if ex.roi else "frame"}
    w = np.asarray(sizes, dtype=np.float64) / spp
    for key, (_, _, pf, pr) in planes.items():
        d = [f - r for f, r in zip(pf, pr)]
        mean_d = sum(wi * di for wi, di in zip(w, d))
        var_d = sum(wi * (di - mean_d) ** 2 for wi, di in zip(w, d)) / (n - 1)   # of the mean
        scale = float(np.mean(sum(wi * f for wi, f in zip(w, pf))))
        per_px = (mean_d ** 2 - var_d).ravel()
        excess = float(np.mean(per_px))
        spread = float(np.std(per_px) / math.sqrt(per_px.size))     # standard error of `excess`
        tag = "" if key == "rel" else "_ldr"
        resolved = excess > 2.0 * spread
        if scale > 0:
            point = (4.0 / 3.0) * math.sqrt(max(excess, 0.0)) / scale
            upper = (4.0 / 3.0) * math.sqrt(max(excess, 0.0) + 2.0 * spread) / scale
            # the budget's value: the estimate when resolved, else its upper bound
            out.update({key: point if resolved else upper, f"rel_point{tag}": point, f"rel_upper{tag}": upper})
        else:
            out.update({key: None, f"rel_point{tag}": None, f"rel_upper{tag}": None})
        out["resolved" + tag] = bool(resolved)
    out.update({"spp": spp,
                "method": f"step halving on the encoded plane sum_j W_j(v) L_j with the frame's mask: "
                          f"{len(fine_t)} nodes vs {len(refined_t)} (midpoints added), common random "
                          f"numbers at {spp} spp, (4/3) x the difference (order 2), MC noise removed; "
                          "rel_upper: with 2 standard errors of the noise subtraction"
                          + ("" if out["resolved"] else "; not resolved above the MC noise: rel is the "
                             "upper bound rel_upper (raise render.temporal_spp to resolve it)"),
                "seconds": time.perf_counter() - t_start, "renders": len(refined_t) * n})
    return out
