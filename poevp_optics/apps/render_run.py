"""The run over frames: render each exposure (K sub-frames), then the camera stages.

A static scene is rendered once and the same radiance reused for every frame and sub-frame;
the report lists that, and every other stage a scene leaves out, under `skipped_stages`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from poevp_optics import __version__
from poevp_optics.core.frame import Frame, Quantity
from poevp_optics.camera.camera import Camera
from poevp_optics.camera.dmd import attenuation_floor
from poevp_optics.analysis.error_budget import physics_noise
from poevp_optics.core.io import write_dn, write_exr, write_png
from poevp_optics.control.masks import mask_levels, predicted_electrons
from poevp_optics.control.predictors import checked_prediction
from poevp_optics.analysis.metrics import crop, entropy_8bit, mask_iou, relative_error, saturated_fraction, to_8bit
from poevp_optics.camera.reconstruct import reconstruct
from poevp_optics.render.renderer import Renderer
from poevp_optics.scene.spec import MaskSpec, SceneError
from poevp_optics.core.report import write_report
from poevp_optics.scene.spec import SceneSpec
from poevp_optics.analysis.tonemap import tonemap
from poevp_optics.core.units import PHOTON_RADIANCE_UNIT


@dataclass(frozen=True)
class RenderedExposure:
    """Ground truth for one frame: K sub-frame radiances and their time average."""

    index: int
    t_start_s: float
    exposure_s: float
    subframe_times_s: np.ndarray        # (K,) sample times (dmd.node_times_s)
    subframes: tuple[np.ndarray, ...]   # K x (H, W) photon radiance, mirror (render) grid
    radiance: Frame                     # time average over the exposure
    variance: np.ndarray                # MC variance of `radiance` per pixel
    roi: tuple[int, int, int, int] | None
    rel_error: float | None
    rel_error_roi: float | None
    basis: tuple[str, ...] = ()         # subframes are emitter-group images (PWM lamps), not times
    subframe_variances: tuple[np.ndarray, ...] = ()   # MC variance of each sample (temporal error)


def _seeds(base: int, frame: int, sub: int, n: int) -> list[int]:
    """Independent 31-bit seeds for (frame, sub-frame, split) from the scene seed."""
    state = np.random.SeedSequence([base, frame, sub]).generate_state(n)
    return [int(s & 0x7FFFFFFF) for s in state]


def _rel_error(mean: np.ndarray, var: np.ndarray, box=None) -> float | None:
    """RMS per-pixel MC standard error over the mean radiance of the frame (or of `box`)."""
    if box is not None:
        y0, x0, y1, x1 = box
        mean, var = mean[y0:y1, x0:x1], var[y0:y1, x0:x1]
    m = float(np.mean(mean, dtype=np.float64))
    if m <= 0:
        return None
    return float(np.sqrt(np.mean(var, dtype=np.float64)) / m)


def _union(a, b):
    if a is None:
        return b
    if b is None:
        return a
    return (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


def _flicker_bases(spec: SceneSpec, renderer: Renderer):
    """Static geometry with PWM lamps: the image without the flickering lamps and one image per
    flickering lamp (radiance is linear in each lamp's drive), each rendered once."""
    acc = spec.accuracy
    emissive = {n for n, e in spec.spectra.items() if e.kind != "reflectance"}
    groups = [("rest", frozenset(spec.flicker))] + [(p, frozenset(emissive - {p})) for p in spec.flicker]
    out = {}
    for j, (name, zero) in enumerate(groups):
        r = Renderer(spec, zero_params=zero)
        out[name] = r.render_with_error(_seeds(spec.render.seed, 0, 1000 + j, acc.mc_splits), acc.spp)
        renderer.stats.calls += r.stats.calls
        renderer.stats.seconds += r.stats.seconds
    return out, renderer.roi_box()


def render_exposures(spec: SceneSpec, renderer: Renderer, progress: bool = True):
    """Yield a `RenderedExposure` per frame. Static scenes render once (K = 1) and reuse it;
    static geometry with PWM lamps renders each emitter group once and hands the camera those
    images (`basis`), whose exposures it integrates exactly against the lamps' drive: no K."""
    from poevp_optics.sources.flicker import drive_mean

    acc = spec.accuracy
    cache = None
    bases = None
    frames = range(spec.timing.frames)
    for i in tqdm(frames, desc=f"render {spec.name}", unit="frame", disable=not progress or None,
                  leave=False):
        t0, t1 = spec.exposure_window_s(i)
        if spec.is_static:
            if cache is None:
                mean, var = renderer.render_with_error(_seeds(spec.render.seed, 0, 0, acc.mc_splits), acc.spp)
                cache = ((mean,), mean, var, renderer.roi_box())
            subs, mean, var, roi = cache
            times = np.array([(t0 + t1) / 2])
        elif spec.geometry_static:                     # flickering lamps, nothing moves
            if bases is None:
                bases, roi0 = _flicker_bases(spec, renderer)
            times = np.array([(t0 + t1) / 2])
            rest_m, rest_v = bases["rest"]
            mean, var = rest_m.astype(np.float64), rest_v.astype(np.float64)
            for p, fl in spec.flicker.items():
                d = float(drive_mean(np.array([t0]), np.array([t1]), fl)[0])
                mean, var = mean + d * bases[p][0], var + d * d * bases[p][1]
            mean = mean.astype(np.float32)
            subs = (rest_m, *[bases[p][0] for p in spec.flicker])
            roi = roi0
            frame = Frame(mean, Quantity.RADIANCE, PHOTON_RADIANCE_UNIT, t0, t1 - t0, i)
            yield RenderedExposure(i, t0, t1 - t0, times, subs, frame, var, roi,
                                   _rel_error(mean, var), _rel_error(mean, var, roi),
                                   ("rest", *spec.flicker))
            continue
        else:
            times = spec.subframe_times_s(i)
            weights = spec.subframe_weights(i)        # time average of the piecewise-linear L(t)
            subs, variances, roi = [], [], None
            mean = var = 0.0
            for k, t in enumerate(times):
                renderer.set_time(float(t))
                m, v = renderer.render_with_error(_seeds(spec.render.seed, i, k, acc.mc_splits), acc.spp)
                subs.append(m)
                variances.append(v)
                mean = mean + weights[k] * m.astype(np.float64)
                var = var + weights[k] ** 2 * v
                roi = _union(roi, renderer.roi_box())
            mean = mean.astype(np.float32)
            frame = Frame(mean, Quantity.RADIANCE, PHOTON_RADIANCE_UNIT, t0, t1 - t0, i)
            yield RenderedExposure(i, t0, t1 - t0, times, tuple(subs), frame, var, roi,
                                   _rel_error(mean, var), _rel_error(mean, var, roi),
                                   subframe_variances=tuple(variances))
            continue
        frame = Frame(mean, Quantity.RADIANCE, PHOTON_RADIANCE_UNIT, t0, t1 - t0, i)
        yield RenderedExposure(i, t0, t1 - t0, times, subs, frame, var, roi,
                               _rel_error(mean, var), _rel_error(mean, var, roi))


def _exr_attrs(spec: SceneSpec, renderer: Renderer, ex: RenderedExposure, quantity: str,
               unit: str = PHOTON_RADIANCE_UNIT) -> dict:
    return {"poevp_quantity": quantity, "poevp_unit": unit,
            "poevp_scene": spec.name, "poevp_version": __version__, "poevp_frame": str(ex.index),
            "poevp_t_start_s": repr(ex.t_start_s), "poevp_exposure_s": repr(ex.exposure_s),
            "poevp_render_path": renderer.plan.mode, "poevp_variant": renderer.variant,
            "poevp_spp": str(spec.render.spp)}


#: Mask laws compared beside the scene's own on every oracle run: the paper's two readings of
#: Eq. 2 at its simulation (a, b) = (0.9, 0) and hardware (0.7, 0.2) settings, Vs = 200.
PAPER_LAWS = {
    "threshold_exp(0.9,0)": ("threshold_exp", 0.9, 0.0),
    "threshold_exp(0.7,0.2)": ("threshold_exp", 0.7, 0.2),
    "threshold_ratio(0.9,0)": ("threshold_ratio", 0.9, 0.0),
    "threshold_ratio(0.7,0.2)": ("threshold_ratio", 0.7, 0.2),
}


def _frame_seed(spec: SceneSpec, index: int, stream: int) -> int:
    return int(np.random.SeedSequence([spec.sensor.seed, spec.render.seed, index, stream])
               .generate_state(1)[0])


def oracle_mask(spec: SceneSpec, camera: Camera, radiance_mean: np.ndarray, index: int,
                mask_spec: MaskSpec | None = None) -> np.ndarray:
    """The mask law applied to the true frame (mirror grid): the upper bound of any predictor."""
    ms = mask_spec or spec.mask
    white_e = radiance_mean.astype(np.float64) * camera.electrons_per_radiance() * camera.white_exposure_s(index)
    ldr8 = to_8bit(camera.noise_free_dn(white_e), camera.params.max_dn)
    return mask_levels(ms, spec.dmd.bits, pred_8bit=ldr8, pred_electrons=white_e,
                       full_well_e=camera.params.full_well_e,
                       level_exposure=camera.level_exposure_s(index))


def predicted_mask(spec: SceneSpec, camera: Camera, pred_8bit: np.ndarray, index: int) -> np.ndarray:
    """The mask law applied to a predicted frame on the 8-bit scale: the prediction is on the
    sensor grid (it comes from captures) and is placed on the mirror grid through the inverse
    registration before the law (camera.to_mirror)."""
    pred = camera.to_mirror(pred_8bit).astype(np.float64)
    e = predicted_electrons(pred, camera.params, spec.mask.clipped_gain)
    return mask_levels(spec.mask, spec.dmd.bits, pred_8bit=np.clip(pred, 0, 255),
                       pred_electrons=e, full_well_e=camera.params.full_well_e,
                       level_exposure=camera.level_exposure_s(index))


def _resize(img: np.ndarray, shape) -> np.ndarray:
    import cv2

    h, w = shape
    if img.shape == (h, w):
        return img.astype(np.float32)
    interp = cv2.INTER_AREA if img.shape[0] > h else cv2.INTER_LINEAR
    return cv2.resize(img.astype(np.float32), (w, h), interpolation=interp)


def predictor_input(mode: str, camera: Camera, ldr, enc, est, flags, index: int) -> np.ndarray:
    """What the predictor sees (8-bit scale, float32), per loop mode (DESIGN.md)."""
    max_dn = camera.params.max_dn
    if mode == "open":
        return to_8bit(ldr.dn, max_dn).astype(np.float32)
    if mode == "raw":
        return to_8bit(enc.dn, max_dn).astype(np.float32)
    # demodulated: reconstruction re-expressed as the signal an all-white mask would give,
    # on the 8-bit scale, unclipped. A saturated pixel's estimate is only a lower bound x_lb:
    # behind a white mirror (x_lb ~ 255) it is marked clipped (255), which the target law reads
    # as clipped_gain x saturation; behind a dimmed mirror (x_lb > 255) it becomes
    # clipped_gain x x_lb, the same assumption one step further, so a highlight brighter than
    # the first guess is dimmed geometrically, frame after frame (static scenes converge).
    e_white = est.astype(np.float64) * camera.electrons_per_radiance() * camera.white_exposure_s(index)
    x = 255.0 * e_white / camera.params.saturation_capacity_e
    sat = (flags.astype(np.int64) & 1) > 0
    lifted = np.where(x > 255.5, x * camera.spec.mask.clipped_gain, 255.0)
    x = np.where(sat, lifted, np.where(np.abs(x - 255.0) <= 0.5, 254.4, x))
    return x.astype(np.float32)


def _mask_png(levels: np.ndarray, top: int) -> np.ndarray:
    return np.clip(np.rint(levels * 255.0 / top), 0, 255).astype(np.uint8)


def _contact_sheet(rows: list[list[np.ndarray]], labels: list[str]) -> np.ndarray:
    """Tile uint8 grey images (rows of frames x columns of kinds) with column labels."""
    import cv2

    h, w = rows[0][0].shape
    scale = min(1.0, 320.0 / w)
    th, tw = int(round(h * scale)), int(round(w * scale))
    band = 18
    sheet = np.full((band + len(rows) * (th + 4), len(labels) * (tw + 4)), 255, np.uint8)
    for c, lab in enumerate(labels):
        cv2.putText(sheet, lab, (c * (tw + 4) + 4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, 0, 1, cv2.LINE_AA)
    for r, row in enumerate(rows):
        for c, img in enumerate(row):
            y, x = band + r * (th + 4), c * (tw + 4)
            sheet[y:y + th, x:x + tw] = cv2.resize(img, (tw, th), interpolation=cv2.INTER_AREA)
    return sheet


def run_render(spec: SceneSpec, out_dir: Path, progress: bool = True, *, renderer: Renderer | None = None,
               exposures: list | None = None, write_images: bool = True,
               keep_frames: tuple[int, ...] = ()) -> dict:
    """Render `spec` and run the camera into `out_dir` (an empty staging folder); return the report.

    renderer/exposures: reuse an already loaded scene and already rendered exposures (the
    comparison runs many camera loops over one render; its guard band must be the camera's).
    write_images=False writes only report.json. keep_frames: frame indices whose mask and
    captures are returned in report["_kept"] (not written to JSON).
    """
    out_dir = Path(out_dir)
    t_run = time.perf_counter()
    t_setup = time.perf_counter()
    camera = Camera(spec)
    renderer = renderer or Renderer(spec, guard_px=camera.guard_px)
    if renderer.guard_px != camera.guard_px:
        raise ValueError(f"renderer guard band {renderer.guard_px} px != camera's {camera.guard_px} px")
    predictor = None
    if camera.dmd is not None and spec.predictor.name != "oracle":
        from poevp_optics.control.predictors import make_predictor
        from poevp_optics.control.predictors.dmvfn import WeightsError

        try:
            predictor = make_predictor(spec.predictor.name, spec.predictor.weights,
                                       spec.predictor.resolution)
        except WeightsError as e:
            raise SceneError(f"{spec.toml_path}: predictor.weights: {e}") from None
    setup_s = time.perf_counter() - t_setup
    bits = camera.params.bits
    max_dn = camera.params.max_dn
    per_frame = []
    stage_s = {"dmd": 0.0, "relay": 0.0, "sensor": 0.0, "reconstruct": 0.0, "mask": 0.0}
    predict_s = []
    history: list[np.ndarray] = []
    t_write = 0.0
    sheet_rows = []
    sheet_every = max(1, spec.timing.frames // 4)
    law_cmp = {name: {"saturated": [], "entropy": []} for name in ["scene_law", *PAPER_LAWS]}
    kept = {}
    mid = spec.timing.frames // 2
    mid_frame = None
    reuse = exposures is not None
    white = camera.white_mask()
    for ex in (exposures if exposures is not None else render_exposures(spec, renderer, progress)):
        i = ex.index
        name = f"frame_{i:04d}"
        truth = ex.radiance.data                              # mirror (render) grid
        truth_s = camera.to_sensor(truth).astype(np.float32)  # what the sensor pixels see
        box = camera.box_to_sensor(ex.roi)                    # sensor-grid ROI
        subs = list(ex.subframes) if not spec.is_static else [truth]
        bk = {"basis": ex.basis} if ex.basis else ({"times_s": ex.subframe_times_s} if len(subs) > 1 else {})
        # ---- camera: LDR twin (DMD all white) and the encoded capture
        ldr = camera.capture(subs, white, i, _frame_seed(spec, i, 1), **bk)
        rec = {"index": i}
        oracle = None
        if camera.dmd:
            tm = time.perf_counter()
            oracle = oracle_mask(spec, camera, truth, i)
            stage_s["mask"] += time.perf_counter() - tm
            needs = predictor.needs_frames if predictor is not None else 0
            if i < spec.loop.init_frames or len(history) < needs:
                mask = white                      # initialisation frames (paper Sec. 3), oracle too
                rec["init"] = True
            elif predictor is None:
                mask = oracle
            else:
                tp = time.perf_counter()
                pred, n_bad = checked_prediction(predictor, history[-2:])
                if n_bad:
                    rec["prediction_fallback_pixels"] = n_bad     # held the last frame there
                mask = predicted_mask(spec, camera, _resize(pred, camera.shape), i)
                predict_s.append(time.perf_counter() - tp)
                rec["predict_seconds"] = predict_s[-1]
            enc = camera.capture(subs, mask, i, _frame_seed(spec, i, 2), **bk)
        else:
            mask, enc = None, ldr
        for k in ("dmd", "relay", "sensor"):
            stage_s[k] += enc.seconds[k]
        tr = time.perf_counter()
        est, flags, _ = camera.reconstruct(enc, i)
        stage_s["reconstruct"] += time.perf_counter() - tr
        valid = flags == 0
        if i == mid and not ex.basis and not spec.is_static:
            mid_frame = (ex, mask)
        rec["mean_signal_dn_roi"] = float(np.mean(crop(enc.dn, box))) - camera.params.offset_dn
        rec.update({
            "saturated_fraction_roi": {"ldr": saturated_fraction(crop(ldr.dn, box), max_dn),
                                       "encoded": saturated_fraction(crop(enc.dn, box), max_dn)},
            "entropy_roi": {"ldr": entropy_8bit(to_8bit(crop(ldr.dn, box), max_dn)),
                            "encoded": entropy_8bit(to_8bit(crop(enc.dn, box), max_dn))},
            "saturated_fraction": {"ldr": saturated_fraction(ldr.dn, max_dn),
                                   "encoded": saturated_fraction(enc.dn, max_dn)},
            "recon_rel_error": relative_error(est, truth_s, valid),
            "recon_rel_error_roi": relative_error(crop(est, box), crop(truth_s, box), crop(valid, box)) if box else None,
            "valid_fraction": float(np.mean(valid)),
        })
        if predictor is not None:
            history.append(_resize(predictor_input(spec.loop.mode, camera, ldr, enc, est, flags, i),
                                   spec.predictor.resolution))
            history = history[-4:]
            oc = camera.capture(subs, oracle, i, _frame_seed(spec, i, 2), **bk)
            rec["saturated_fraction_roi"]["oracle"] = saturated_fraction(crop(oc.dn, box), max_dn)
            rec["entropy_roi"]["oracle"] = entropy_8bit(to_8bit(crop(oc.dn, box), max_dn))
            if not rec.get("init"):
                top = camera.top_level
                rec["mask_error"] = {"iou": mask_iou(mask, oracle, top),
                                     "mean_abs": float(np.mean(np.abs(mask - oracle)) / top)}
        if camera.dmd:
            rec["mask_mean"] = float(np.mean(mask) / camera.top_level)
            if not rec.get("init"):
                law_cmp["scene_law"]["saturated"].append(rec["saturated_fraction_roi"]["encoded"])
                law_cmp["scene_law"]["entropy"].append(rec["entropy_roi"]["encoded"])
            if spec.mask.law != "white" and predictor is None and not rec.get("init"):
                for lname, (law, a, b) in PAPER_LAWS.items():
                    ms = MaskSpec(law=law, vs=200.0, a=a, b=b, smooth_px=spec.mask.smooth_px)
                    m2 = oracle_mask(spec, camera, truth, i, ms)
                    c2 = camera.capture(subs, m2, i, _frame_seed(spec, i, 2), **bk)
                    law_cmp[lname]["saturated"].append(saturated_fraction(crop(c2.dn, box), max_dn))
                    law_cmp[lname]["entropy"].append(entropy_8bit(to_8bit(crop(c2.dn, box), max_dn)))
        if i in keep_frames:
            kept[i] = {"ldr": to_8bit(ldr.dn, max_dn).astype(np.uint8),
                       "capture": to_8bit(enc.dn, max_dn).astype(np.uint8),
                       "mask": _mask_png(mask, camera.top_level) if mask is not None else None,
                       "oracle_mask": _mask_png(oracle, camera.top_level) if oracle is not None else None,
                       "roi": box}
        if not write_images:
            per_frame.append({**rec, "roi": list(box) if box else None, "rel_error": ex.rel_error,
                              "rel_error_roi": ex.rel_error_roi})
            continue
        # ---- outputs
        tw = time.perf_counter()
        attrs = _exr_attrs(spec, renderer, ex, "")
        if spec.outputs.radiance_exr:
            write_exr(out_dir / "radiance" / f"{name}.exr",
                      {"Y": truth_s, "mc_stderr": np.sqrt(camera.to_sensor(ex.variance))},
                      {**attrs, "poevp_quantity": "sensor-weighted photon radiance on the sensor grid, "
                                                  "exposure mean; mc_stderr = Monte Carlo standard error"})
        if spec.outputs.subframes_exr and ex.basis:
            for bname, sub in zip(ex.basis, ex.subframes):
                write_exr(out_dir / "subframes" / f"{name}_{bname}.exr", {"Y": sub},
                          {**attrs, "poevp_quantity": f"photon radiance of emitter group {bname!r} at full "
                                                      "drive (mirror grid, guard band included)"})
        elif spec.outputs.subframes_exr and not spec.is_static:
            for k, sub in enumerate(ex.subframes):
                write_exr(out_dir / "subframes" / f"{name}_sub{k:03d}.exr", {"Y": sub},
                          {**attrs, "poevp_quantity": f"photon radiance at t = {ex.subframe_times_s[k]!r} s "
                                                      "(mirror grid, guard band included)"})
        write_dn(out_dir / "capture" / name, enc.dn, bits)
        if camera.dmd:
            write_dn(out_dir / "ldr" / name, ldr.dn, bits)
            write_png(out_dir / "mask" / f"{name}.png", _mask_png(mask, camera.top_level))
        write_exr(out_dir / "exposure" / f"{name}.exr", {"Y": enc.exposure_s},
                  {**attrs, "poevp_quantity": "effective exposure (DMD duty x throughput incl. leakage)",
                   "poevp_unit": "s"})
        write_exr(out_dir / "reconstruction" / f"{name}.exr", {"Y": est, "flags": flags},
                  {**attrs, "poevp_quantity": "radiance estimate; flags: 1 saturated, 2 SNR<1, 4 unexposed, "
                                              "8 PSF crosstalk"})
        if spec.outputs.previews:
            write_png(out_dir / "preview" / f"{name}.png", tonemap(truth_s, spec.outputs.tonemap))
            write_png(out_dir / "preview_reconstruction" / f"{name}.png", tonemap(est, spec.outputs.tonemap))
        if spec.outputs.contact_sheet and i % sheet_every == 0 and len(sheet_rows) < 4:
            row = [tonemap(truth_s, spec.outputs.tonemap), to_8bit(ldr.dn, max_dn).astype(np.uint8)]
            if camera.dmd:
                row.append(_mask_png(mask, camera.top_level))
            row += [to_8bit(enc.dn, max_dn).astype(np.uint8), tonemap(est, spec.outputs.tonemap)]
            sheet_rows.append(row)
        t_write += time.perf_counter() - tw
        rec.update({"t_start_s": ex.t_start_s, "exposure_s": ex.exposure_s,
                    "subframe_times_s": ex.subframe_times_s, "roi": list(box) if box else None,
                    "radiance_mean": float(np.mean(truth_s)), "radiance_max": float(np.max(truth_s)),
                    "radiance_min": float(np.min(truth_s)),
                    "roi_radiance_mean": float(np.mean(crop(truth_s, box))) if box else None,
                    "rel_error": ex.rel_error, "rel_error_roi": ex.rel_error_roi})
        per_frame.append(rec)
    if sheet_rows:
        labels = ["scene (tone-mapped)", "LDR twin"] + (["mask"] if camera.dmd else []) + \
                 ["encoded capture", "reconstruction"]
        write_png(out_dir / "contact_sheet.png", _contact_sheet(sheet_rows, labels))
    from poevp_optics.analysis.error_budget import temporal_error

    if reuse:
        temporal = {"rel": None, "method": "not estimated: this run reuses a shared render", "seconds": 0.0}
    else:
        temporal = temporal_error(spec, renderer, camera, *(mid_frame or (None, None)))
    report = _report(spec, renderer, camera, per_frame, stage_s, setup_s, t_write, t_run, law_cmp,
                     predictor, predict_s, temporal)
    write_report(out_dir, report)
    report["_kept"] = kept
    return report


def _mean(vals):
    vals = [v for v in vals if v is not None]
    return float(np.mean(vals)) if vals else None


def _error_budget(spec, camera, per_frame, stage_s, temporal, render_s) -> dict:
    from poevp_optics.analysis.error_budget import POISSON_BOUND, budget

    roi = _mean([f["rel_error_roi"] for f in per_frame])
    frame = _mean([f["rel_error"] for f in per_frame])
    psf = camera.psf
    return budget({
        "render_mc": {"rel": roi if roi is not None else frame, "rel_frame": frame,
                      "where": "ROI" if roi is not None else "frame", "seconds": render_s},
        "temporal": temporal,
        "psf_truncation": {"rel": psf.truncation_error if psf is not None else 0.0,
                           "support_px": int(psf.kernel.shape[0]) if psf is not None else 1,
                           **({"note": psf.note} if psf is not None and psf.note else {}),
                           "seconds": stage_s["relay"]},
        "poisson_sampler": {"rel": POISSON_BOUND, "method": "exact (Knuth < 10 e-, PTRS >= 10 e-); "
                            "float32 counts exact to 2^24 e-", "seconds": stage_s["sensor"]},
    })


def _report(spec, renderer, camera, per_frame, stage_s, setup_s, t_write, t_run, law_cmp,
            predictor=None, predict_s=(), temporal=None) -> dict:
    skipped = {}
    if spec.is_static:
        skipped["render_repeat"] = (f"static scene: rendered once and reused for all "
                                    f"{spec.timing.frames} frames; sub-frames not needed")
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
        if predictor is None:
            skipped["predict"] = "predictor 'oracle' uses the rendered ground truth: no predictor runs"
        if camera.taps is None:
            skipped["registration"] = "identity mirror-to-sensor map: no resampling"
    stats = renderer.stats
    sched = camera.schedule(0)
    floor = attenuation_floor(spec.dmd, sched) if camera.dmd else None
    metrics = {
        "saturated_fraction_roi": {k: _mean([f["saturated_fraction_roi"][k] for f in per_frame]) for k in ("ldr", "encoded")},
        "entropy_roi": {k: _mean([f["entropy_roi"][k] for f in per_frame]) for k in ("ldr", "encoded")},
        "saturated_fraction": {k: _mean([f["saturated_fraction"][k] for f in per_frame]) for k in ("ldr", "encoded")},
        "recon_rel_error": _mean([f["recon_rel_error"] for f in per_frame]),
        "recon_rel_error_roi": _mean([f["recon_rel_error_roi"] for f in per_frame]),
        "valid_fraction": _mean([f["valid_fraction"] for f in per_frame]),
    }
    loop_frames = [f for f in per_frame if not f.get("init")]
    if camera.dmd is not None:
        # the first loop.init_frames frames are white for every predictor, the oracle included:
        # averages after them compare predictors on the frames where a mask acts
        for key in ("saturated_fraction_roi", "entropy_roi"):
            metrics[key]["ldr_after_init"] = _mean([f[key]["ldr"] for f in loop_frames])
            metrics[key]["encoded_after_init"] = _mean([f[key]["encoded"] for f in loop_frames])
            if predictor is None:
                metrics[key]["oracle_after_init"] = metrics[key]["encoded_after_init"]
        metrics["init_frames"] = len(per_frame) - len(loop_frames)
    if predictor is not None:
        for key in ("saturated_fraction_roi", "entropy_roi"):
            metrics[key]["oracle"] = _mean([f[key]["oracle"] for f in per_frame])
            metrics[key]["oracle_after_init"] = _mean([f[key]["oracle"] for f in loop_frames])
        metrics["mask_error"] = {"iou": _mean([f["mask_error"]["iou"] for f in loop_frames]),
                                 "mean_abs": _mean([f["mask_error"]["mean_abs"] for f in loop_frames])}
        # lag artifact: saturated plate fraction in the first two loop frames in which the LDR
        # twin's plate is saturated (the highlight "arrives" and the mask must catch it)
        lit = [f for f in loop_frames if f["saturated_fraction_roi"]["ldr"] > 0.1][:2]
        metrics["lag_artifact"] = _mean([f["saturated_fraction_roi"]["encoded"] for f in lit])
    if camera.dmd and any(v["saturated"] for k, v in law_cmp.items() if k != "scene_law"):
        metrics["mask_law_comparison"] = {
            (f"scene:{spec.mask.law}" if k == "scene_law" else k):
                {"saturated_fraction_roi": _mean(v["saturated"]), "entropy_roi": _mean(v["entropy"])}
            for k, v in law_cmp.items()}
    p = camera.params
    notes = list(renderer.plan.notes)
    if camera.dmd is not None and not loop_frames:
        notes.append(f"every frame is one of the loop.init_frames = {spec.loop.init_frames} all-white "
                     f"initialisation frames: no mask acted; this run shows the LDR camera only")
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
        notes.append(f"predictor {predictor.name!r} gave NaN/Inf on frames {fell_back} "
                     f"({sum(f['prediction_fallback_pixels'] for f in per_frame if f.get('prediction_fallback_pixels'))} "
                     "pixels): those pixels held the last frame (the 'hold' prediction); per_frame "
                     "'prediction_fallback_pixels' counts them")
    if camera.psf is not None and camera.psf.note:
        notes.append(f"relay PSF: {camera.psf.note}")
    total = time.perf_counter() - t_run
    report = {
        "scene": spec.name, "scene_file": str(spec.toml_path), "description": spec.description,
        "version": __version__, "seed": spec.render.seed, "resolution": list(spec.render.resolution),
        "frames": spec.timing.frames, "unit": PHOTON_RADIANCE_UNIT,
        "timing": {"fps": spec.timing.fps, "exposure_s": spec.timing.exposure_s,
                   "exposure_offset_s": spec.timing.exposure_offset_s,
                   "dmd_window_s": spec.timing.dmd_window_s,
                   "dmd_window_offset_s": spec.timing.dmd_window_offset_s,
                   "outside_window": spec.timing.outside_window},
        "accuracy": {"spp": spec.render.spp, "subframes": 1 if spec.geometry_static else spec.render.subframes,
                     "mc_splits": spec.render.mc_splits},
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
                  "predictor": spec.predictor.name} if camera.dmd else None),
        "stages": {
            "render": {
                "seconds": stats.seconds + setup_s, "mitsuba_seconds": stats.seconds,
                "setup_seconds": setup_s, "calls": stats.calls,
                "rel_error": _mean([f["rel_error"] for f in per_frame]),
                "rel_error_roi": _mean([f["rel_error_roi"] for f in per_frame]),
                "rel_error_definition": "RMS per-pixel Monte Carlo standard error / mean radiance "
                                        "(frame or ROI), from independent-seed renders; mean over frames",
                "path": renderer.plan.mode, "path_reason": renderer.plan.reason,
                "variant": renderer.variant, "variant_reason": renderer.variant_reason,
                "static": spec.is_static},
            **{k: {"seconds": v} for k, v in stage_s.items()},
            **({"predict": {
                "seconds": float(np.median(predict_s)) if predict_s else None,
                "seconds_definition": "median per frame, predictor + mask law",
                "total_seconds": float(np.sum(predict_s)), "frames": len(predict_s),
                "predictor": predictor.describe(), "mode": spec.loop.mode,
                "init_frames": spec.loop.init_frames,
                "reference": {"paper_vp_plus_mask_ms_rtx3090": 16.9,
                              "dlpc900_8bit_pattern_min_ms": 4.046}}} if predictor is not None else {}),
        },
        "metrics": metrics,
        "errors": _error_budget(spec, camera, per_frame, stage_s, temporal or {"rel": None},
                                stats.seconds + setup_s),
        "physics_noise": physics_noise(_mean([f.get("mean_signal_dn_roi") for f in per_frame]),
                                       _mean([f.get("mean_signal_dn_roi") for f in per_frame]) / p.gain_dn_per_e
                                       if _mean([f.get("mean_signal_dn_roi") for f in per_frame]) else None,
                                       p.bits),
        "notes": notes,
        "skipped_stages": skipped,
        "io_seconds": t_write, "total_seconds": total,
        "per_frame": per_frame,
    }
    return report
