"""`poevp chart`: a simulated camera's dynamic range on a rendered transmissive DR chart.

The chart is static: rendered once (one `render_with_error`), then captured N times with the DMD
all white (LDR) and N times through a mask. The mask comes from the closed loop on the chart
(`chart.mask_source = "loop"`: the scene's predictor, `hold` by default, in its loop mode, frame
after frame until the mask is stable) or from the mask law on the true chart (`"oracle"`).
DR math and attribution: charts.py. Everything here is wiring, files and plots.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from poevp_optics.analysis import charts
from poevp_optics.sources import spectra
from poevp_optics.camera.camera import Camera
from poevp_optics.camera.dmd import attenuation_parts
from poevp_optics.core.io import write_exr, write_png
from poevp_optics.apps.run.outputs import contact_sheet, mask_png
from poevp_optics.control.loop_step import LoopStep, oracle_mask
from poevp_optics.core.seeds import CHART_LOOP_STREAM, capture_seed, render_seeds
from poevp_optics.analysis.metrics import to_8bit
from poevp_optics.camera.reconstruct import dn_to_electrons, is_saturated
from poevp_optics.render.renderer import Renderer, absolute_spectrum
from poevp_optics.core.report import write_report
from poevp_optics.core.exceptions import SceneError
from poevp_optics.scene.spec import SceneSpec
from poevp_optics.scene.load import load_scene
from poevp_optics.analysis.tonemap import tonemap

#: The paper's measurements with its prototype (poevp-paper.txt Sec. 7, 36-patch chart).
PAPER_DB = {"ldr": 70.35, "encoded": 120.74}
METHODS = charts.chart_methods()      # DR methods on the patches: name -> SNR_inc threshold


def _stable_changed(old: np.ndarray, new: np.ndarray, level_exposure: np.ndarray) -> float:
    """Fraction of mirrors whose exposure changes by more than 25 % between two masks."""
    a = level_exposure[old.astype(np.int64)]
    b = level_exposure[new.astype(np.int64)]
    return float(np.mean(np.abs(b - a) > 0.25 * np.maximum(a, b)))


def settle_mask(spec: SceneSpec, cam: Camera, truth: np.ndarray, white_capture) -> tuple[np.ndarray, dict]:
    """Run the loop (control/loop_step.py) on the static chart until the mask is stable; return
    it and the history. Stable: no saturated pixel whose mirror could still go darker, and under
    1 % of mirrors changing their exposure by more than 25 % from one frame to the next."""
    lev = cam.level_exposure_s(0)
    if spec.chart.mask_source == "oracle":
        return oracle_mask(cam, spec.resolved.loop.mask, cam.dmd_image(truth), 0), {"source": "oracle", "frames": 0, "converged": True,
                                                       "history": []}
    # no [attenuator] here: a global ND scales both ends of one frame's range alike, so it leaves
    # the chart's (intra-frame) dynamic range unchanged
    # the scene's exposure throughout: the chart measures one frame's range with a settled mask
    fixed = dataclasses.replace(spec.resolved.loop.mask, exposure_time_s=spec.timing.exposure_s)
    step = LoopStep(cam, fixed, spec.loop, spec.predictor)
    source = f"loop ({step.model.name}, {spec.loop.mode})"
    mask, frames = cam.white_mask(), []
    min_level = min(spec.mask.min_level, cam.top_level)
    for it in range(spec.chart.max_iterations):
        cap = cam.capture([truth], mask, it, capture_seed(spec.sensor.seed, spec.render.seed, it, CHART_LOOP_STREAM))
        est, flags, _ = cam.reconstruct(cap, it)
        step.observe(it, white_capture, cap, est, flags)
        decision = step.next_mask(it + 1)
        sat = (flags.astype(np.int64) & 1) > 0
        movable = int(np.count_nonzero(sat & (cam.to_sensor(mask) > min_level)))
        changed = _stable_changed(mask, decision.levels, lev)
        frames.append({"frame": it, "saturated_fraction": float(np.mean(sat)),
                       "saturated_movable": movable, "changed_fraction": changed,
                       **({"prediction_fallback_pixels": decision.fallback_px} if decision.fallback_px else {})})
        if it + 1 >= spec.loop.init_frames and movable == 0 and changed < 1e-2:
            return mask, {"source": source, "frames": it + 1, "converged": True, "history": frames}
        mask = decision.levels
    return mask, {"source": source, "frames": spec.chart.max_iterations, "converged": False, "history": frames}


def _center_crop(img: np.ndarray, shape) -> np.ndarray:
    """The central `shape` of an image rendered with a wider guard band."""
    gy, gx = (img.shape[0] - shape[0]) // 2, (img.shape[1] - shape[1]) // 2
    return img[gy:gy + shape[0], gx:gx + shape[1]]


def _measure(cam: Camera, spec: SceneSpec, truth, regions, masks_levels, stream: int, lum, dens, true_sig):
    """N captures through `masks_levels` (None: no DMD) -> (PatchTable, first capture, mean estimate).
    truth: the chart radiance on the camera's mirror grid."""
    p = cam.params
    n = spec.chart.repeats
    dark_e = p.dark_current_e_per_s * spec.timing.exposure_s if cam.sensor.switches.dark_current else 0.0
    est, sat, elec = [], [], []
    first = scale = None
    for i in range(n):
        cap = cam.capture([truth], masks_levels, i, capture_seed(spec.sensor.seed, spec.render.seed, i, stream))
        if first is None:                    # the mask is fixed: one exposure map for all
            first = cap
            scale = cap.exposure_s.astype(np.float64) * cam.etendue_m2_sr * cam.throughput
        dn = cap.dn.astype(np.float64)
        e_dn = dn_to_electrons(dn, p)
        e = e_dn - dark_e                    # not clamped at 0: the noise near black stays
        est.append(np.where(scale > 1e-300, e / np.maximum(scale, 1e-300), 0.0))
        sat.append(is_saturated(dn, e_dn, p))
        elec.append(e)
    clip_sig = ((p.max_dn - p.offset_dn) / p.gain_dn_per_e - dark_e) / np.maximum(scale, 1e-300)
    flare = first.signal_e.astype(np.float64) - cam.to_sensor(truth) * scale
    est = np.stack(est)
    table = charts.patch_table(regions, dens, lum, true_sig, est, np.stack(sat), clip_sig,
                               np.stack(elec), scale, flare)
    return table, first, est.mean(axis=0)


def _with_camera(spec: SceneSpec, ref: SceneSpec) -> SceneSpec:
    """Our chart seen by `ref`'s camera: its timing, DMD, optics and sensor (our render, mask law)."""
    timing = dataclasses.replace(ref.timing, frames=spec.timing.frames)
    return dataclasses.replace(spec, timing=timing, dmd=ref.dmd, objective=ref.objective, relay=ref.relay,
                               sensor=ref.sensor)


def measure_camera(spec: SceneSpec, truth_field, regions, lum, dens, true_sig) -> dict:
    """LDR (scene bits and 8-bit readout), settled mask, encoded: tables, DR, limits.
    truth_field: the chart rendered with a guard band at least this camera's."""
    t0 = time.perf_counter()
    cam = Camera.from_params(spec.resolved.camera)
    truth = _center_crop(truth_field, cam.mirror_shape)
    top = cam.top_level
    white = cam.white_mask()
    res = {"tables": {}, "dr": {}, "details": {}, "images": {}}
    ldr_t, ldr_cap, ldr_est = _measure(cam, spec, truth, regions, white, 1, lum, dens, true_sig)
    res["tables"]["ldr"] = ldr_t
    res["images"]["ldr"] = to_8bit(ldr_cap.dn, cam.params.max_dn)
    emva = charts.emva_dr(cam.params, spec.timing.exposure_s)
    if cam.params.bits != 8:
        spec8 = dataclasses.replace(spec, sensor=dataclasses.replace(spec.sensor, bits=8))
        cam8 = Camera.from_params(spec8.resolved.camera)
        res["tables"]["ldr_8bit"], _, _ = _measure(cam8, spec8, _center_crop(truth_field, cam8.mirror_shape),
                                                   regions, cam8.white_mask(), 1, lum, dens, true_sig)
        res["emva_8bit"] = charts.emva_dr(cam8.params, spec.timing.exposure_s)
    if cam.dmd is not None:
        mask, settle = settle_mask(spec, cam, truth, ldr_cap)
        enc_t, enc_cap, enc_est = _measure(cam, spec, truth, regions, mask, 2, lum, dens, true_sig)
        res["tables"]["encoded"] = enc_t
        res["settle"] = settle
        res["images"].update(mask=mask_png(mask, top), encoded=to_8bit(enc_cap.dn, cam.params.max_dn),
                             reconstruction=enc_est.astype(np.float32))
        res["mask"] = mask
        min_level = min(spec.mask.min_level, top)
        res["parts"] = attenuation_parts(spec.dmd, cam.schedule(0), min_level)
    for mode, table in res["tables"].items():
        res["details"][mode] = {m: charts.dynamic_range(table, thr) for m, thr in METHODS.items()}
        res["dr"][mode] = {m: res["details"][mode][m]["db"] for m in METHODS}
    res["dr"]["ldr"]["emva"] = emva["db"]
    if "ldr_8bit" in res["dr"]:
        res["dr"]["ldr_8bit"]["emva"] = res["emva_8bit"]["db"]
    res["emva"] = emva
    if "encoded" in res["dr"]:
        res["dr"]["encoded"]["emva"] = emva["db"] + res["parts"]["gain_db"]
        floor_e = charts.sensor_noise_floor_e(cam.params, spec.timing.exposure_s)
        res["limits"] = charts.attribute(res["details"]["ldr"]["iso15739"],
                                         res["details"]["encoded"]["iso15739"], res["parts"],
                                         res["tables"]["encoded"], floor_e, flare_source(cam))
    res["psf"] = cam.psf.name if cam.psf is not None else "delta"
    res["psf_truncation"] = cam.psf.truncation_error if cam.psf is not None else 0.0
    if cam.objective is not None:
        res["objective"] = objective_limit(cam, truth, regions, dens, res, spec.chart.roi_inset_px)
    res["seconds"] = time.perf_counter() - t0
    return res


def flare_source(cam: Camera) -> tuple[str, str]:
    """(charts.LIMIT_WORDS key, words) of the optics whose spread is the chart's flare (the
    capture minus the pinhole image, `_measure`): the objective's PSF (unless `delta`) and
    veiling glare g (before the DMD), the relay's PSF (unless `delta`) and glare."""
    obj, rel = [], []
    o, r = cam.objective, cam.relay_spec
    if o is not None and o.psf != "delta":
        obj.append(f"the objective's {o.psf} PSF")
    if o is not None and o.glare_fraction > 0:
        obj.append(f"the objective's veiling glare (g = {o.glare_fraction:g}, before the DMD: no mask lowers it)")
    if r.psf != "delta":
        rel.append(f"the relay's {r.psf} PSF")
    if r.glare_fraction > 0:
        rel.append(f"the relay's glare (g = {r.glare_fraction:g})")
    key = "optics_flare" if obj and rel else "objective_flare" if obj else "relay_flare"
    spread = " and ".join(obj + rel) or "no optic (a pinhole image: only resampling spreads light)"
    return key, f"flare (light spread from brighter patches) by {spread}"


def whole_patch_area(region: np.ndarray, inset_px: int) -> int:
    """A rectangular patch's whole area (px) from its measuring region, which
    charts.patch_regions eroded by `inset_px`: the region's bounding box grown by the inset on
    each side (the corners a noisy selection drops do not shrink it)."""
    ys, xs = np.nonzero(region)
    return int((ys.max() - ys.min() + 1 + 2 * inset_px) * (xs.max() - xs.min() + 1 + 2 * inset_px))


def objective_limit(cam: Camera, truth, regions, dens, res: dict, inset_px: int = 0) -> dict:
    """How the objective's veiling glare limits the encoded DR (objective.glare_floor). Two
    floors: the VGI of the darkest patch in a white surround, and this chart's own. The VGI
    (ISO 9358:1994, read as ISO 18844:2017 reads flare: at the centre of the black patch, the
    patch being the chart's element, not its measuring region) is the closed form for a black
    disc of the *whole* patch's equivalent radius sqrt(area / pi) in mirrors (`whole_patch_area`);
    the inset measuring region's radius (reported as measuring_radius_px) would give a VGI
    11-34 % higher on dr_chart36. The chart's own floor: the glare
    the halo brings onto the darkest patch from every patch, g (H * x) (x the pinhole image),
    over the brightest patch's radiance. Glare is in the image the mirrors see, so the mask
    cannot lower either: a patch darker than the floor relative to the brightest gets more glare
    than light of its own (the ISO 15739 SNR may still resolve it while shot noise allows); the
    DMD's floor adds at most its headroom to the LDR DR. `binding`: the lower of the chart's glare
    limit and that DMD limit."""
    from poevp_optics.camera.objective import glare_floor

    dark, bright = int(np.argmax(dens)), int(np.argmin(dens))
    scale = cam.registration.scale if cam.dmd is not None else 1.0
    rho = math.sqrt(whole_patch_area(regions[dark], inset_px) / math.pi) / scale
    out = {**cam.objective_summary(), "glare": glare_floor(cam.objective, cam.mirror_shape, rho)}
    out["glare"].update(black_patch="whole patch (ISO 18844): equivalent radius of the darkest patch's "
                                    "rectangle; the VGI is read at its centre",
                        measuring_radius_px=math.sqrt(float(regions[dark].sum()) / math.pi) / scale)
    glare_db = out["glare"]["floor_db"]
    if cam.objective.glare_fraction > 0:
        from poevp_optics.camera.objective import convolve_reflect, glare_kernel

        veil = cam.objective.glare_fraction * convolve_reflect(np.asarray(truth, np.float64),
                                                               glare_kernel(cam.objective, cam.mirror_shape).kernel)
        x_s = cam.to_sensor(truth)
        ratio = float(cam.to_sensor(veil)[regions[dark]].mean() / x_s[regions[bright]].mean())
        glare_db = float(-20 * math.log10(ratio))
        out["glare"].update(chart_veil_ratio=ratio, chart_floor_db=glare_db)
    if "parts" in res:
        ldr_db = res["dr"]["ldr"]["iso15739"]
        dmd_cap = ldr_db + res["parts"]["gain_db"]
        binds = "objective glare" if glare_db < dmd_cap else "DMD attenuation floor"
        out.update(dmd_floor_db=res["parts"]["gain_db"], dmd_floor=res["parts"]["floor"],
                   dmd_limit_db=dmd_cap, glare_limit_db=glare_db, binding=binds,
                   explanation=(f"objective glare (g = {cam.objective.glare_fraction:g}) veils the darkest "
                                f"patch at {10 ** (-glare_db / 20):.3g} of the brightest ({glare_db:.1f} dB; "
                                f"{out['glare']['floor_db']:.1f} dB in a white surround, VGI "
                                f"{out['glare']['vgi']:.3g}) whatever the mask: a patch darker than that "
                                f"gets more glare than light of its own; the DMD's floor "
                                f"({res['parts']['floor']:.3g}, {res['parts']['gain_db']:.1f} dB) adds at most "
                                f"that to the LDR DR ({ldr_db:.1f} + {res['parts']['gain_db']:.1f} = "
                                f"{dmd_cap:.1f} dB): the lower of the two, {binds}, binds (the ISO 15739 "
                                f"figure may exceed both: it resolves steps inside the veil while shot noise "
                                f"allows)"))
    return out


def _eight_bit_note(res) -> str | None:
    if "ldr_8bit" not in res["dr"]:
        return None
    e8, e = res["emva_8bit"], res["emva"]
    chart8 = res["dr"]["ldr_8bit"]["iso15739"]
    return (f"8-bit readout of the same electrons: 1 DN = {e8['mu_sat_e'] / 254:.0f} e-, so the ADC's "
            f"quantisation noise (0.29 DN = {e8['sigma_d_e']:.1f} e- with read noise) dwarfs the "
            f"{e['sigma_d_e']:.1f} e- dark noise of the 12-bit readout: the per-pixel EMVA DR drops "
            f"from {e['db']:.1f} to {e8['db']:.1f} dB (20 log10(255 / 0.29) = 58.9 dB is the cap for "
            f"a pixel that spans every code, 20 log10(255) = 48.1 dB if 1 DN is the floor). The chart "
            f"gives {chart8:.1f} dB because a patch mean over many pixels and captures resolves "
            f"steps below 1 DN where noise and fixed-pattern offsets dither the codes, while the "
            f"per-pixel temporal noise it divides by is the quantised one.")


def _plot(path: Path, res: dict, title: str):
    from poevp_optics.core.runtime import pyplot

    plt = pyplot()

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6))
    styles = {"ldr": ("C0", "LDR (DMD white)"), "ldr_8bit": ("C2", "LDR, 8-bit readout"),
              "encoded": ("C3", "encoded (mask)")}
    for mode, t in res["tables"].items():
        c, label = styles[mode]
        ok = ~t.clipped
        pos = ok & (t.mean_signal > 0)                  # log axes: a zero or negative mean is not drawn
        axes[0].loglog(t.luminance_cd_m2[pos], t.mean_signal[pos], "o-", c=c, ms=3,
                       label=f"{label}: {res['dr'][mode]['iso15739']:.1f} dB")
        axes[0].loglog(t.luminance_cd_m2[~ok], t.mean_signal[~ok], "x", c=c, ms=5)
        good = ok & (t.snr > 0) & np.isfinite(t.snr)
        axes[1].loglog(t.luminance_cd_m2[good], t.snr[good], "o-", c=c, ms=3, label=label)
        d = res["details"][mode]["iso15739"]
        for key, ls in (("l_min_cd_m2", ":"), ("l_max_cd_m2", "--")):
            if d.get(key):
                axes[0].axvline(d[key], c=c, ls=ls, lw=0.8)
                axes[1].axvline(d[key], c=c, ls=ls, lw=0.8)
    t = next(iter(res["tables"].values()))
    axes[0].loglog(t.luminance_cd_m2, t.true_signal, "k-", lw=0.6, label="ground truth")
    axes[0].set_ylim(t.true_signal.min() / 10, t.true_signal.max() * 10)
    for thr in METHODS.values():
        axes[1].axhline(thr, c="grey", ls="-.", lw=0.8)
    axes[0].set(xlabel="patch luminance (cd/m²)", ylabel="mean estimate (e⁻ s⁻¹ m⁻² sr⁻¹)",
                title="signal (x: clipped; dotted L_min, dashed L_max)")
    axes[1].set(xlabel="patch luminance (cd/m²)", ylabel="incremental SNR",
                title="SNR (thresholds 1: iso15739, 10: snr10)")
    axes[0].legend(fontsize=8)
    axes[1].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    from poevp_optics.core.io import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _csv(path: Path, blocks: dict):
    import csv
    import io as _io

    from poevp_optics.core.io import atomic_path

    buf = _io.StringIO()
    w = None
    for camera, res in blocks.items():
        for mode, t in res["tables"].items():
            for row in t.rows():
                row = {"camera": camera, "mode": mode, **row}
                if w is None:
                    w = csv.DictWriter(buf, fieldnames=list(row))
                    w.writeheader()
                w.writerow(row)
    with atomic_path(path) as tmp:
        Path(tmp).write_text(buf.getvalue())


def _summary(res: dict) -> dict:
    out = {"dynamic_range_db": res["dr"], "details": res["details"], "emva": res["emva"],
           "psf": res["psf"], "seconds": res["seconds"],
           "patches": {m: t.rows() for m, t in res["tables"].items()}}
    for k in ("limits", "settle", "emva_8bit", "objective"):
        if k in res:
            out[k] = res[k]
    note = _eight_bit_note(res)
    if note:
        out["eight_bit_note"] = note
    return out


def _write_files(out_dir: Path, spec: SceneSpec, truth, var, blocks: dict, ref_name: str | None) -> float:
    """The chart's EXRs, images, curves and patch table; returns the seconds it took."""
    tw = time.perf_counter()
    main = blocks["scene"]
    attrs = {"poevp_scene": spec.name, "poevp_unit": "e- s-1 m-2 sr-1"}
    write_exr(out_dir / "radiance.exr", {"Y": truth, "mc_stderr": np.sqrt(var)},
              {**attrs, "poevp_quantity": "sensor-weighted photon radiance of the chart"})
    rows = [[tonemap(truth, spec.outputs.tonemap), main["images"]["ldr"].astype(np.uint8)]]
    labels = ["chart (tone-mapped)", "LDR capture"]
    if "encoded" in main["tables"]:
        write_exr(out_dir / "reconstruction.exr", {"Y": main["images"]["reconstruction"]},
                  {**attrs, "poevp_quantity": f"mean of {spec.chart.repeats} encoded reconstructions"})
        write_png(out_dir / "mask.png", main["images"]["mask"])
        write_png(out_dir / "encoded.png", main["images"]["encoded"].astype(np.uint8))
        rows[0] += [main["images"]["mask"], main["images"]["encoded"].astype(np.uint8),
                    tonemap(main["images"]["reconstruction"], spec.outputs.tonemap)]
        labels += ["mask", "encoded capture", "reconstruction"]
    write_png(out_dir / "ldr.png", main["images"]["ldr"].astype(np.uint8))
    write_png(out_dir / "chart_images.png", contact_sheet(rows, labels))
    _plot(out_dir / "chart_curves.png", main, f"{spec.name}: dynamic range ({main['psf']} PSF)")
    if ref_name:
        _plot(out_dir / f"chart_curves_{ref_name}.png", blocks[ref_name],
              f"{spec.name} seen by {ref_name}'s camera (paper: {PAPER_DB['ldr']} / {PAPER_DB['encoded']} dB)")
    _csv(out_dir / "patches.csv", blocks)
    return time.perf_counter() - tw


def _chart_report(spec: SceneSpec, renderer, blocks: dict, ref_name, dens, regions, check: float,
                  render_s: float) -> dict:
    """The chart's report.json (without stage timings)."""
    from poevp_optics.analysis.error_budget import POISSON_BOUND, budget

    main, plan = blocks["scene"], renderer.plan
    report = {"scene": spec.name, "scene_file": str(spec.toml_path), "kind": "chart",
              "chart": {"patches": spec.chart.patches, "densities": dens.tolist(),
                        "light_box_cd_m2": spec.chart.luminance_cd_per_m2, "source": spec.chart.source,
                        "span_db": float(20 * (dens.max() - dens.min())), "repeats": spec.chart.repeats,
                        "pixels_per_patch_min": int(min(r.sum() for r in regions))},
              "render": {"path": plan.mode, "reason": plan.reason, "variant": renderer.variant,
                         "calls": renderer.stats.calls, "seconds": render_s,
                         "patch_radiance_max_rel_error": check},
              **_summary(main)}
    report["dynamic_range_db"] = main["dr"]
    report["errors"] = budget({
        "render_mc": {"rel": check, "where": "patch interiors (closed form vs render)", "seconds": render_s},
        "temporal": {"rel": 0.0, "method": "static chart: one radiance sample is exact", "seconds": 0.0},
        "psf_truncation": {"rel": main["psf_truncation"], "seconds": 0.0},
        "poisson_sampler": {"rel": POISSON_BOUND, "method": "exact samplers", "seconds": 0.0},
        "dr_interpolation": {"rel": None, "db": float(20 * np.median(np.abs(np.diff(dens)))) / 2,
                             "method": "half a patch step: the log-log interpolation of L_min is "
                                       "exact only for a straight SNR curve between two patches"}})
    if ref_name:
        r = blocks[ref_name]
        report["reference_camera"] = {
            "scene": ref_name, **_summary(r), "paper_db": PAPER_DB,
            "comparison": {"ldr": {"simulated": r["dr"]["ldr"]["iso15739"], "paper": PAPER_DB["ldr"]},
                           "encoded": {"simulated": r["dr"].get("encoded", {}).get("iso15739"),
                                       "paper": PAPER_DB["encoded"]}},
            "note": _paper_note(r, ref_name)}
    report["skipped_stages"] = {
        "render_repeat": f"static chart: rendered once ({renderer.stats.calls} Mitsuba calls for "
                         f"{spec.render.mc_splits} MC splits), reused by every capture",
        "subframes": "static: one radiance sample per exposure (K = 1 is exact)"}
    if main["psf"] == "delta":
        report["skipped_stages"]["relay"] = "psf = 'delta': no convolution"
    return report


def _patch_regions(spec: SceneSpec, truth, var, expected, names):
    """Each patch's inner pixels (at least 16, else a one-line error naming the inset key)."""
    regions = charts.patch_regions(truth, expected, spec.chart.roi_inset_px, np.sqrt(var))
    for i, reg in enumerate(regions):
        if reg.sum() < 16:
            raise SceneError(f"{spec.toml_path}: chart.roi_inset_px: patch {names[i]} keeps {int(reg.sum())} "
                             f"pixels after the {spec.chart.roi_inset_px}-pixel inset (need >= 16): "
                             "raise render.resolution or lower the inset")
    return regions


def run_chart(spec: SceneSpec, out_dir: Path, progress: bool = True) -> dict:
    """Render the chart once, measure the scene's camera (and the reference camera), write files."""
    t_run = time.perf_counter()
    file = spec.toml_path
    if not spec.chart.patches:
        raise SceneError(f"{file}: chart.patches: not a chart scene (no [chart] section with patches)")
    if not spec.is_static:
        raise SceneError(f"{file}: motion: a dynamic-range chart must be static")
    out_dir = Path(out_dir)
    ref = load_scene(spec.toml_path.parent / spec.chart.reference_camera) if spec.chart.reference_camera else None
    cam = Camera.from_params(spec.resolved.camera)
    guard = max(cam.guard_px, Camera.from_params(_with_camera(spec, ref).resolved.camera).guard_px if ref else 0)
    renderer = Renderer(spec.resolved.render, guard_px=guard)
    names = [spec.chart.param(i) for i in range(spec.chart.patches)]
    expected = np.array([spectra.integrate(renderer.plan.response_e_per_J * absolute_spectrum(spec.spectra[n]))
                         for n in names])
    dens = np.array(spec.chart.density_list())
    lum = np.array([spec.spectra[n].luminance_cd_per_m2 for n in names])
    t0 = time.perf_counter()
    truth_field, var_field = renderer.render_with_error(render_seeds(spec.render.seed, 0, 0, spec.render.mc_splits),
                                                        spec.render.spp)
    render_s = time.perf_counter() - t0
    truth = cam.to_sensor(_center_crop(truth_field, cam.mirror_shape)).astype(np.float32)
    var = cam.to_sensor(_center_crop(var_field, cam.mirror_shape))
    regions = _patch_regions(spec, truth, var, expected, names)
    check = max(abs(float(truth[r].mean()) / e - 1) for r, e in zip(regions, expected))
    blocks = {"scene": measure_camera(spec, truth_field, regions, lum, dens, expected)}
    ref_name = ref.name if ref is not None else None
    if ref is not None:
        blocks[ref_name] = measure_camera(_with_camera(spec, ref), truth_field, regions, lum, dens, expected)
    write_s = _write_files(out_dir, spec, truth, var, blocks, ref_name)
    report = _chart_report(spec, renderer, blocks, ref_name, dens, regions, check, render_s)
    report["stages"] = {"render": {"seconds": render_s}, "cameras": {k: v["seconds"] for k, v in blocks.items()},
                        "write": {"seconds": write_s}}
    report["total_seconds"] = time.perf_counter() - t_run
    write_report(out_dir, report)
    from poevp_optics.apps.run.report_html import write_report_html

    write_report_html(out_dir, report)                  # the images, DR curves and notes to look at
    return report


def _paper_note(r: dict, name: str) -> str:
    ldr = r["dr"]["ldr"]["iso15739"]
    enc = r["dr"].get("encoded", {}).get("iso15739")
    parts = r.get("parts", {})
    text = (f"With {name}'s camera (8-bit readout, its timing and DMD) the simulated LDR DR is "
            f"{ldr:.1f} dB against the paper's {PAPER_DB['ldr']} dB")
    if enc is not None:
        text += (f"; encoded {enc:.1f} dB against {PAPER_DB['encoded']} dB. The limit that binds: "
                 f"{charts.LIMIT_WORDS[parts.get('binding', 'white_fill')]}, which passes "
                 f"{parts.get('floor', math.nan):.3g} of white whatever the mask "
                 f"({parts.get('gain_db', math.nan):.1f} dB of headroom). The paper's 50 dB gain needs a "
                 "DMD window that covers the exposure (or a dark DMD outside it): with the timing "
                 "printed in its Fig. 7 caption no mask can attenuate more than the white fill allows.")
    return text
