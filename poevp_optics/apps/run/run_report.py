"""The render run's `report.json`: scene, camera, per-stage seconds and errors, metrics, notes,
skipped stages and per-frame values (README, "A short tour of the outputs")."""

from __future__ import annotations

import time

import numpy as np

from poevp_optics import __version__
from poevp_optics.analysis.error_budget import POISSON_BOUND, budget, physics_noise
from poevp_optics.camera.dmd import attenuation_floor
from poevp_optics.core.units import PHOTON_RADIANCE_UNIT


def mean_of(vals):
    """Mean of the values that are not None (None when there are none)."""
    vals = [v for v in vals if v is not None]
    return float(np.mean(vals)) if vals else None


def render_targets(spec, per_frame) -> dict:
    """The MC term's target: render.target_rel_error, frames that met it, spp used."""
    acc = spec.accuracy
    spp = [s for f in per_frame for s in f.get("spp", [])]
    met = [f.get("target_met") for f in per_frame if f.get("target_met") is not None]
    out = {"target": acc.target_rel_error or None,
           "met": (all(met) if met else None) if acc.target_rel_error > 0 else None,
           "spp_used": {"min": min(spp), "max": max(spp), "mean": float(np.mean(spp))} if spp else None}
    if acc.target_rel_error > 0:
        out["frames_met"] = sum(bool(m) for m in met)
        out["max_spp"] = acc.max_spp
        if not all(met):
            out["note"] = (f"{len(met) - sum(bool(m) for m in met)} frame(s) stopped at render.max_spp = "
                           f"{acc.max_spp} above the target {acc.target_rel_error:g}")
    return out


def error_budget(spec, camera, per_frame, stage_s, temporal, render_s) -> dict:
    """The numerical error budget of the run (analysis/error_budget.py): each term with the
    target it was held to (`target`, None: no target) and whether it `met` it."""
    roi = mean_of([f["rel_error_roi"] for f in per_frame])
    frame = mean_of([f["rel_error"] for f in per_frame])
    unclipped = mean_of([f.get("rel_error_unclipped") for f in per_frame])
    psf = camera.psf
    trunc = psf.truncation_error if psf is not None else 0.0
    auto = psf is not None and spec.accuracy.psf_support_px == 0
    psf_target = 1.0 - spec.accuracy.psf_support_energy if auto else None
    return budget({
        "render_mc": {"rel": roi if roi is not None else frame, "rel_frame": frame, "rel_frame_unclipped": unclipped,
                      "where": "ROI" if roi is not None else "frame", "seconds": render_s,
                      **render_targets(spec, per_frame)},
        "temporal": {"target": None, **temporal},
        "psf_truncation": {"rel": trunc, "target": psf_target,
                           "met": (trunc <= psf_target * (1 + 1e-9)) if psf_target is not None else None,
                           "support_px": int(psf.kernel.shape[0]) if psf is not None else 1,
                           **({"note": psf.note} if psf is not None and psf.note else {}),
                           "seconds": stage_s["relay"]},
        "poisson_sampler": {"rel": POISSON_BOUND, "target": None, "method": "exact (Knuth < 10 e-, PTRS >= 10 e-); "
                            "float32 counts exact to 2^24 e-", "seconds": stage_s["sensor"]},
    })


def skipped_stages(spec, camera, causal: bool) -> dict:
    """What this run left out, and why (DESIGN.md: a run leaves out what its scene does not need)."""
    skipped = {}
    if spec.is_static:
        n = spec.timing.frames
        skipped["render_repeat"] = ("static scene: rendered once" + (f" and reused for all {n} frames" if n > 1 else "")
                                    + "; sub-frames not needed")
    elif spec.geometry_static:
        skipped["render_repeat"] = (f"static geometry with PWM lamps ({', '.join(spec.flicker)}): "
                                    f"{1 + len(spec.flicker)} emitter-group images rendered once")
        skipped["subframes"] = ("PWM lamps on static geometry: the camera integrates each lamp's "
                                "drive against the DMD's bit-planes exactly; render.subframes unused")
    if camera.psf is None:
        skipped["relay"] = "psf = 'delta': no convolution"
    sw = camera.sensor.switches
    if not (sw.shot or sw.read):
        skipped["sensor_noise"] = (f"sensor.noise = false: no random numbers drawn "
                                   f"({camera.sensor.random_draws} draws)")
    if camera.dmd is None:
        skipped["dmd"] = "dmd.enabled = false: plain LDR camera"
        skipped["predict"] = "no DMD: no mask to predict"
    else:
        if not causal:
            skipped["predict"] = "predictor 'oracle' uses the rendered ground truth: no predictor runs"
        if camera.taps is None:
            skipped["registration"] = "identity mirror-to-sensor map: no resampling"
        if not spec.attenuator.enabled:
            skipped["attenuator"] = "attenuator.kind = 'none': the mask alone sets each mirror's exposure"
    return skipped


def attenuator_section(spec, per_frame) -> dict:
    """The global attenuator's settings over the run (camera/attenuator.py)."""
    a = spec.attenuator
    recs = [f["attenuator"] for f in per_frame if f.get("attenuator")]
    g = [r["transmission"] for r in recs]
    return {"kind": a.kind, "min_transmission": a.min_transmission, "settle_s": a.settle_s,
            "serve_min_mirrors": a.serve_min_mirrors,
            "transmission_min": min(g) if g else None, "transmission_max": max(g) if g else None,
            "dimmed_frames": [f["index"] for f in per_frame if f.get("attenuator", {}).get("transmission", 1.0) < 1.0],
            "late_frames": [f["index"] for f in per_frame if f.get("attenuator", {}).get("late")],
            "definition": "transmission per frame in per_frame[i].attenuator; a late command keeps the previous one"}


def run_metrics(spec, camera, per_frame, law_cmp, causal: bool) -> dict:
    """Frame averages; after-init averages; the causal predictor against the oracle."""
    keys2 = ("ldr", "encoded")
    metrics = {
        "saturated_fraction_roi": {k: mean_of([f["saturated_fraction_roi"][k] for f in per_frame]) for k in keys2},
        "entropy_roi": {k: mean_of([f["entropy_roi"][k] for f in per_frame]) for k in keys2},
        "saturated_fraction": {k: mean_of([f["saturated_fraction"][k] for f in per_frame]) for k in keys2},
        "recon_rel_error": mean_of([f["recon_rel_error"] for f in per_frame]),
        "recon_rel_error_roi": mean_of([f["recon_rel_error_roi"] for f in per_frame]),
        "valid_fraction": mean_of([f["valid_fraction"] for f in per_frame]),
    }
    loop_frames = [f for f in per_frame if not f.get("init")]
    if camera.dmd is not None:
        # the first loop.init_frames frames are white for every predictor, the oracle included:
        # averages after them compare predictors on the frames where a mask acts
        for key in ("saturated_fraction_roi", "entropy_roi"):
            metrics[key]["ldr_after_init"] = mean_of([f[key]["ldr"] for f in loop_frames])
            metrics[key]["encoded_after_init"] = mean_of([f[key]["encoded"] for f in loop_frames])
            if not causal:
                metrics[key]["oracle_after_init"] = metrics[key]["encoded_after_init"]
        metrics["init_frames"] = len(per_frame) - len(loop_frames)
    whites = [f["plate_white_fraction"]["encoded"] for f in loop_frames if f.get("plate_white_fraction")]
    if camera.dmd is not None and whites:
        lo, hi = spec.mask.band_low, spec.mask.band_high
        metrics["plate_white_after_init"] = {
            "in_band_fraction": float(np.mean([lo <= w <= hi for w in whites])), "band": [lo, hi],
            "per_frame": whites, "definition": "90th percentile of the plate box in the 8-bit capture / 255"}
    if causal:
        for key in ("saturated_fraction_roi", "entropy_roi"):
            metrics[key]["oracle"] = mean_of([f[key]["oracle"] for f in per_frame])
            metrics[key]["oracle_after_init"] = mean_of([f[key]["oracle"] for f in loop_frames])
        metrics["mask_error"] = {"iou": mean_of([f["mask_error"]["iou"] for f in loop_frames]),
                                 "mean_abs": mean_of([f["mask_error"]["mean_abs"] for f in loop_frames])}
        # lag artifact: saturated plate fraction in the first two loop frames in which the LDR
        # twin's plate is saturated (the highlight "arrives" and the mask must catch it)
        lit = [f for f in loop_frames if f["saturated_fraction_roi"]["ldr"] > 0.1][:2]
        metrics["lag_artifact"] = mean_of([f["saturated_fraction_roi"]["encoded"] for f in lit])
    if any(f.get("plates") for f in per_frame):      # render.roi_shape = "plates" (apps/run/plates.py)
        from poevp_optics.apps.run.plates import plate_summary

        metrics["plates"] = plate_summary(spec, per_frame)
    if camera.dmd and any(v["saturated"] for k, v in law_cmp.items() if k != "scene_law"):
        metrics["mask_law_comparison"] = {
            (f"scene:{spec.mask.law}" if k == "scene_law" else k):
                {"saturated_fraction_roi": mean_of(v["saturated"]), "entropy_roi": mean_of(v["entropy"])}
            for k, v in law_cmp.items()}
    return metrics


def run_notes(spec, renderer, camera, step, per_frame, metrics, floor) -> list[str]:
    """Report notes: the spectra's coverage, the DMD's attenuation floor, fallbacks, PSF caps."""
    notes = list(renderer.plan.notes)
    if camera.dmd is not None and per_frame and all(f.get("init") for f in per_frame):
        n = len(per_frame)
        what = ("the 1 frame is a white initialisation frame" if n == 1 else
                f"all {n} frames are white initialisation frames")
        notes.append(f"{what} (loop.init_frames = {spec.loop.init_frames}): no predictor ran and every mask is "
                     "white; this run shows the LDR camera only")
    if floor is not None and floor["white_fill_fraction"] > 0.01:
        ldr_sat = metrics["saturated_fraction_roi"]["ldr"]
        enc_sat = metrics["saturated_fraction_roi"]["encoded"]
        notes.append(
            f"DMD timing imposes an attenuation floor: outside the {spec.timing.dmd_window_s * 1e3:.2f} ms "
            f"display window the mirrors are {spec.timing.outside_window} for "
            f"{floor['white_fill_fraction']:.0%} of the {spec.timing.exposure_s * 1e3:.2f} ms exposure, "
            f"so no mask can pass less than {floor['floor']:.1%} of the light ({floor['floor_db']:.1f} dB "
            f"of suppression at most). Plate pixels brighter than 1/{floor['floor']:.2f} = "
            f"{1 / floor['floor']:.2f}x full well stay saturated: saturated plate fraction "
            f"{ldr_sat:.1%} (LDR) -> {enc_sat:.1%} (encoded).")
    fell_back = [f["index"] for f in per_frame if f.get("prediction_fallback_pixels")]
    if fell_back:
        n = sum(f["prediction_fallback_pixels"] for f in per_frame if f.get("prediction_fallback_pixels"))
        notes.append(f"predictor {step.model.name!r} gave NaN/Inf on frames {fell_back} ({n} pixels): those "
                     "pixels held the last frame (the 'hold' prediction); per_frame "
                     "'prediction_fallback_pixels' counts them")
    if camera.psf is not None and camera.psf.note:
        notes.append(f"relay PSF: {camera.psf.note}")
    return notes


def camera_sections(spec, camera, floor) -> dict:
    """The report's description of the camera: timing, accuracy, sensor, optics, DMD, mask."""
    p, t = camera.params, spec.timing
    objective = camera.objective_summary()
    return {
        **({"objective": objective} if objective is not None else {}),
        "timing": {"fps": t.fps, "exposure_s": t.exposure_s, "exposure_offset_s": t.exposure_offset_s,
                   "dmd_window_s": t.dmd_window_s, "dmd_window_offset_s": t.dmd_window_offset_s,
                   "outside_window": t.outside_window},
        "accuracy": {"spp": spec.render.spp, "subframes": 1 if spec.geometry_static else spec.render.subframes,
                     "mc_splits": spec.render.mc_splits, "sampler": spec.render.sampler,
                     "light_selection": spec.render.light_selection,
                     "target_rel_error": spec.render.target_rel_error or None, "max_spp": spec.render.max_spp,
                     **({"roi_spp": spec.render.roi_spp} if spec.render.roi_spp else {})},
        "sensor": {"preset": p.name, "bits": p.bits, "full_well_e": p.full_well_e,
                   "read_noise_e": p.read_noise_e, "gain_dn_per_e": p.gain_dn_per_e,
                   "offset_dn": p.offset_dn, "f_number": p.f_number,
                   "pixel_pitch_m": p.pixel_pitch_m, "etendue_m2_sr": camera.etendue_m2_sr,
                   "noise": camera.sensor.switches.__dict__},
        "optics": {**camera.layout.as_dict(), "guard_px": camera.guard_px,
                   "mirror_grid": list(camera.mirror_shape), "sensor_grid": list(camera.shape),
                   "guard_definition": "mirrors rendered beyond each edge of the sensor's footprint so "
                                       "the relay PSF sees the light beyond the field; cropped before "
                                       "the sensor, never in metrics"},
        "dmd": ({"bits": spec.dmd.bits, "bit_order": spec.dmd.bit_order,
                 "contrast_ratio": spec.dmd.contrast_ratio,
                 "throughput_on": spec.dmd.fill_factor * spec.dmd.reflectance,
                 "attenuation_floor": floor} if camera.dmd else None),
        "mask": ({"law": spec.mask.law, "vs": spec.mask.vs, "a": spec.mask.a, "b": spec.mask.b,
                  "target": spec.mask.target, "smooth_px": spec.mask.smooth_px,
                  "predictor": spec.predictor.name, **_controller_keys(spec.resolved.loop.mask)} if camera.dmd else None),
    }


def _controller_keys(mask) -> dict:
    """The exposure controller's settings (first_guess as used: scaled with the beams when
    mask.prior_beam_cd is set); {} for the other laws."""
    if mask.law != "exposure_controller":
        return {}
    return {"first_guess": mask.first_guess, "prior_beam_cd": mask.prior_beam_cd or None,
            "clip_step": mask.clip_step, "band": [mask.band_low, mask.band_high], "carry": mask.carry}


def stage_sections(spec, renderer, step, res, setup_s: float, causal: bool) -> dict:
    """Per-stage seconds (render, dmd, relay, sensor, reconstruct, mask, predict)."""
    stats, per_frame, predict_s = renderer.stats, res.per_frame, res.predict_seconds
    stages = {
        "render": {
            "seconds": stats.seconds + setup_s, "mitsuba_seconds": stats.seconds,
            "setup_seconds": setup_s, "calls": stats.calls,
            # the loop's wait for frames rendered one ahead on a thread of their own (render/ahead.py:
            # the Mitsuba seconds overlap the camera's stages); None: rendered in line (one thread)
            "ahead_wait_seconds": res.render_wait_seconds,
            "rel_error": mean_of([f["rel_error"] for f in per_frame]),
            "rel_error_roi": mean_of([f["rel_error_roi"] for f in per_frame]),
            "rel_error_unclipped": mean_of([f.get("rel_error_unclipped") for f in per_frame]),
            "clipped_fraction": mean_of([f.get("clipped_fraction") for f in per_frame]),
            "rel_error_pixel_median": mean_of([f.get("rel_error_pixel_median") for f in per_frame]),
            "rel_error_pixel_p90": mean_of([f.get("rel_error_pixel_p90") for f in per_frame]),
            "rel_error_definition": "RMS per-pixel Monte Carlo standard error / mean radiance "
                                    "(frame or ROI), from independent-seed renders; mean over frames. "
                                    "rel_error: every rendered pixel (guard band included); "
                                    "rel_error_unclipped: the field of view without the pixels clipped "
                                    "in the encoded capture (full scale whatever the estimate), "
                                    "clipped_fraction of it left out; rel_error_pixel_median/_p90: each unclipped "
                                    "pixel's own standard error / its radiance, median and 90th percentile "
                                    "(a few lamp-edge pixels 1e4x the road dominate the RMS figures; each pixel's "
                                    "error comes from mc_splits replicates, so these two scatter by ~2x "
                                    "between runs where a third of the pixels, the sky seen directly, "
                                    "carry no MC noise)",
            "path": renderer.plan.mode, "path_reason": renderer.plan.reason,
            "variant": renderer.variant, "variant_reason": renderer.variant_reason,
            "static": spec.is_static,
            # a frame source ([source] exr_sequence / ldr_highlight) draws no samples and lights nothing
            "sampler": spec.render.sampler if spec.source.renders else None,
            "light_weights": getattr(renderer, "light_weights", None), **render_targets(spec, per_frame)},
        **{k: {"seconds": v} for k, v in res.stage_seconds.items()},
    }
    if causal:
        stages["predict"] = {
            "seconds": float(np.median(predict_s)) if predict_s else None,
            "seconds_definition": "median per frame, predictor + mask law",
            "total_seconds": float(np.sum(predict_s)), "frames": len(predict_s),
            "predictor": step.model.describe(), "mode": spec.loop.mode, "init_frames": spec.loop.init_frames,
            "reference": {"paper_vp_plus_mask_ms_rtx3090": 16.9, "dlpc900_8bit_pattern_min_ms": 4.046}}
    return stages


def build_report(spec, renderer, camera, step, res, *, setup_s: float, t_run: float, temporal: dict) -> dict:
    """The whole report of a render run (render_run.RunResult `res`)."""
    causal = step is not None and not step.needs_truth
    floor = attenuation_floor(spec.dmd, camera.schedule(0)) if camera.dmd else None
    per_frame = res.per_frame
    metrics = run_metrics(spec, camera, per_frame, res.law_comparison, causal)
    p = camera.params
    signal_dn = mean_of([f.get("mean_signal_dn_roi") for f in per_frame])
    stats = renderer.stats
    return {
        "scene": spec.name, "scene_file": str(spec.toml_path), "description": spec.description,
        "version": __version__, "seed": spec.render.seed, "resolution": list(spec.render.resolution),
        "frames": spec.timing.frames, "unit": PHOTON_RADIANCE_UNIT,
        **camera_sections(spec, camera, floor),
        "stages": stage_sections(spec, renderer, step, res, setup_s, causal),
        **({"timing_budget": step.clock.summary({"timeline_png": res.timeline})}
           if step is not None and step.clock is not None else {}),
        **({"attenuator": attenuator_section(spec, per_frame)} if spec.attenuator.enabled else {}),
        "metrics": metrics,
        "errors": error_budget(spec, camera, per_frame, res.stage_seconds, temporal or {"rel": None},
                               stats.seconds + setup_s),
        "physics_noise": physics_noise(signal_dn, signal_dn / p.gain_dn_per_e if signal_dn else None, p.bits),
        "notes": run_notes(spec, renderer, camera, step, per_frame, metrics, floor),
        "skipped_stages": skipped_stages(spec, camera, causal),
        "io_seconds": res.write_seconds, "io_wait_seconds": res.write_wait_seconds,
        "total_seconds": time.perf_counter() - t_run,
        "per_frame": per_frame,
    }
