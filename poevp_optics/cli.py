"""`poevp` command line: render, validate, compare, chart, sweep, evaluate, train-predictor, info.

Exit status: 0 done; 1 a sweep finished with failed points (`--allow-failed`: 0); 2 bad input
(one line on stderr naming the file and key, or the flag; nothing written); 130 Ctrl-C; 143
SIGTERM (both: a message, partial output removed, earlier outputs untouched).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from pathlib import Path

from poevp_optics import __version__
from poevp_optics.core import runtime
from poevp_optics.core.exceptions import UserError


class _OneLineParser(argparse.ArgumentParser):
    """Argument errors as one line (`poevp: error: argument --threads: ...`), exit 2."""

    def error(self, message):
        self.exit(2, f"poevp: error: {' '.join(message.split())}\n")


def _int_at_least(low: int):
    """An argparse type: an integer >= low, else a one-line argument error."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < low:
            raise argparse.ArgumentTypeError(f"expected an integer >= {low}, got {text!r}")
        return value
    return parse


_positive_int = _int_at_least(1)
_count = _int_at_least(0)


def _resolution_override(text: str) -> str:
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected HxW, e.g. 368x640, got {text!r}") from None
    return f"render.resolution=[{h},{w}]"


class _Override(argparse.Action):
    """`--set KEY=VALUE` and the shorthands (--frames, --spp, --resolution, --seed) become
    `section.key=value` overrides in the order given, so the last one given wins."""

    def __init__(self, option_strings, dest, key=None, **kwargs):
        self.key = key
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        text = values if self.key is None else self.key(values)
        setattr(namespace, self.dest, [*(getattr(namespace, self.dest, None) or []), text])


def _add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="scene folder (holding scene.toml) or a .toml file")
    p.set_defaults(overrides=[])
    p.add_argument("--set", dest="overrides", action=_Override, metavar="KEY=VALUE",
                   help="override a scene key, TOML value syntax (repeatable; applied in order): render.spp=64")
    p.add_argument("--frames", dest="overrides", action=_Override, type=int, metavar="N",
                   key=lambda v: f"timing.frames={v}", help="shorthand for --set timing.frames=N")
    p.add_argument("--spp", dest="overrides", action=_Override, type=int, metavar="N",
                   key=lambda v: f"render.spp={v}", help="shorthand for --set render.spp=N")
    p.add_argument("--resolution", dest="overrides", action=_Override, type=_resolution_override,
                   metavar="HxW", key=lambda v: v, help="shorthand for --set render.resolution=[H,W]")
    p.add_argument("--seed", dest="overrides", action=_Override, type=int, metavar="S",
                   key=lambda v: f"render.seed={v}", help="shorthand for --set render.seed=S")
    p.add_argument("--accuracy", choices=("fast", "default", "reference"), default="default",
                   help="spp, MC error target, sub-frames and PSF support together, applied after "
                        "every --set (fast: 5 %% target within the scene's spp, K/2; reference: "
                        "0.5 %% target within 64x spp, 4x K)")


def _add_job_options(p: argparse.ArgumentParser, out_help: str) -> None:
    p.add_argument("--out", help=out_help)
    p.add_argument("--threads", type=_positive_int, help="DrJit/torch/OpenCV threads (default: all cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _overrides(args) -> list[str]:
    from poevp_optics.core.exceptions import SceneError
    from poevp_optics.scene.load import accuracy_overrides, parse_override
    out = list(args.overrides)
    preset = getattr(args, "accuracy", "default")
    if preset != "default":
        added = accuracy_overrides(args.scene, out, preset)
        set_keys = {".".join(parse_override(o)[0]): o for o in out}
        for a in added:
            key = a.split("=", 1)[0]
            if key == "relay.support_energy" and key in set_keys:
                raise SceneError(f"--accuracy {preset} sets {key}, and so does --set {set_keys[key]}: "
                                 "give one of them")
        out += added
    return out


def cmd_render(args) -> int:
    from poevp_optics.apps.runner import run_job

    spec, out, report = run_job("render", args.scene, _overrides(args), out=args.out, threads=args.threads,
                                progress=not args.quiet)
    r = report["stages"]["render"]
    frame, roi = r["rel_error"], r["rel_error_roi"]
    print(f"poevp: rendered {report['frames']} frames of {spec.name} at "
          f"{report['resolution'][0]}x{report['resolution'][1]} ({r['path']}, {r['variant']}) in "
          f"{report['total_seconds']:.1f} s; MC rel. error "
          + (f"{frame:.2%} frame" if frame is not None else
             "- (black frame)" if spec.source.renders else f"- (radiance from [source] {spec.source.kind})")
          + (f", {roi:.2%} ROI" if roi is not None else "") + _target_line(r) + f" -> {out}/report.json")
    return 0


def _target_line(r: dict) -> str:
    """' (target 1.00 %: met, 16-64 spp)' for an error-targeted render, else ''."""
    if not r.get("target"):
        return ""
    used = r.get("spp_used") or {}
    met = "met" if r.get("met") else r.get("note", "not met")
    return f" (target {r['target']:.2%}: {met}; {used.get('min')}-{used.get('max')} spp)"


def cmd_validate(args) -> int:
    from poevp_optics.apps.memory import fits_note
    from poevp_optics.apps.preflight import check_run
    from poevp_optics.scene.load import load_scene
    spec = load_scene(args.scene, _overrides(args))
    job = args.job or ("chart" if spec.chart.patches else "render")
    pf = check_run(spec, job, load=args.load)
    plan = pf.plan
    if not spec.source.renders:
        what = f"source {plan.mode}: {plan.reason}" + "".join(f"; note: {n}" for n in plan.notes)
    else:
        what = (f"spp {spec.render.spp}, "
                f"{'static' if spec.is_static else ('PWM lamps on static geometry: ' + ', '.join(spec.flicker)) if spec.geometry_static else 'moving: ' + ', '.join(spec.motion)}; "
                f"render path {plan.mode} ({plan.reason})")
    print(f"poevp: {spec.toml_path} is valid for `poevp {job}`: {spec.timing.frames} frames, "
          f"{spec.render.resolution[0]}x{spec.render.resolution[1]}, {what}; {fits_note(pf.memory)}")
    return 0


def cmd_compare(args) -> int:
    from poevp_optics.apps.runner import run_job
    from poevp_optics.control.loop_step import LOOP_MODES
    from poevp_optics.control.predictors import PREDICTORS
    from poevp_optics.core.exceptions import SceneError

    preds = [p.strip() for p in args.predictors.split(",") if p.strip()]
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    for m in modes:
        if m not in LOOP_MODES:
            raise SceneError(f"--modes {args.modes}: unknown loop mode {m!r} ({', '.join(LOOP_MODES)})")
    for p in preds:
        if p not in PREDICTORS:
            raise SceneError(f"--predictors {args.predictors}: unknown predictor {p!r} ({', '.join(PREDICTORS)})")
    if not preds or not modes:
        raise SceneError("--predictors/--modes: give at least one of each")
    _, out, rows = run_job("compare", args.scene, _overrides(args), out=args.out, threads=args.threads,
                           progress=not args.quiet, check={"predictors": tuple(preds)},
                           predictors=preds, modes=modes)
    for r in rows:
        print(f"{r['predictor']:>11s} {r['mode']:>12s}  mask IoU {_f(r['mask_iou'])}  plate saturated "
              f"{_f(r['sat_loop_after_init'])} (LDR {_f(r['sat_ldr'])})  entropy {_f(r['entropy_loop_after_init'])}")
    print(f"poevp: comparison -> {out}/comparison.md")
    return 0


def _f(v):
    return "-" if v is None else f"{v:.3f}"


def cmd_chart(args) -> int:
    from poevp_optics.apps.runner import run_job

    spec, out, r = run_job("chart", args.scene, _overrides(args), out=args.out, threads=args.threads,
                           progress=not args.quiet)
    dr = r["dynamic_range_db"]
    line = "  ".join(f"{mode} {dr[mode]['iso15739']:.1f} dB" for mode in dr if dr[mode].get("iso15739") is not None)
    print(f"poevp: {spec.name} ISO 15739 DR: {line} (EMVA sensor {dr['ldr']['emva']:.1f} dB)")
    if "limits" in r:
        print(f"poevp: {r['limits']['explanation']}")
    if "reference_camera" in r:
        c = r["reference_camera"]["comparison"]
        enc = c["encoded"]["simulated"]
        print(f"poevp: with {r['reference_camera']['scene']}'s camera: LDR {c['ldr']['simulated']:.1f} dB "
              f"(paper {c['ldr']['paper']}), encoded {'-' if enc is None else f'{enc:.1f}'} dB "
              f"(paper {c['encoded']['paper']})")
    print(f"poevp: chart done in {r['total_seconds']:.1f} s -> {out}/report.json")
    return 0


def cmd_sweep(args) -> int:
    from poevp_optics.apps.runner import reads
    from poevp_optics.core.io import check_output
    from poevp_optics.scene.load import load_scene
    from poevp_optics.apps.sweep import sweep

    spec = load_scene(args.scene, _overrides(args), cross_checks=False)
    out = Path(args.out) if args.out else Path("out") / f"{spec.name}-sweep"
    check_output(out, "sweep", protect=reads(spec))
    df = sweep(args.scene, args.grid, out=out, seeds=args.seeds, workers=args.workers,
               scheduler=args.scheduler, scheduler_file=args.scheduler_file, shared_fs=args.shared_fs,
               retries=args.retries, job=args.job, base_overrides=_overrides(args),
               metric=args.plot, progress=not args.quiet, retry_failed=args.retry_failed,
               threads=args.threads)
    n_failed = 0
    if df is not None:
        n_ok = int((df["status"] == "ok").sum())
        n_failed = len(df) - n_ok
        print(f"poevp: sweep table {out}/results.parquet: {n_ok} ok, {n_failed} failed")
        for _, r in df[df["status"] == "failed"].iterrows():
            print(f"poevp:   failed point {r['point']} seed {r['seed']}: {r['error']}")
    if n_failed and not args.allow_failed:
        print(f"poevp: {n_failed} sweep points failed (exit 1; --allow-failed exits 0; "
              "--retry-failed runs them again)", file=sys.stderr)
        return 1
    return 0


def _csv_numbers(flag: str, text: str | None):
    if text is None:
        return None
    try:
        return tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise UserError(f"evaluate: {flag}: {text!r} is not a comma-separated list of numbers") from None


def _eval_config(args):
    """The evaluation's configuration from the command line (defaults: EvalConfig, --quick: CI set)."""
    import dataclasses

    from poevp_optics.apps.evaluate import BASE, EvalConfig, quick_config
    from poevp_optics.scene.load import resolve_scene_path

    scene = resolve_scene_path(args.scene) if args.scene else BASE
    cfg = quick_config(scene) if args.quick else EvalConfig(scene=scene)
    texts = [t.strip() for t in args.texts.split(",")] if args.texts else None
    if args.texts_file:
        f = Path(args.texts_file)
        if not f.is_file():
            raise UserError(f"{f}: --texts-file: no such file")
        texts = [ln.strip() for ln in f.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    new = {"texts": tuple(texts) if texts is not None else None,
           "speeds_px": _csv_numbers("--speeds", args.speeds), "e_levels": _csv_numbers("--E", args.E),
           "e_sweep": _csv_numbers("--E-sweep", args.E_sweep),
           "kinds": tuple(args.kinds.split(",")) if args.kinds else None,
           "predictors": tuple(args.predictors.split(",")) if args.predictors else None,
           "baselines": tuple(b for b in args.baselines.split(",") if b) if args.baselines is not None else None,
           "search": args.search, "loop_mode": args.loop_mode, "e_reading": args.e_reading,
           "paper_law": args.paper_law}
    return dataclasses.replace(cfg, **{k: v for k, v in new.items() if v is not None})


def cmd_evaluate(args) -> int:
    from poevp_optics.apps.evaluate import check_config, evaluate
    from poevp_optics.apps.runner import run_in_folder

    cfg = _eval_config(args)
    check_config(cfg)
    out = Path(args.out) if args.out else Path("out") / ("evaluate-quick" if args.quick else "evaluate")
    log = (lambda *a: None) if args.quiet else print
    report = run_in_folder("evaluate", out, args.threads, lambda stage: evaluate(stage, cfg, log=log))
    for e, v in report["findings"]["separating_speed_px"].items():
        print(f"poevp: E = {e}: " + (f"hold < 50 % while flow/dmvfn > 80 % from {v:g} px/frame" if v is not None
                                      else "no separating speed in the sweep"))
    print(f"poevp: evaluation -> {out}/evaluation.md")
    return 0


def _data_config(args):
    """apps/train_data.py DataConfig from the train-data / train-predictor flags."""
    from poevp_optics.apps.train_data import DataConfig

    kw = {}
    if args.sequences:
        try:
            n = [int(v) for v in str(args.sequences).split(",")]
            if len(n) not in (1, 3):
                raise ValueError
        except ValueError:
            raise UserError(f"--sequences {args.sequences}: N or TRAIN,VAL,TEST (integers)") from None
        kw["sequences"] = tuple(n) if len(n) == 3 else (n[0], max(1, n[0] // 4), max(1, n[0] // 4))
    if args.frames:
        kw["frames"] = args.frames
    if args.resolution:
        h, _, w = args.resolution.lower().partition("x")
        if not (h.isdigit() and w.isdigit()):
            raise UserError(f"--resolution {args.resolution}: HxW in pixels, e.g. 184x320")
        kw["resolution"] = (int(h), int(w))
    if args.spp:
        kw["spp"] = args.spp
    kw["seed"] = args.data_seed
    return DataConfig(**kw)


def _command_line(cmd: str, args) -> str:
    """The command as parsed (every option given or defaulted): reruns the same training."""
    skip = {"func", "scene", "command"} | ({"minutes", "val_sequences"} if getattr(args, "name", "") == "track_net" else set())
    opts = [f"--{k.replace('_', '-')}" + ("" if v is True else f" {v}") for k, v in sorted(vars(args).items())
            if k not in skip and v not in (None, False)]
    return " ".join(["poevp", cmd, str(args.scene or ""), *opts]).replace("  ", " ")


def _data_cluster(args):
    from poevp_optics.apps.train_data import Cluster

    return Cluster(args.scheduler, args.scheduler_file, args.shared_fs, args.retries, args.threads)


def cmd_train_data(args) -> int:
    import time

    from poevp_optics.apps.train_data import build_data

    runtime.set_threads(args.threads)
    t0 = time.perf_counter()
    data = build_data(args.scene, _data_config(args), cluster=_data_cluster(args), progress=not args.quiet)
    m = data.manifest
    print(f"poevp train-data: {args.scene}: {', '.join(f'{s} {n}' for s, n in m['split']['sequences'].items())} "
          f"sequences, sha256 {data.sha256[:16]}, {'rendered' if data.rendered else 'from the cache'} "
          f"({time.perf_counter() - t0:.0f} s now; rendering took {m['timing']['render_seconds']:.0f} s) -> {data.folder}")
    return 0


def cmd_train(args) -> int:
    from poevp_optics.control.predictors.dmvfn import default_weights

    runtime.set_threads(args.threads)
    if args.data_only:
        if not args.scene:
            raise UserError("train-predictor --data-only: name the SCENE whose data to build")
        return cmd_train_data(args)
    if args.name == "track_net":
        import time

        from poevp_optics.apps.train_track import train_track_net_scene

        scene = args.scene or "highbeam_plate"
        weights = Path(args.weights_out) if args.weights_out else Path(args.out) / f"track_net_{Path(scene).name}.safetensors"
        if weights.resolve() == (Path(__file__).resolve().parents[1] / "assets/predictor/track_net.safetensors"):
            raise UserError(f"--weights-out {weights}: the shipped track_net weights come from "
                            "apps/train_track.py; write a scene-trained model elsewhere")
        t0 = time.perf_counter()
        rec = train_track_net_scene(scene, _data_config(args), steps=args.max_steps or 3000,
                                    batch=args.batch or 128, lr=args.lr or 3e-3, seed=args.seed,
                                    device=args.device, checkpoint_dir=Path(args.out) / f"track_net_{Path(scene).name}",
                                    resume=args.resume, checkpoint_every=args.checkpoint_every,
                                    weights_out=weights, cluster=_data_cluster(args), progress=not args.quiet,
                                    command=_command_line("train-predictor", args))
        b, t = rec["budget"], rec["test"].get("all", {})
        print(f"poevp: trained track_net on {scene} for {b['steps']} steps ({b['epochs']:.0f} epochs, "
              f"{b['train_seconds']:.0f} s training, {b['data_seconds']:.0f} s data, device {b['device']}); "
              f"held-out median centroid error {t.get('track_net', float('nan')):.2f} px "
              f"(constant velocity {t.get('constant_velocity', float('nan')):.2f}, track "
              f"{t.get('track', float('nan')):.2f}; n = {t.get('n', 0)}) -> {weights} "
              f"({time.perf_counter() - t0:.0f} s in all)")
        return 0
    from poevp_optics.apps.train import train

    weights = Path(args.weights_out) if args.weights_out else default_weights(args.name)
    frames_data, source = None, None
    if args.scene:
        from poevp_optics.apps.train_data import build_data

        data = build_data(args.scene, _data_config(args), cluster=_data_cluster(args), progress=not args.quiet)
        frames_data = (data.splits["train"]["frames"], data.splits["val"]["frames"])
        source = f"{data.manifest['scene']} (apps/train_data.py, sha256 {data.sha256})"
    rec = train(args.name, minutes=args.minutes, sequences=int(str(args.sequences or 48).split(",")[0]),
                frames=args.frames or 6, val_sequences=args.val_sequences, batch=args.batch or 4,
                lr=args.lr or 2e-3, seed=args.seed, out=Path(args.out), weights_out=weights,
                max_steps=args.max_steps, frames_data=frames_data, device=args.device, source=source)
    v = rec["validation"]
    print(f"poevp: trained {args.name} for {rec['steps']} steps ({rec['train_seconds']:.0f} s); "
          f"validation highlight IoU {v['model']['highlight_iou']:.3f} (hold {v['hold']['highlight_iou']:.3f}, "
          f"flow {v['flow']['highlight_iou']:.3f}), PSNR {v['model']['psnr_db']:.2f} dB -> {weights}")
    return 0


def info_dict() -> dict:
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    out = {"poevp_optics": __version__, "python": platform.python_version(),
           "mitsuba": mi.__version__, "drjit": dr.__version__, "numpy": np.__version__}
    for mod in ("torch", "OpenEXR", "colour", "colour_hdri", "cv2"):
        try:
            out[mod] = __import__(mod).__version__
        except Exception as e:  # noqa: BLE001
            out[mod] = f"unavailable ({type(e).__name__})"
    out["cuda_available"] = runtime.backend_available("cuda")
    out["llvm_available"] = runtime.backend_available("llvm")
    out["variant_spectral"] = runtime.choose_variant("spectral")[0]
    out["variant_mono"] = runtime.choose_variant("mono")[0]
    out["DRJIT_LIBLLVM_PATH"] = os.environ.get("DRJIT_LIBLLVM_PATH")
    out["libllvm_loaded"] = runtime.libllvm_in_use()
    out["drjit_threads"] = dr.thread_count()
    out["cpu_count"] = os.cpu_count()
    return out


def cmd_info(args) -> int:
    info = info_dict()
    if args.json:
        print(json.dumps(info, indent=2))
    elif args.short:
        print(f"poevp_optics {info['poevp_optics']}: mitsuba {info['mitsuba']} "
              f"({info['variant_spectral']}), libLLVM {info['libllvm_loaded']}, torch {info['torch']}")
    else:
        for k, v in info.items():
            print(f"{k:20s} {v}")
    return 0


def _add_cluster_options(p) -> None:
    """`poevp sweep` on an existing Dask cluster (apps/cluster.py, apps/bundle.py)."""
    where = p.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS", help="tcp://HOST:PORT of an existing Dask scheduler")
    where.add_argument("--scheduler-file", metavar="PATH",
                       help="JSON file naming an existing Dask scheduler (as `dask scheduler "
                            "--scheduler-file` and dask-jobqueue write)")
    p.add_argument("--shared-fs", action="store_true",
                   help="workers read this machine's paths (a shared file system; verified on each "
                        "worker) instead of receiving the scene bundle")
    p.add_argument("--retries", type=_count, default=2, metavar="N",
                   help="run a point whose worker died again up to N times before it is a failed row "
                        "(default 2)")


def _add_train_data_options(p) -> None:
    """train-data / train-predictor: what to render (apps/train_data.py DataConfig) and where."""
    p.add_argument("--sequences", help="N train sequences (val, test N/4 each) or TRAIN,VAL,TEST "
                   "(default 96,24,24 for a scene: about 4 min of rendering for highbeam_plate, 8 for night_road on 2 cores; dmvfn without SCENE: 48)")
    p.add_argument("--frames", type=_positive_int, help="frames per sequence (default 8; dmvfn without SCENE 6)")
    p.add_argument("--resolution", help="HxW training resolution (default 184x320)")
    p.add_argument("--spp", type=_positive_int, help="samples per pixel (default 4)")
    p.add_argument("--data-seed", type=int, default=0, help="the data's seed streams")
    p.add_argument("--threads", type=_positive_int)
    p.add_argument("--quiet", action="store_true")
    _add_cluster_options(p)


def _add_train_parsers(sub) -> None:
    """`poevp train-predictor` and `poevp train-data` (apps/train_track.py, train.py, train_data.py)."""
    p = sub.add_parser("train-predictor", help="train track_net, dmvfn_lite or dmvfn on sequences rendered from a scene")
    p.add_argument("scene", nargs="?", help="scene whose renders to train on (apps/train_data.py); default: "
                   "highbeam_plate (track_net) or the procedural highbeam_plate set (dmvfn)")
    p.add_argument("--name", default="dmvfn_lite", choices=("dmvfn_lite", "dmvfn", "track_net"))
    p.add_argument("--minutes", type=float, default=10.0, help="dmvfn: training time budget")
    p.add_argument("--val-sequences", type=_positive_int, default=8, help="dmvfn without SCENE")
    p.add_argument("--batch", type=_positive_int, help="default 128 (track_net), 4 (dmvfn)")
    p.add_argument("--lr", type=float, help="default 3e-3 (track_net), 2e-3 (dmvfn)")
    p.add_argument("--seed", type=int, default=0, help="weights' init and batches")
    p.add_argument("--max-steps", type=_positive_int, help="track_net: steps (default 3000)")
    p.add_argument("--out", default="out/train", help="checkpoints (resumable); track_net's weights")
    p.add_argument("--weights-out", help="default: out/train/track_net_<scene>.safetensors (track_net), "
                   "assets/predictor/<name>.safetensors (dmvfn)")
    p.add_argument("--resume", action="store_true", help="continue from the checkpoint in --out (same run only)")
    p.add_argument("--checkpoint-every", type=_positive_int, default=500, help="track_net: steps between checkpoints")
    p.add_argument("--device", default="auto", choices=("cpu", "cuda", "auto"),
                   help="auto: cuda when torch.cuda.is_available()")
    p.add_argument("--data-only", action="store_true", help="build the data (as train-data) and stop")
    _add_train_data_options(p)
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("train-data", help="render a scene's predictor training data (cached by content)")
    p.add_argument("scene")
    _add_train_data_options(p)
    p.set_defaults(func=cmd_train_data)


def _add_evaluate_parser(sub) -> None:
    """`poevp evaluate`'s flags (apps/evaluate.py EvalConfig holds the defaults)."""
    p = sub.add_parser("evaluate", help="plate recognition (full ALPR) over speed, E and motion: LDR vs fusion vs POE-VP")
    p.add_argument("scene", nargs="?", help="a scene with a plate (render.roi_shape); default highbeam_plate")
    p.add_argument("--quick", action="store_true", help="CI size: 1 text, 2 speeds, E = 49 (about a minute)")
    p.add_argument("--texts", help="comma-separated plate texts (default: 4 held-out texts)")
    p.add_argument("--texts-file", help="plate texts, one a line")
    p.add_argument("--speeds", help="lateral speeds, px/frame, comma-separated (default 4,8,16,20,24,28,32,40,48)")
    p.add_argument("--E", help="over-exposure rates of the speed sweep (default 9,49)")
    p.add_argument("--E-sweep", dest="E_sweep", help="over-exposure rates of the accuracy-vs-E sweep")
    p.add_argument("--kinds", help="motion kinds: lateral,approaching,receding,swerve,reversal")
    p.add_argument("--predictors", help="any of poevp_optics.control.predictors.PREDICTORS (default hold,flow,dmvfn_lite,track_net,oracle)")
    p.add_argument("--baselines", help="ldr,fusion_classic,fusion_deghost (default all; '' for none)")
    p.add_argument("--search", choices=("frame", "vehicle"), help="ALPR search region (default frame)")
    p.add_argument("--paper-law", dest="paper_law",
                   choices=("threshold_ratio", "threshold_exp", "threshold_linear", "exposure_controller", "target"),
                   help="ldr_highlight scenes: Eq. 2's reading (default threshold_ratio) or one of ours")
    p.add_argument("--e-reading", dest="e_reading", choices=("display", "linear"),
                   help="E -> plate peak: display (paper Sec. 4.A, 8-bit values x (E+1), default) or linear")
    p.add_argument("--loop-mode", dest="loop_mode", choices=("open", "raw", "demodulated"),
                   help="what the predictor sees (default demodulated; open: paper Fig. 3)")
    _add_job_options(p, "default out/evaluate")
    p.set_defaults(func=cmd_evaluate)


def build_parser() -> argparse.ArgumentParser:
    from poevp_optics.apps.runner import JOBS, sweep_jobs

    parser = _OneLineParser(prog="poevp", description="POE-VP DMD camera simulator")
    parser.add_argument("--version", action="version", version=f"poevp_optics {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("render", help="render a scene: radiance frames, previews, report.json")
    _add_run_options(p)
    _add_job_options(p, "output folder (default out/<scene>); replaced whole on success")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("validate", help="every check a run makes, short of rendering")
    _add_run_options(p)
    p.add_argument("--job", choices=JOBS.names(),
                   help="check the scene for this command (default: chart for a [chart] scene, else render)")
    p.add_argument("--load", action="store_true", help="also load the XML in Mitsuba")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("compare", help="one render, several predictors x loop modes: table + figure")
    _add_run_options(p)
    p.add_argument("--predictors", default="oracle,hold,flow,dmvfn", help="comma-separated names")
    p.add_argument("--modes", default="open,raw,demodulated", help="comma-separated loop modes")
    _add_job_options(p, "default out/<scene>-compare")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("chart", help="dynamic range on a rendered DR test chart (ISO 15739, EMVA)")
    _add_run_options(p)
    _add_job_options(p, "default out/<scene>-chart")
    p.set_defaults(func=cmd_chart)

    p = sub.add_parser("sweep", help="grid of scene variations on Dask: table, plots; resumable")
    _add_run_options(p)
    p.add_argument("--grid", action="append", default=[], required=True,
                   help="KEY=v1,v2,... | KEY=start:stop:num | KEY=log:start:stop:num (repeatable)")
    p.add_argument("--seeds", type=_positive_int, default=1, help="seeds per point (render.seed, sensor.seed)")
    p.add_argument("--out", help="default out/<scene>-sweep; rerunning the same sweep resumes")
    p.add_argument("--workers", type=_positive_int, help="local Dask worker processes (default: cores)")
    _add_cluster_options(p)
    p.add_argument("--job", default="render", choices=sweep_jobs())
    p.add_argument("--plot", metavar="METRIC", help="column to plot, e.g. metrics.saturated_fraction_roi.encoded")
    p.add_argument("--retry-failed", action="store_true", help="rerun points recorded as failed")
    p.add_argument("--allow-failed", action="store_true",
                   help="exit 0 even when points failed (default: exit 1)")
    p.add_argument("--threads", type=_positive_int,
                   help="DrJit/torch/OpenCV threads per worker (default cores // workers)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_sweep)

    _add_evaluate_parser(sub)

    _add_train_parsers(sub)

    p = sub.add_parser("info", help="versions, Mitsuba variant, libLLVM, devices")
    p.add_argument("--json", action="store_true")
    p.add_argument("--short", action="store_true")
    p.set_defaults(func=cmd_info)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns the exit status (module docstring)."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as e:                        # --help, --version, argument errors
        return e.code if isinstance(e.code, int) else 2
    try:
        with runtime.sigterm_raises():
            return args.func(args)
    except UserError as e:
        print(f"poevp: error: {e}", file=sys.stderr)
        return 2
    except BaseException as e:
        # a signal can land inside an import or a C extension, which re-raises it as its own
        # error (ImportError, RuntimeError) with the signal's exception as the cause
        if _caused_by(e, KeyboardInterrupt):
            print("poevp: interrupted (Ctrl-C); partial output removed, earlier outputs untouched",
                  file=sys.stderr)
            return 130
        if _caused_by(e, runtime.Terminated):
            print("poevp: terminated (SIGTERM); partial output removed, earlier outputs and finished "
                  "sweep points kept", file=sys.stderr)
            return 143
        raise


def _caused_by(e: BaseException, kind: type) -> bool:
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, kind):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


if __name__ == "__main__":
    sys.exit(main())
