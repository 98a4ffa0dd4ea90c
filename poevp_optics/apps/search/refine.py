"""`poevp search --refine`: after the trials, a gradient step from the search's best settings by
the differentiable camera (control/differentiable_camera.py), checked by running the camera.

Where it applies. The differentiable camera models one frame of the paper's Eq. 2 law
(`mask.law = "threshold_exp"`) as a function of its coefficients (Vs, a, b) = (`mask.vs`,
`mask.a`, `mask.b`), with the smooth objective J = (w - t)^2: w the plate's mean white (mean DN
/ max DN over the plate box), t the middle of the band [`mask.band_low`, `mask.band_high`]. It is
a smooth stand-in for one search objective only, `metrics.plate_white_after_init.in_band_fraction`
maximised (the fraction of frames whose plate white lies in that band): J falls as the white
moves into the band. For any other metric, law or parameters the refinement says in one line why
it does not apply, and the search's answer stands.

What it does. The best trial's run is replayed on this machine, scene by scene, from the stored
render (`renders/` of the search; rendered again when the search stored none): the same
exposures and the same closed loop, recording the prediction the law read on every frame after
the white initialisation frames. Each such frame becomes a FrameModel (its radiance, its
prediction, the plate's box), and `refine` minimises the mean J over every frame of every scene
within the searched bounds (L-BFGS-B); a coefficient the search did not vary (or varied as a
list of choices) stays at the best trial's value. The replay is checked against the trial: its
plate whites equal the best trial's report, frame by frame, or the refinement stops there.

The model holds the predictions fixed; in the camera they move with the masks (the closed loop),
and the model's clips, threshold and mask levels are smooth (its docstring). So the refined
settings are run as one more point per scene, exactly as a trial runs (`points/<hash>/`,
replaying the stored render), and the search's own objective and constraints are read from
those runs: `refined.json` beside `best.json` holds both objectives (best trial and refined, both
from the camera), the model's J before and after, the settings and a ready `--set` line, and
`improved` (the refined runs beat the best trial and meet every constraint). When the start is
flat (no predicted value reaches Vs; the plate clipped) it holds the reason instead, and no run.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from poevp_optics.control.loop_step import LoopStep

#: The search metric the differentiable camera's objective stands in for (module docstring).
METRIC = "metrics.plate_white_after_init.in_band_fraction"
#: Scene keys of the coefficients, in control/differentiable_camera.py COEFFICIENTS order.
KEYS = ("mask.vs", "mask.a", "mask.b")
LAW = "threshold_exp"
FILE = "refined.json"


class _Taps(LoopStep):
    """The scene's loop, recording for every frame the prediction its mask law read (mirror
    grid, 8-bit scale). Its decision is LoopStep.next_mask's, step for step (the replay is
    checked against the trial's report)."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.predictions: dict[int, np.ndarray] = {}

    def next_mask(self, index, truth=None):
        import time

        from poevp_optics.control.loop_step import MASKED_MODES, MaskDecision, predicted_decision, resize_onto
        from poevp_optics.control.predictors import checked_prediction
        from poevp_optics.core.grids import OnGrid
        from poevp_optics.core.units import to_8bit

        cam = self.camera
        needs = 0 if self.model is None else self.model.needs_frames
        if index < self.loop.init_frames or len(self.history) < needs or self.needs_truth:
            d = super().next_mask(index, truth)
            if not d.init:                   # the oracle: the law read the true frame (oracle_decision)
                t = cam.mirror_grid.take(truth, "the oracle's truth").astype(np.float64)
                white_e = t * cam.electrons_per_radiance() * cam.white_exposure_s(index)
                self.predictions[index] = to_8bit(cam.noise_free_dn(white_e), cam.params.max_dn).astype(np.float64)
            return d
        t0 = time.perf_counter()
        pred, n_bad = checked_prediction(self.model, [h.on(self.predictor_grid).array for h in self.history])
        pred_s = resize_onto(OnGrid(pred, self.predictor_grid), cam.sensor_grid)
        levels, g = predicted_decision(cam, self.mask, pred_s, index, self.controller,
                                       self.loop.mode in MASKED_MODES, self.attenuator)
        seconds = time.perf_counter() - t0
        self.predictions[index] = cam.mirror_grid.take(cam.to_mirror(pred_s), "the placed prediction").astype(
            np.float64)
        return MaskDecision(levels, False, seconds, n_bad, transmission=g)


def not_applicable(q) -> str | None:
    """Why the search's question has no differentiable stand-in (one line), or None."""
    obj = q.objective
    if obj.metric != METRIC or obj.direction != "maximize":
        return (f"not differentiable: the differentiable camera stands in for --maximize {METRIC} "
                f"(the plate's white against the band), not --{obj.direction} {obj.metric}")
    cont = [p.key for p in q.params if p.key in KEYS and p.kind in ("float", "log", "int")]
    if not cont:
        return ("not differentiable: the search varies none of mask.vs, mask.a, mask.b over a range "
                "(the coefficients of the paper's Eq. 2 the differentiable camera moves)")
    return None


def replay_frames(spec, stored: Path | None):
    """The FrameModels of a run of `spec` after its white initialisation frames, and the run's
    plate white per such frame (90th percentile / 255, as its report), replaying the stored
    render in the folder `stored` when it holds a complete one, else rendering."""
    from poevp_optics.analysis.metrics import plate_white_fraction, to_8bit
    from poevp_optics.apps.run.render_run import RunResult, capture_frame
    from poevp_optics.camera.camera import Camera
    from poevp_optics.control.differentiable_camera import FrameModel
    from poevp_optics.render.radiance import open_source
    from poevp_optics.render.render_cache import Replay, verify

    camera = Camera.from_params(spec.resolved.camera)
    source = None
    if stored is not None and stored.name.endswith(f"-g{camera.guard_px}"):
        man, _ = verify(stored)
        if man is not None:
            source = Replay(stored, man, spec.resolved.render, camera.guard_px)
    source = source or open_source(spec.resolved.render, camera.guard_px)
    step = _Taps.from_params(camera, spec.resolved.loop)
    m = spec.mask
    models, whites = [], []
    for ex in source.exposures(False):
        fc = capture_frame(spec, camera, step, ex, RunResult())
        if step.model is not None:
            step.observe(ex.index, fc.ldr, fc.enc, fc.est, fc.flags)
        pred = step.predictions.get(ex.index)
        if pred is None or fc.box is None:
            continue
        whites.append(plate_white_fraction(to_8bit(fc.enc.dn, camera.params.max_dn), fc.box))
        subs = list(ex.subframes) if not spec.is_static else [ex.radiance.data]
        times = ex.subframe_times_s if not spec.is_static else None
        models.append(FrameModel(camera, subs, ex.index, pred, fc.box, (m.band_low, m.band_high),
                                 times_s=times, smooth_px=m.smooth_px, mirror_box=ex.roi))
    return models, whites


def _replayed_models(scenes, specs, best: dict, out: Path):
    """The best trial's frames as differentiable models, replayed from its stored renders:
    (models, frames per scene, None), or ([], [], why not) when a replay differs from the trial
    or has no frame to refine."""
    import json

    models, checks = [], []
    for sc, sp, folder in zip(scenes, specs, best["points"]):
        report = json.loads((out / "points" / folder / "report.json").read_text())
        key = (report.get("render_reuse") or {}).get("key")
        frames, whites = replay_frames(sp, out / "renders" / key if key else None)
        ran = (report.get("metrics", {}).get("plate_white_after_init") or {}).get("per_frame") or []
        if [float(w) for w in whites] != [float(w) for w in ran]:
            return [], [], (f"{sc.name}: the replayed run's plate whites {whites} differ from the best "
                            f"trial's {ran} (points/{folder}); nothing refined")
        if not frames:
            return [], [], (f"{sc.name}: no frame after the white initialisation frames has a plate box "
                             "and a mask from the law; nothing to refine")
        models += frames
        checks.append(len(frames))
    return models, checks, None


def refine_best(scenes, q, out: Path, best: dict, run_points, log=print) -> dict:
    """The refinement of `best` (best.json's dict) for the search `q` over `scenes`
    (search.SearchScene); run_points(tasks) runs points as the search's trials run and returns
    {folder name: result}. Writes and returns refined.json's dict (module docstring)."""
    from poevp_optics.apps.search.results import set_line
    from poevp_optics.control.differentiable_camera import FrameMean, refine
    from poevp_optics.scene.load import load_scene

    settings = dict(best["settings"])
    record = {"from_trial": best["trial"], "metric": q.objective.metric, "objective_before": best["objective"],
              "settings_before": settings}
    why = not_applicable(q)
    specs = [load_scene(sc.toml, [*sc.base, *(f"{k}={v}" for k, v in settings.items())], cross_checks=False)
             for sc in scenes]
    if why is None:
        other = [f"{sc.name}: mask.law = {sp.mask.law!r}" for sc, sp in zip(scenes, specs) if sp.mask.law != LAW]
        if other:
            why = (f"not differentiable: the differentiable camera models the paper's Eq. 2 law "
                   f"(mask.law = {LAW!r}); the best trial runs {', '.join(other)}")
    if why is not None:
        return _write(out, {**record, "refined": False, "note": why}, log)
    models, checks, why = _replayed_models(scenes, specs, best, out)
    if why is not None:
        return _write(out, {**record, "refined": False, "note": why}, log)
    params = {p.key: p for p in q.params}
    theta0 = [float(getattr(specs[0].mask, k.split(".")[1])) for k in KEYS]
    bounds = []
    for k, t in zip(KEYS, theta0):
        p = params.get(k)
        bounds.append((p.low, p.high) if p is not None and p.kind != "choice" else (t, t))
    for k, t in zip(KEYS, theta0):
        if any(float(getattr(sp.mask, k.split(".")[1])) != t for sp in specs):
            return _write(out, {**record, "refined": False,
                                "note": f"{k} differs between the scenes (a --set of one scene); the refinement "
                                        "moves one value for all"}, log)
    r = refine(FrameMean(models), theta0, bounds)
    record.update({"frames": checks, "model_before": r.value0, "model_after": r.value,
                   "model_gradient_per_bound_width": dict(zip(KEYS, r.grad0)), "iterations": r.iterations,
                   "model_definition": "mean over the frames after the white initialisation of (w - t)^2, "
                                       "w the plate's mean white / full scale, t the band's middle"})
    if r.note:
        return _write(out, {**record, "refined": False, "note": r.note}, log)
    if r.theta == r.theta0:
        return _write(out, {**record, "refined": False,
                            "note": "the model's objective does not fall from the best trial's settings within "
                                    "the bounds (a minimum there already)"}, log)
    new = dict(settings)
    for k, t, p in zip(KEYS, r.theta, r.theta0):
        if t != p:
            new[k] = params[k].literal(int(round(t)) if params[k].kind == "int" else t)
    results = run_points(new)
    values, viol, errors, folders = [], [-math.inf] * len(q.objective.constraints), [], []
    for sc, (folder, res) in zip(scenes, results):
        folders.append(folder.name)
        if "error" in res:
            errors.append(f"{sc.name}: {res['error']}")
            continue
        values.append(res["value"])
        viol = [max(v, c.violation(x)) for v, c, x in zip(viol, q.objective.constraints, res["constraints"])]
    after = float(np.mean(values)) if values and not errors else math.nan
    feasible = all(v <= 0 for v in viol)
    row = {f"param.{k}": v for k, v in new.items()}
    record.update({"refined": True, "settings": new, "set_line": set_line(row), "points": folders,
                   "objective_after": after,
                   "constraints_after": {c.text: (v if math.isfinite(v) else None)
                                         for c, v in zip(q.objective.constraints, viol)},
                   "feasible": feasible and not errors,
                   "improved": bool(feasible and not errors and math.isfinite(after)
                                    and q.objective.better(after, best["objective"])),
                   "note": "; ".join(errors)})
    return _write(out, record, log)


def _write(out: Path, record: dict, log) -> dict:
    from poevp_optics.core.io import write_json

    write_json(out / FILE, record)
    return record
