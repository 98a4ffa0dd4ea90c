"""`poevp render`: the run over frames. Per frame: the ground truth (the scene's [source]:
render/radiance.py, a Mitsuba render or frames read by sources/), the
LDR twin and the encoded capture (camera/), the reconstruction, the closed loop's next step
(control/loop_step.py), the per-frame metrics; then the outputs (apps/run/outputs.py: written on a
thread of their own while the next frame is computed, `BackgroundWriter`) and the report
(apps/run/run_report.py). A run leaves out what its scene does not need; the report lists it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from poevp_optics.analysis.metrics import (crop, entropy_8bit, mask_iou, plate_white_fraction, relative_error,
                                          saturated_fraction, to_8bit)
from poevp_optics.apps.run.outputs import OutputWriter, mask_png
from poevp_optics.apps.run.report_extensions import active as report_extensions
from poevp_optics.apps.run.run_report import build_report
from poevp_optics.apps.run.temporal_check import temporal_error
from poevp_optics.camera.camera import Camera
from poevp_optics.control.loop_step import LoopStep, oracle_choice, oracle_mask
from poevp_optics.control.masks import MaskSpec
from poevp_optics.core.exceptions import SceneError
from poevp_optics.core.report import write_report
from poevp_optics.core.seeds import ENCODED_STREAM, LDR_STREAM, capture_seed
from poevp_optics.core.frame import RenderedExposure
from poevp_optics.render.ahead import RenderAhead
from poevp_optics.render.progressive import pixel_rel_errors, rel_error_unclipped
from poevp_optics.render.radiance import open_source

#: Mask laws compared beside the scene's own on every oracle run: the paper's two readings of
#: Eq. 2 at its simulation (a, b) = (0.9, 0) and hardware (0.7, 0.2) settings, Vs = 200.
PAPER_LAWS = {
    "threshold_exp(0.9,0)": ("threshold_exp", 0.9, 0.0),
    "threshold_exp(0.7,0.2)": ("threshold_exp", 0.7, 0.2),
    "threshold_ratio(0.9,0)": ("threshold_ratio", 0.9, 0.0),
    "threshold_ratio(0.7,0.2)": ("threshold_ratio", 0.7, 0.2),
}


@dataclass
class FrameCapture:
    """One frame through the camera: the captures, the mask that made the encoded one, and the
    reconstruction (sensor grid), with the ground truth on the sensor grid."""

    exposure: RenderedExposure
    truth_s: np.ndarray
    box: tuple | None
    ldr: object
    enc: object
    mask: np.ndarray | None
    oracle: np.ndarray | None
    est: np.ndarray
    flags: np.ndarray
    record: dict
    oracle_transmission: float = 1.0      # the oracle mask's attenuator setting
    oracle_exposure: object | None = None  # the oracle's exposure time and DMD bit depth (control/exposure_time.py)


@dataclass
class RunResult:
    """What the frame loop produced, besides the files."""

    per_frame: list = field(default_factory=list)
    kept: dict = field(default_factory=dict)
    stage_seconds: dict = field(default_factory=lambda: dict.fromkeys(
        ("dmd", "relay", "sensor", "reconstruct", "mask"), 0.0))
    predict_seconds: list = field(default_factory=list)
    law_comparison: dict = field(default_factory=lambda: {
        name: {"saturated": [], "entropy": []} for name in ["scene_law", *PAPER_LAWS]})
    mid_frame: tuple | None = None
    write_seconds: float = 0.0           # the writer's own time (on its thread: BackgroundWriter)
    write_wait_seconds: float = 0.0      # the frame loop's time waiting for the writer
    timeline: str | None = None          # the timeline figure's file name (apps/run/timeline.py)
    render_wait_seconds: float | None = None  # the loop's wait for frames rendered ahead (None: in line)
    extensions: list = field(default_factory=list)   # the scene's report extensions and their state


def capture_inputs(spec, ex: RenderedExposure) -> tuple[list, dict]:
    """(radiance samples, timing keyword) a capture of exposure `ex` takes: its time samples with
    their times (`capture_timing`), or a static scene's one radiance image."""
    if spec.is_static:
        return [ex.radiance.data], {}
    return list(ex.subframes), ex.capture_timing()


def capture_frame(spec, camera: Camera, step: LoopStep | None, ex: RenderedExposure, res: RunResult) -> FrameCapture:
    """LDR twin (DMD all white), the loop's mask, the encoded capture and its reconstruction."""
    i = ex.index
    # mirror grid: the image the objective forms there (a moving scene's from its samples' images)
    t_obj = time.perf_counter()
    truth = (camera.dmd_image_of_average(ex.radiance.data, ex.subframes, ex.subframe_weights, keep_veil=True)
             if ex.subframe_weights else camera.dmd_image(ex.radiance.data, keep_veil=True))
    t_obj = time.perf_counter() - t_obj
    subs, timing = capture_inputs(spec, ex)              # the camera applies the objective
    ldr = camera.capture(subs, camera.white_mask(), i, capture_seed(spec.sensor.seed, spec.render.seed, i, LDR_STREAM),
                         **timing)
    rec = {"index": i}
    mask = oracle = None
    oracle_g, oracle_fx = 1.0, None
    enc = ldr
    if camera.dmd:
        cmd = step.command(i, truth)
        rec.update(cmd.record)
        if cmd.decision.predict_seconds is not None:
            res.predict_seconds.append(cmd.decision.predict_seconds)
        tm = time.perf_counter()
        if step.needs_truth and not cmd.decision.init:   # the oracle's own decision: not computed twice
            oracle, oracle_g, oracle_fx = cmd.decision.levels, cmd.decision.transmission, cmd.decision.exposure
        else:
            oracle, oracle_g, oracle_fx = oracle_choice(camera, spec.resolved.loop.mask, truth, i, spec.attenuator)
        res.stage_seconds["mask"] += time.perf_counter() - tm
        mask = cmd.levels.array                            # mirror grid (cmd.levels carries it)
        enc = camera.capture_command(subs, cmd, i, capture_seed(spec.sensor.seed, spec.render.seed, i, ENCODED_STREAM),
                                     **timing)
    for k in ("dmd", "relay", "sensor"):
        res.stage_seconds[k] += enc.seconds[k]
    if camera.objective is not None:         # formed with the truth; the captures reuse the images
        res.stage_seconds["objective"] = (res.stage_seconds.get("objective", 0.0) + t_obj + ldr.seconds["objective"]
                                          + (enc.seconds["objective"] if enc is not ldr else 0.0))
    tr = time.perf_counter()
    est, flags, _ = camera.reconstruct(enc, i)
    res.stage_seconds["reconstruct"] += time.perf_counter() - tr
    return FrameCapture(ex, camera.to_sensor(truth).astype(np.float32), camera.box_to_sensor(ex.roi),
                        ldr, enc, mask, oracle, est, flags, rec, oracle_g, oracle_fx)


def _metrics(spec, camera: Camera, fc: FrameCapture) -> None:
    """Plate (ROI) and frame metrics of the LDR twin and the encoded capture."""
    max_dn, box = camera.params.max_dn, fc.box
    ldr, enc, valid = fc.ldr.dn, fc.enc.dn, fc.flags == 0
    fc.record["mean_signal_dn_roi"] = float(np.mean(crop(enc, box))) - camera.params.offset_dn
    fc.record.update({
        "saturated_fraction_roi": {"ldr": saturated_fraction(crop(ldr, box), max_dn),
                                   "encoded": saturated_fraction(crop(enc, box), max_dn)},
        "entropy_roi": {"ldr": entropy_8bit(to_8bit(crop(ldr, box), max_dn)),
                        "encoded": entropy_8bit(to_8bit(crop(enc, box), max_dn))},
        "saturated_fraction": {"ldr": saturated_fraction(ldr, max_dn), "encoded": saturated_fraction(enc, max_dn)},
        "recon_rel_error": relative_error(fc.est, fc.truth_s, valid),
        "recon_rel_error_roi": (relative_error(crop(fc.est, box), crop(fc.truth_s, box), crop(valid, box))
                                if box else None),
        "valid_fraction": float(np.mean(valid)),
    })
    if box:
        fc.record["plate_white_fraction"] = {"ldr": plate_white_fraction(to_8bit(ldr, max_dn), box),
                                             "encoded": plate_white_fraction(to_8bit(enc, max_dn), box)}
    if fc.exposure.plates:                  # render.roi_shape = "plates": every plate its own record
        from poevp_optics.apps.run.plates import frame_plates

        fc.record["plates"] = frame_plates(spec, camera, fc.exposure, ldr, enc)


def unclipped_mc_error(camera: Camera, ex: RenderedExposure, capture_dn: np.ndarray) -> dict:
    """The frame's MC error where the camera can see it: over the render grid's field of view
    (guard band excluded), leaving out the mirrors whose sensor pixels are clipped in the capture
    (`capture_dn` >= max DN: full scale whatever the radiance estimate). Returns
    {"rel_error_unclipped": RMS standard error / mean radiance there (None: no MC error, or no
    pixel left), "clipped_fraction": share of the field of view left out, and over the pixels
    left, the median and 90th percentile of each pixel's own relative error
    (progressive.pixel_rel_errors)}."""
    clipped_s = np.asarray(capture_dn) >= camera.params.max_dn - 0.5
    clipped_m = camera.to_mirror(clipped_s.astype(np.float32)) > 0      # bilinear: any touch
    g = camera.guard_px
    h, w = camera.mirror_shape[0] - 2 * g, camera.mirror_shape[1] - 2 * g
    view = np.s_[g:g + h, g:g + w]
    mean, var, clip = ex.radiance.data[view], ex.variance[view], clipped_m[view]
    err, frac = rel_error_unclipped(mean, var, clip)
    if ex.rel_error is None:
        return {"rel_error_unclipped": None, "clipped_fraction": frac}
    med, p90 = pixel_rel_errors(mean, var, clip)
    return {"rel_error_unclipped": err, "clipped_fraction": frac, "rel_error_pixel_median": med,
            "rel_error_pixel_p90": p90}


def _against_oracle(spec, camera: Camera, fc: FrameCapture) -> None:
    """A causal predictor's frame: the oracle mask's capture and the mask's error against it."""
    max_dn, box, i = camera.params.max_dn, fc.box, fc.exposure.index
    subs, timing = capture_inputs(spec, fc.exposure)
    oc = camera.capture(subs, fc.oracle, i, capture_seed(spec.sensor.seed, spec.render.seed, i, ENCODED_STREAM),
                        **timing, transmission=fc.oracle_transmission, exposure=fc.oracle_exposure)
    fc.record["saturated_fraction_roi"]["oracle"] = saturated_fraction(crop(oc.dn, box), max_dn)
    fc.record["entropy_roi"]["oracle"] = entropy_8bit(to_8bit(crop(oc.dn, box), max_dn))
    if not fc.record.get("init"):
        top = camera.top_level
        fc.record["mask_error"] = {"iou": mask_iou(fc.mask, fc.oracle, top),
                                   "mean_abs": float(np.mean(np.abs(fc.mask - fc.oracle)) / top)}


def _law_comparison(spec, camera: Camera, fc: FrameCapture, res: RunResult, causal: bool) -> None:
    """The scene's law beside the paper's Eq. 2 readings (oracle runs, frames after init)."""
    fc.record["mask_mean"] = float(np.mean(fc.mask) / camera.top_level)
    if fc.record.get("init"):
        return
    res.law_comparison["scene_law"]["saturated"].append(fc.record["saturated_fraction_roi"]["encoded"])
    res.law_comparison["scene_law"]["entropy"].append(fc.record["entropy_roi"]["encoded"])
    if spec.mask.law == "white" or causal:
        return
    max_dn, box, i = camera.params.max_dn, fc.box, fc.exposure.index
    subs, timing = capture_inputs(spec, fc.exposure)
    for lname, (law, a, b) in PAPER_LAWS.items():
        ms = MaskSpec(law=law, vs=200.0, a=a, b=b, smooth_px=spec.mask.smooth_px)
        m2 = oracle_mask(camera, ms, camera.dmd_image(fc.exposure.radiance.data), i)
        c2 = camera.capture(subs, m2, i, capture_seed(spec.sensor.seed, spec.render.seed, i, ENCODED_STREAM),
                            **timing)
        res.law_comparison[lname]["saturated"].append(saturated_fraction(crop(c2.dn, box), max_dn))
        res.law_comparison[lname]["entropy"].append(entropy_8bit(to_8bit(crop(c2.dn, box), max_dn)))


def _kept(camera: Camera, fc: FrameCapture) -> dict:
    max_dn, top = camera.params.max_dn, camera.top_level
    return {"ldr": to_8bit(fc.ldr.dn, max_dn).astype(np.uint8), "capture": to_8bit(fc.enc.dn, max_dn).astype(np.uint8),
            "mask": mask_png(fc.mask, top) if fc.mask is not None else None,
            "oracle_mask": mask_png(fc.oracle, top) if fc.oracle is not None else None, "roi": fc.box}


def _render_effort(ex) -> dict:
    """The spp each radiance sample of the frame used, and whether the error target was met."""
    return {"spp": list(ex.spp), "target_met": ex.target_met}


class BackgroundWriter:
    """A frame's files written on one background thread while the loop goes on to the next
    frame (render, captures, prediction): at most one frame waits to be written, and the loop
    waits for it before handing over the next. The writer's work is NumPy, OpenCV and OpenEXR
    calls that release the GIL, and the render leaves the CPUs idle between its kernels, so
    most of the writing hides behind the next frame. The files are the same bytes as written in
    line (the writer reads only its own frame's arrays, which nothing changes after the loop's
    step). An error in the writer is raised in the loop, at the next hand-over or at `close`;
    `close` waits for the last write, so the staging folder is never removed under it.
    Measured on the default scene (1920x1080, 21 frames, warm cache, 2 cores): 115.3 s against
    126.7 s written in line, the same files, peak resident memory 2573 against 2548 MiB."""

    #: write in the loop's own thread (benchmarks/render_cost.py: its stage clocks read the
    #: process CPU time, which would count the loop's work in the writer's time as well)
    in_line = False

    def __init__(self, writer: OutputWriter, res: RunResult):
        from concurrent.futures import ThreadPoolExecutor

        self.writer, self.res = writer, res
        self.pool = ThreadPoolExecutor(1, thread_name_prefix="poevp-writer")
        self.pending = None

    def _write(self, fc: FrameCapture) -> float:
        t = time.perf_counter()
        self.writer.frame(fc)
        return time.perf_counter() - t

    def submit(self, fc: FrameCapture) -> None:
        if self.in_line:
            self.res.write_seconds += self._write(fc)
            return
        self.wait()
        self.pending = self.pool.submit(self._write, fc)

    def wait(self) -> None:
        """Wait for the frame being written; its error, if any, raised here."""
        if self.pending is None:
            return
        t = time.perf_counter()
        try:
            self.res.write_seconds += self.pending.result()
        finally:
            self.pending = None
            self.res.write_wait_seconds += time.perf_counter() - t

    def close(self, quiet: bool = False) -> None:
        """Wait for the last write and end the thread; quiet: the loop failed, and its own error,
        not the writer's, is the one to report."""
        try:
            self.wait()
        except Exception:
            if not quiet:
                raise
        finally:
            self.pool.shutdown(wait=True)


def simulate(spec, camera: Camera, step: LoopStep | None, exposures, *, writer: OutputWriter | None = None,
             keep_frames: tuple[int, ...] = ()) -> RunResult:
    """The frame loop: capture, reconstruct, loop step, metrics, outputs (module docstring); the
    outputs written on a thread of their own (`BackgroundWriter`), all written when it returns."""
    res = RunResult()
    background = BackgroundWriter(writer, res) if writer is not None else None
    try:
        _frames(spec, camera, step, exposures, res, background, keep_frames)
    except BaseException:
        if background is not None:
            background.close(quiet=True)
        raise
    if background is not None:
        background.close()
    return res


def _frames(spec, camera: Camera, step: LoopStep | None, exposures, res: RunResult,
            background: BackgroundWriter | None, keep_frames: tuple[int, ...]) -> None:
    mid = spec.timing.frames // 2
    causal = step is not None and not step.needs_truth
    extensions = res.extensions = report_extensions(spec, causal)
    for ex in exposures:
        fc = capture_frame(spec, camera, step, ex, res)                 # render -> capture -> reconstruct
        if ex.index == mid and not ex.basis and not spec.is_static:
            res.mid_frame = (ex, fc.mask)
        _metrics(spec, camera, fc)
        fc.record.update(unclipped_mc_error(camera, ex, fc.enc.dn))
        _extension_records(extensions, spec, camera, fc, step, after_observe=False)
        if causal:
            step.observe(ex.index, fc.ldr, fc.enc, fc.est, fc.flags)   # the loop's step
        _extension_records(extensions, spec, camera, fc, step, after_observe=True)
        if causal:
            _against_oracle(spec, camera, fc)
        if camera.dmd:
            _law_comparison(spec, camera, fc, res, causal)
        if ex.index in keep_frames:
            res.kept[ex.index] = _kept(camera, fc)
        res.per_frame.append(_frame_record(ex, fc, written=background is not None))
        if background is not None:
            background.submit(fc)


def _extension_records(extensions, spec, camera: Camera, fc: FrameCapture, step, *, after_observe: bool) -> None:
    """The report plug-ins' per-frame entries (report_extensions.py), before or after the loop
    observes the frame."""
    for ext, state in extensions:
        if ext.frame is not None and ext.after_observe == after_observe:
            fc.record[ext.key] = ext.frame(spec, camera, fc, step, state)


def _frame_record(ex: RenderedExposure, fc: FrameCapture, *, written: bool) -> dict:
    """The frame's report.json entry: the loop's record, the ROI and the render's MC error and
    effort; a run that writes images also records its timing and radiance range."""
    box = fc.box
    truth = {"ground_truth": ex.ground_truth} if ex.ground_truth else {}
    if not written:
        return {**fc.record, "roi": list(box) if box else None, "rel_error": ex.rel_error,
                "rel_error_roi": ex.rel_error_roi, **truth, **_render_effort(ex)}
    fc.record.update({"t_start_s": ex.t_start_s, "exposure_s": ex.exposure_s,
                      "subframe_times_s": ex.subframe_times_s, "roi": list(box) if box else None,
                      "radiance_mean": float(np.mean(fc.truth_s)), "radiance_max": float(np.max(fc.truth_s)),
                      "radiance_min": float(np.min(fc.truth_s)),
                      "roi_radiance_mean": float(np.mean(crop(fc.truth_s, box))) if box else None,
                      "rel_error": ex.rel_error, "rel_error_roi": ex.rel_error_roi, **truth,
                      **_render_effort(ex)})
    return fc.record


def loop_step_of(spec, camera: Camera) -> LoopStep | None:
    """The scene's closed loop (None without a DMD); weights errors name the scene's key."""
    if camera.dmd is None:
        return None
    from poevp_optics.core.weights import WeightsError

    try:
        return LoopStep.from_params(camera, spec.resolved.loop)
    except WeightsError as e:
        raise SceneError(f"{spec.toml_path}: predictor.weights: {e}") from None


def run_frames(spec, out_dir: Path, progress: bool = True, *, renderer=None,
               exposures: list | None = None, write_images: bool = True,
               keep_frames: tuple[int, ...] = (), render_cache=None) -> tuple[dict, dict]:
    """Render (or read: [source]) `spec` and run the camera into `out_dir` (an empty staging
    folder); return (report, kept frames). renderer/exposures: reuse an opened source
    (render/radiance.py open_source) and its exposures (the comparison runs many camera loops
    over one render; its guard band must be the camera's).
    write_images=False writes only report.json. keep_frames: frame indices whose masks and
    captures come back in the second value. render_cache: a render/render_cache.py RenderCache
    (a sweep's): the exposures of a stored identical render are replayed, or this run's render
    is stored for the next run with the same render inputs."""
    out_dir = Path(out_dir)
    t_run = time.perf_counter()
    camera = Camera.from_params(spec.resolved.camera)
    if render_cache is not None and renderer is None and exposures is None:
        renderer = render_cache.open(spec.resolved.render, camera.guard_px)   # stored or recorded
    renderer = renderer or open_source(spec.resolved.render, camera.guard_px)       # the scene's [source] kind
    if renderer.guard_px != camera.guard_px:
        raise ValueError(f"renderer guard band {renderer.guard_px} px != camera's {camera.guard_px} px")
    step = loop_step_of(spec, camera)
    setup_s = time.perf_counter() - t_run
    writer = OutputWriter(spec, camera, renderer, out_dir) if write_images else None
    frames = exposures if exposures is not None else renderer.exposures(progress)
    ahead = None
    timed = step is not None and step.clock is not None and step.clock.spec.compute == "measured"
    if exposures is None and RenderAhead.wanted() and not timed:   # a measured budget times the loop alone
        ahead = frames = RenderAhead(frames)          # the next frame renders while the camera runs this one
    try:
        res = simulate(spec, camera, step, frames, writer=writer, keep_frames=keep_frames)
    finally:
        if ahead is not None:
            ahead.close()
    if ahead is not None:
        res.render_wait_seconds = ahead.wait_seconds
    if writer is not None:
        writer.finish()
        if step is not None and step.clock is not None and step.clock.records:
            from poevp_optics.apps.run.timeline import write_timeline

            res.timeline = write_timeline(out_dir, spec.timing, step.clock, camera.schedule,
                                          spec.loop.init_frames, spec.timing.frames,
                                          spec.attenuator.settle_s if spec.attenuator.enabled else None).name
    if exposures is not None:
        temporal = {"rel": None, "method": "not estimated: this run reuses a shared render", "seconds": 0.0}
    elif renderer.temporal_skip:
        temporal = {"rel": None, "method": renderer.temporal_skip, "seconds": 0.0}
    else:
        temporal = temporal_error(spec, renderer, camera, *(res.mid_frame or (None, None)))
    if render_cache is not None:
        render_cache.finish()
    report = build_report(spec, renderer, camera, step, res, setup_s=setup_s, t_run=t_run, temporal=temporal)
    if render_cache is not None:
        report["render_reuse"] = render_cache.report_section()
    if spec.resolved.derived:          # values the scene computed from other keys (scene/resolve.py)
        report["derived"] = dict(spec.resolved.derived)
    if spec.defaults_applied:          # the best loop the scene did not choose (scene/defaults.py)
        report["defaults_applied"] = list(spec.defaults_applied)
        report["notes"].append("defaults applied (the scene chose no mask law / loop mode / predictor): "
                               + ", ".join(spec.defaults_applied))
    for ext, _ in res.extensions:
        if ext.finish is not None:
            ext.finish(spec, camera, report, out_dir, write_images)
    write_report(out_dir, report)
    if write_images:
        from poevp_optics.apps.run.report_html import write_report_html

        write_report_html(out_dir, report, spec.plate.text)
        if (report.get("metrics") or {}).get("plates"):
            from poevp_optics.apps.run.plates import write_plates_markdown

            write_plates_markdown(out_dir, report)
    return report, res.kept


def run_render(spec, out_dir: Path, progress: bool = True, **kw) -> dict:
    """`run_frames` without the kept frames: the report."""
    return run_frames(spec, out_dir, progress, **kw)[0]
