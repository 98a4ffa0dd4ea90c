"""`poevp` command line: render, validate, compare, chart, sweep, evaluate, train-predictor, info."""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from pathlib import Path

from . import __version__


def _add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="scene folder (holding scene.toml) or a .toml file")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene key, TOML value syntax (repeatable): render.spp=64")
    p.add_argument("--frames", type=int, help="shorthand for --set timing.frames=N")
    p.add_argument("--spp", type=int, help="shorthand for --set render.spp=N")
    p.add_argument("--resolution", help="HxW, shorthand for --set render.resolution=[H,W]")
    p.add_argument("--seed", type=int, help="shorthand for --set render.seed=S")
    p.add_argument("--accuracy", choices=("fast", "default", "reference"), default="default",
                   help="spp, sub-frames and PSF support together (fast: 1/4 spp, K/2; reference: 4x, 4x)")


def _add_job_options(p: argparse.ArgumentParser, out_help: str) -> None:
    p.add_argument("--out", help=out_help)
    p.add_argument("--threads", type=int, help="DrJit/torch/OpenCV threads (default: all cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _overrides(args) -> list[str]:
    from .scene import SceneError

    out = list(args.overrides)
    if getattr(args, "frames", None) is not None:
        out.append(f"timing.frames={args.frames}")
    if getattr(args, "spp", None) is not None:
        out.append(f"render.spp={args.spp}")
    if getattr(args, "seed", None) is not None:
        out.append(f"render.seed={args.seed}")
    if getattr(args, "resolution", None):
        try:
            h, w = (int(v) for v in args.resolution.lower().split("x"))
        except ValueError:
            raise SceneError(f"--resolution {args.resolution}: expected HxW, e.g. 368x640") from None
        out.append(f"render.resolution=[{h},{w}]")
    if getattr(args, "accuracy", "default") != "default":
        from .scene import accuracy_overrides

        out += accuracy_overrides(args.scene, out, args.accuracy)
    return out


def cmd_render(args) -> int:
    from . import runtime
    from .io import staged_dir
    from .loop import run_render
    from .scene import load_scene

    spec = load_scene(args.scene, _overrides(args))
    runtime.set_threads(args.threads)
    out = Path(args.out) if args.out else Path("out") / spec.name
    with staged_dir(out) as stage:
        report = run_render(spec, stage, progress=not args.quiet)
    r = report["stages"]["render"]
    roi = r["rel_error_roi"]
    print(f"poevp: rendered {report['frames']} frames of {spec.name} at "
          f"{report['resolution'][0]}x{report['resolution'][1]} ({r['path']}, {r['variant']}) in "
          f"{report['total_seconds']:.1f} s; MC rel. error {r['rel_error']:.2%} frame"
          + (f", {roi:.2%} ROI" if roi is not None else "") + f" -> {out}/report.json")
    return 0


def cmd_validate(args) -> int:
    from .render import plan_spectra
    from .scene import load_scene

    spec = load_scene(args.scene, _overrides(args))
    plan = plan_spectra(spec)
    if args.load:
        from .render import Renderer

        Renderer(spec)  # loads the XML in Mitsuba and checks moving ids / ROI shape
    print(f"poevp: {spec.toml_path} is valid: {spec.timing.frames} frames, "
          f"{spec.render.resolution[0]}x{spec.render.resolution[1]}, "
          f"{'static' if spec.is_static else ('PWM lamps on static geometry: ' + ', '.join(spec.flicker)) if spec.geometry_static else 'moving: ' + ', '.join(spec.motion)}; "
          f"render path {plan.mode} ({plan.reason})")
    return 0


def cmd_compare(args) -> int:
    from . import runtime
    from .compare import compare
    from .io import staged_dir
    from .scene import SceneError, load_scene

    spec = load_scene(args.scene, _overrides(args))
    preds = [p.strip() for p in args.predictors.split(",") if p.strip()]
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    for m in modes:
        if m not in ("open", "raw", "demodulated"):
            raise SceneError(f"--modes: unknown loop mode {m!r}")
    runtime.set_threads(args.threads)
    out = Path(args.out) if args.out else Path("out") / f"{spec.name}-compare"
    with staged_dir(out) as stage:
        rows = compare(args.scene, preds, modes, stage, _overrides(args), progress=not args.quiet)
    for r in rows:
        print(f"{r['predictor']:>11s} {r['mode']:>12s}  mask IoU {_f(r['mask_iou'])}  plate saturated "
              f"{_f(r['sat_loop_after_init'])} (LDR {_f(r['sat_ldr'])})  entropy {_f(r['entropy_loop_after_init'])}")
    print(f"poevp: comparison -> {out}/comparison.md")
    return 0


def _f(v):
    return "-" if v is None else f"{v:.3f}"


def cmd_chart(args) -> int:
    from . import runtime
    from .chart_run import run_chart
    from .io import staged_dir
    from .scene import load_scene

    spec = load_scene(args.scene, _overrides(args))
    runtime.set_threads(args.threads)
    out = Path(args.out) if args.out else Path("out") / f"{spec.name}-chart"
    with staged_dir(out) as stage:
        r = run_chart(spec, stage, progress=not args.quiet)
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
    from .sweep import sweep

    out = Path(args.out) if args.out else Path("out") / f"{Path(args.scene).resolve().name}-sweep"
    df = sweep(args.scene, args.grid, out=out, seeds=args.seeds, workers=args.workers,
               scheduler=args.scheduler, job=args.job, base_overrides=_overrides(args),
               metric=args.plot, progress=not args.quiet, retry_failed=args.retry_failed,
               threads=args.threads)
    if df is not None:
        n_ok = int((df["status"] == "ok").sum())
        print(f"poevp: sweep table {out}/results.parquet: {n_ok} ok, {len(df) - n_ok} failed")
        for _, r in df[df["status"] == "failed"].iterrows():
            print(f"poevp:   failed point {r['point']} seed {r['seed']}: {r['error']}")
    return 0


def cmd_evaluate(args) -> int:
    from . import runtime
    from .evaluate import E_LEVELS, evaluate
    from .io import staged_dir

    runtime.set_threads(args.threads)
    out = Path(args.out) if args.out else Path("out") / ("evaluate-quick" if args.quick else "evaluate")
    with staged_dir(out) as stage:
        summary = evaluate(stage, quick=args.quick, progress=not args.quiet)
    e = str(max(E_LEVELS))
    for m, s in ((k, v) for k, v in summary.items() if k != "test_set"):
        print(f"{m:>15s}  accuracy E={e}: {s[e]['accuracy_pct']:5.1f} %  all: {s['all']['accuracy_pct']:5.1f} %"
              f"  entropy {s[e]['entropy_bits']:.2f} bits  {s['all']['method_ms']:.1f} ms/frame")
    print(f"poevp: evaluation -> {out}/evaluation.md")
    return 0


def cmd_train(args) -> int:
    from . import runtime
    from .predict.dmvfn import default_weights
    from .predict.train import train

    runtime.set_threads(args.threads)
    weights = Path(args.weights_out) if args.weights_out else default_weights(args.name)
    rec = train(args.name, minutes=args.minutes, sequences=args.sequences, frames=args.frames,
                val_sequences=args.val_sequences, batch=args.batch, lr=args.lr, seed=args.seed,
                out=Path(args.out), weights_out=weights, max_steps=args.max_steps)
    v = rec["validation"]
    print(f"poevp: trained {args.name} for {rec['steps']} steps ({rec['train_seconds']:.0f} s); "
          f"validation highlight IoU {v['model']['highlight_iou']:.3f} (hold {v['hold']['highlight_iou']:.3f}, "
          f"flow {v['flow']['highlight_iou']:.3f}), PSNR {v['model']['psnr_db']:.2f} dB -> {weights}")
    return 0


def info_dict() -> dict:
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    from . import runtime

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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="poevp", description="POE-VP DMD camera simulator")
    parser.add_argument("--version", action="version", version=f"poevp_optics {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("render", help="render a scene: radiance frames, previews, report.json")
    _add_run_options(p)
    p.add_argument("--out", help="output folder (default out/<scene>); replaced whole on success")
    p.add_argument("--threads", type=int, help="DrJit/torch threads (default: all cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("validate", help="parse and check a scene without rendering")
    _add_run_options(p)
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
    p.add_argument("--seeds", type=int, default=1, help="seeds per point (render.seed, sensor.seed)")
    p.add_argument("--out", help="default out/<scene>-sweep; rerunning resumes")
    p.add_argument("--workers", type=int, help="local Dask worker processes (default: cores)")
    p.add_argument("--scheduler", help="tcp://HOST:PORT of an existing Dask scheduler")
    p.add_argument("--job", default="render", choices=("render", "chart"))
    p.add_argument("--plot", metavar="METRIC", help="column to plot, e.g. metrics.saturated_fraction_roi.encoded")
    p.add_argument("--retry-failed", action="store_true", help="rerun points recorded as failed")
    p.add_argument("--threads", type=int, help="DrJit/torch/OpenCV threads per worker (default cores // workers)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("evaluate", help="plate recognition: LDR vs exposure fusion vs POE-VP (OCR)")
    p.add_argument("--quick", action="store_true", help="2 sequences x 5 frames (CI size)")
    _add_job_options(p, "default out/evaluate")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("train-predictor", help="train dmvfn_lite (or dmvfn) on rendered sequences")
    p.add_argument("--name", default="dmvfn_lite", choices=("dmvfn_lite", "dmvfn"))
    p.add_argument("--minutes", type=float, default=10.0, help="training time budget")
    p.add_argument("--sequences", type=int, default=48)
    p.add_argument("--val-sequences", type=int, default=8)
    p.add_argument("--frames", type=int, default=6)
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--lr", type=float, default=2e-3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-steps", type=int)
    p.add_argument("--out", default="out/train", help="checkpoints (resumable)")
    p.add_argument("--weights-out", help="default: assets/predictor/<name>.safetensors")
    p.add_argument("--threads", type=int)
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("info", help="versions, Mitsuba variant, libLLVM, devices")
    p.add_argument("--json", action="store_true")
    p.add_argument("--short", action="store_true")
    p.set_defaults(func=cmd_info)
    return parser


def main(argv: list[str] | None = None) -> int:
    from .scene import SceneError
    from .spectra import SpectrumError

    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (SceneError, SpectrumError) as e:
        print(f"poevp: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("poevp: interrupted; existing outputs left untouched", file=sys.stderr)
        return 130
    except BaseException as e:
        if type(e).__name__ == "Terminated":     # sweep.Terminated (SIGTERM)
            print("poevp: terminated (SIGTERM); finished results kept", file=sys.stderr)
            return 143
        raise


if __name__ == "__main__":
    sys.exit(main())
