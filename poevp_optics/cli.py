"""`poevp` command line: render, validate, compare, chart, sweep, search, evaluate, train-predictor, schema, info.

Exit status: 0 done; 1 a sweep finished with failed points (`--allow-failed`: 0), a search
with no trial meeting its constraints, or the
environment failed (disk full, out of memory, too many open files) or an internal error (one
line; `--debug` or POEVP_DEBUG=1 shows the traceback); 2 bad input (one line on stderr naming
the file and key, or the flag, or the path; nothing written); 130 Ctrl-C; 143 SIGTERM (both: a
message, partial output removed, earlier outputs untouched).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from pathlib import Path

from poevp_optics.apps.cli_args import add_cluster_options as _add_cluster_options, tls_options as _tls_options
from poevp_optics.apps.cli_args import positive_int as _positive_int, seeds_arg as _seeds, threads_arg as _threads
from poevp_optics import __version__
from poevp_optics.core import runtime
from poevp_optics.core.exceptions import UserError


class _OneLineParser(argparse.ArgumentParser):
    """Argument errors as one line (`poevp: error: argument --threads: ...`), exit 2."""

    def error(self, message):
        self.exit(2, f"poevp: error: {' '.join(message.split())}\n")


def _resolution_arg(text: str) -> tuple[int, int]:
    """--resolution HxW: (H, W) as typed (the scene's bounds check the values)."""
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected HxW, e.g. 368x640, got {text!r}") from None
    return h, w


def _scale_arg(text: str) -> tuple[float, str]:
    """--scale S: (the scale, as typed)."""
    from poevp_optics.scene.scale import parse_scale

    try:
        return parse_scale(text), text.strip()
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


class _Override(argparse.Action):
    """`--set KEY=VALUE` and the shorthands (--frames, --spp, --seed) become `section.key=value`
    overrides in the order given, so the last one given wins."""

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
    p.add_argument("--seed", dest="overrides", action=_Override, type=int, metavar="S",
                   key=lambda v: f"render.seed={v}", help="shorthand for --set render.seed=S")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--scale", type=_scale_arg, metavar="S",
                      help="the camera at S times the scene's mirrors over the same field (S: 1/6, 0.5, 2): "
                           "render.resolution x S (whole pixels), objective.focal_length_m x S, every size in "
                           "mirrors x S (mask.smooth_px, objective.guard_max_px, chart.roi_inset_px) and "
                           "every area x S^2 (attenuator.serve_min_mirrors); the relay and the sensor's pixels "
                           "keep theirs. Default: the environment variable POEVP_SCALE where set (and no "
                           "--resolution, --dmd-mirrors or --set render.resolution is given), else 1. A key "
                           "also given with --set keeps the --set value")
    size.add_argument("--resolution", type=_resolution_arg, metavar="HxW",
                      help="the camera at HxW mirrors over the same field across the width: as --scale "
                           "W / (the scene's width), so the focal length and the sizes in mirrors follow "
                           "(another aspect than the scene's changes the field's height); wins over --set "
                           "render.resolution, which alone changes the pixel count and nothing else")
    size.add_argument("--dmd-mirrors", dest="dmd_mirrors", action="store_true",
                      help="render at the DMD's own mirror count (dmd.controller's DMD: the DLP6500's "
                           "1920x1080, the DLP9000's 2560x1600), the focal length and the sizes in mirrors "
                           "scaled as --scale does; applied after every --set (it rescales the camera they "
                           "describe)")
    p.add_argument("--yes", "--force", dest="yes", action="store_true",
                   help="run even when the run-size estimate (CPU time, disk) is above the limits "
                        "(POEVP_MAX_CPU_HOURS, default 4; POEVP_MAX_DISK, default 20G); free space is "
                        "still checked")
    p.add_argument("--accuracy", choices=("fast", "default", "reference"), default="default",
                   help="spp, MC error target, sub-frames and PSF support together, applied after "
                        "every --set (fast: 5 %% target within the scene's spp, K/2; reference: "
                        "0.5 %% target within 64x spp, 4x K)")


def _add_job_options(p: argparse.ArgumentParser, out_help: str) -> None:
    p.add_argument("--out", help=out_help)
    p.add_argument("--threads", type=_threads,
                   help="DrJit/torch/OpenCV threads (default: all cores); with 2 or more a render run "
                        "renders the next frame while the camera runs this one")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _overrides(args) -> list[str]:
    """The run's `section.key=value` overrides: the camera's scale, the --set's and shorthands,
    the --dmd-mirrors and --accuracy sets (`_overrides_and_scaling`)."""
    return _overrides_and_scaling(args)[0]


def _camera_scaling(args, sets: list[str]):
    """The Scaling (scene/scale.py) that --scale, --resolution, --dmd-mirrors or POEVP_SCALE ask
    for, against the scene with the user's --set applied; None where none applies or it is 1."""
    from poevp_optics.core.exceptions import SceneError, UserError
    from poevp_optics.scene.load import load_scene, parse_override
    from poevp_optics.scene.scale import parse_scale, scaled_resolution, scaling_for

    explicit = set()
    for o in sets:                       # a malformed one is named, with the file, by load_scene
        try:
            explicit.add(".".join(parse_override(o)[0]))
        except SceneError:
            pass
    scale, resolution = getattr(args, "scale", None), getattr(args, "resolution", None)
    if getattr(args, "dmd_mirrors", False):
        from poevp_optics.apps.run.headline import DMD_MIRRORS

        spec = load_scene(args.scene, sets)
        known = DMD_MIRRORS.get(spec.dmd.controller) if spec.dmd.enabled else None
        if known is None:
            raise SceneError(f"{args.scene}: --dmd-mirrors: dmd.controller names no DMD of known mirror count "
                             "(dlpc900_dlp6500, dlpc900_dlp9000) or the DMD is disabled")
        return scaling_for(spec, known[1], "--dmd-mirrors")
    if resolution is not None:           # the flag names the resolution: it wins over --set render.resolution
        explicit.discard("render.resolution")
        given = f"--resolution {resolution[0]}x{resolution[1]}"
    elif scale is not None:
        given = f"--scale {scale[1]}"
    else:
        env = os.environ.get("POEVP_SCALE", "").strip()
        if not env or "render.resolution" in explicit:
            return None
        try:
            scale = (parse_scale(env), env)
        except ValueError as e:
            raise UserError(f"POEVP_SCALE={env}: {e}") from None
        given = f"POEVP_SCALE={env}"
    if resolution is None and abs(scale[0] - 1.0) < 1e-12:
        return None
    spec = load_scene(args.scene, sets)
    target = resolution if resolution is not None else scaled_resolution(spec.render.resolution, scale[0])
    scaling = scaling_for(spec, target, given, explicit)
    return scaling if scaling.changes or scaling.kept else None


def _overrides_and_scaling(args):
    """(the run's overrides, its Scaling or None). --scale / --resolution / POEVP_SCALE come first,
    so a key the user also sets with --set keeps the --set value (--resolution's own
    render.resolution comes last: that flag names it); --dmd-mirrors comes after every --set;
    --accuracy last."""
    from poevp_optics.core.exceptions import SceneError
    from poevp_optics.scene.load import accuracy_overrides, parse_override
    sets = list(args.overrides)
    scaling = _camera_scaling(args, sets)
    if scaling is None:
        out = sets
    elif scaling.given == "--dmd-mirrors":
        out = [*sets, *scaling.sets]
    else:
        res = [x for x in scaling.sets if x.startswith("render.resolution=")]
        out = [*(x for x in scaling.sets if x not in res), *sets, *res]
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
    return out, scaling


def cmd_render(args) -> int:
    from poevp_optics.apps.run.headline import (dmd_scale_line, init_line, mc_error_line, plural, scale_line,
                                                target_line)

    from poevp_optics.apps.run.runner import run_job

    overrides, scaling = _overrides_and_scaling(args)
    spec, out, report = run_job("render", args.scene, overrides, out=args.out, threads=args.threads,
                                yes=args.yes,
                                progress=not args.quiet)
    r = report["stages"]["render"]
    print(f"poevp: rendered {plural(report['frames'], 'frame')} of {spec.name} at "
          f"{report['resolution'][0]}x{report['resolution'][1]} ({r['path']}, {r['variant']}) in "
          f"{report['total_seconds']:.1f} s; MC rel. error " + mc_error_line(r, spec)
          + target_line(r) + f" -> {out}/report.json"
          + (f", {out}/report.html (open it in a browser)" if (Path(out) / "report.html").is_file() else "")
          + scale_line(scaling) + dmd_scale_line(spec, scaling) + init_line(report, spec))
    return 0


def cmd_validate(args) -> int:
    from poevp_optics.apps.run.headline import plural
    from poevp_optics.apps.run.memory import fits_note
    from poevp_optics.apps.run.preflight import check_run
    from poevp_optics.apps.run.runner import check_size
    from poevp_optics.scene.load import load_scene
    spec = load_scene(args.scene, _overrides(args))
    job = args.job or ("chart" if spec.chart.patches else "render")
    pf = check_run(spec, job, load=not args.no_load)
    plan = pf.plan
    size = check_size(spec, job, plan, None, args.yes)
    if not spec.source.renders:
        what = f"source {plan.mode}: {plan.reason}" + "".join(f"; note: {n}" for n in plan.notes)
    else:
        what = (f"spp {spec.render.spp}, "
                f"{'static' if spec.is_static else ('PWM lamps on static geometry: ' + ', '.join(spec.flicker)) if spec.geometry_static else 'moving: ' + ', '.join(spec.motion)}; "
                f"render path {plan.mode} ({plan.reason})")
    print(f"poevp: {spec.toml_path} is valid for `poevp {job}`: {plural(spec.timing.frames, 'frame')}, "
          f"{spec.render.resolution[0]}x{spec.render.resolution[1]}, {what}; {fits_note(pf.memory)}; "
          f"run size: {size.describe()}")
    return 0


def cmd_compare(args) -> int:
    from poevp_optics.apps.run.runner import run_job
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
                                yes=args.yes,
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
    from poevp_optics.apps.run.runner import run_job

    spec, out, r = run_job("chart", args.scene, _overrides(args), out=args.out, threads=args.threads,
                                yes=args.yes,
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
    from poevp_optics.apps.run.runner import reads
    from poevp_optics.core.io import check_output
    from poevp_optics.scene.load import load_scene
    from poevp_optics.apps.sweep.sweep import sweep

    spec = load_scene(args.scene, _overrides(args), cross_checks=False)
    out = Path(args.out) if args.out else Path("out") / f"{spec.name}-sweep"
    check_output(out, "sweep", protect=reads(spec))
    df = sweep(args.scene, args.grid, out=out, seeds=args.seeds, workers=args.workers,
               scheduler=args.scheduler, scheduler_file=args.scheduler_file, shared_fs=args.shared_fs,
               retries=args.retries, job=args.job, base_overrides=_overrides(args),
               metric=args.plot, progress=not args.quiet, retry_failed=args.retry_failed,
               threads=args.threads, yes=args.yes, rebuild=args.rebuild,
               reuse_render=not args.no_reuse_render, **_tls_options(args))
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


def cmd_schema(args) -> int:
    """`poevp schema`: the JSON Schema of scene.toml (scene/schema.py) to stdout or --out."""
    from poevp_optics.scene.schema import schema_json

    text = schema_json()
    if args.out:
        try:
            Path(args.out).write_text(text)
        except OSError as e:
            raise UserError(f"--out {args.out}: {e.strerror or e}") from None
        print(f"wrote {args.out}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


def _add_sweep_parser(sub) -> None:
    from poevp_optics.apps.run.runner import sweep_jobs

    p = sub.add_parser("sweep", help="grid of scene variations on Dask: table, plots; resumable")
    _add_run_options(p)
    p.add_argument("--grid", action="append", default=[], required=True,
                   help="KEY=v1,v2,... | KEY=start:stop:num | KEY=log:start:stop:num (repeatable)")
    p.add_argument("--seeds", type=_seeds, default=1, help="seeds per point (render.seed, sensor.seed), "
                   "at most 1000")
    p.add_argument("--out", help="default out/<scene>-sweep; rerunning the same sweep resumes")
    p.add_argument("--workers", type=_positive_int, help="local Dask worker processes (default: cores)")
    _add_cluster_options(p)
    p.add_argument("--job", default="render", choices=sweep_jobs())
    p.add_argument("--plot", metavar="METRIC", help="column to plot, e.g. metrics.saturated_fraction_roi.encoded")
    p.add_argument("--retry-failed", action="store_true", help="rerun points recorded as failed")
    p.add_argument("--rebuild", action="store_true",
                   help="a results table or sweep.json that does not read is rebuilt from the points' "
                        "own report.json files (points without one run again)")
    p.add_argument("--allow-failed", action="store_true",
                   help="exit 0 even when points failed (default: exit 1)")
    p.add_argument("--no-reuse-render", action="store_true",
                   help="render every point (default: points whose render inputs are the same share "
                        "one render, stored under renders/ in the sweep folder)")
    p.add_argument("--threads", type=_threads,
                   help="DrJit/torch/OpenCV threads per worker (default cores // workers)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_sweep)


def build_parser() -> argparse.ArgumentParser:
    from poevp_optics.apps.evaluate.evaluate_cli import add_evaluate_parser
    from poevp_optics.apps.train.train_cli import add_train_parsers
    from poevp_optics.apps.run.runner import JOBS

    parser = _OneLineParser(prog="poevp", description="POE-VP DMD camera simulator")
    parser.add_argument("--version", action="version", version=f"poevp_optics {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="show tracebacks and library warnings (also POEVP_DEBUG=1; any position)")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("render", help="render a scene: radiance frames, previews, report.json")
    _add_run_options(p)
    _add_job_options(p, "output folder (default out/<scene>); replaced whole on success")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("validate", help="every check a run makes, short of rendering")
    _add_run_options(p)
    p.add_argument("--job", choices=JOBS.names(),
                   help="check the scene for this command (default: chart for a [chart] scene, else render)")
    p.add_argument("--load", action="store_true", help="(the default) load the XML in Mitsuba as render does")
    p.add_argument("--no-load", action="store_true",
                   help="skip loading the XML in Mitsuba (faster; an include or parameter Mitsuba "
                        "refuses is then found by render only)")
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

    _add_sweep_parser(sub)

    from poevp_optics.apps.search.search_cli import add_search_parser

    add_search_parser(sub, _add_run_options, _overrides)

    add_evaluate_parser(sub, _add_job_options)

    add_train_parsers(sub)

    p = sub.add_parser("schema", help="JSON Schema of scene.toml (for editors: taplo, Even Better TOML)")
    p.add_argument("--out", help="write it to this file (default: stdout)")
    p.set_defaults(func=cmd_schema)

    p = sub.add_parser("info", help="versions, Mitsuba variant, libLLVM, devices")
    p.add_argument("--json", action="store_true")
    p.add_argument("--short", action="store_true")
    p.set_defaults(func=cmd_info)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns the exit status (module docstring). Every failure is one line
    on stderr (core/failures.py); `--debug` (anywhere before `--`) or POEVP_DEBUG=1 lets the
    traceback and library warnings through instead."""
    import atexit
    import warnings

    from poevp_optics.core.failures import debug_requested

    from_shell = argv is None
    if from_shell:                     # a process of its own: its large arrays reuse freed blocks
        runtime.keep_large_blocks()
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = debug_requested(argv)
    argv = [a for i, a in enumerate(argv) if not (a == "--debug" and "--" not in argv[:i])]
    if from_shell:                     # SIGTERM after the command's own handling: still one line
        runtime.sigterm_exits(_TERMINATED)
        atexit.register(_exit_after_cleanup)
    if debug:
        rc = _EXIT[0] = _run(argv, debug)
        return rc
    with warnings.catch_warnings(record=True) as caught:
        rc = _EXIT[0] = _run(argv, debug)
    if caught and rc == 0:             # a failure's one line says what went wrong; --debug shows them
        first = caught[0]
        print(f"poevp: note: {len(caught)} library warning(s) during the run, first "
              f"{first.category.__name__}: {' '.join(str(first.message).split())[:200]} "
              "(--debug shows them)", file=sys.stderr)
    return rc


_EXIT: list = [None]


def _exit_after_cleanup() -> None:
    """The last exit handler (registered first): every output is written and every other exit
    handler (Dask, multiprocessing, temporary files) has run, so leave now with the command's
    status. The interpreter's own teardown after this point resets signal handlers to the
    defaults, where a SIGTERM would end the process silently (-15)."""
    if _EXIT[0] is None:
        return
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 - a closed pipe: nothing more to say
            pass
    os._exit(_EXIT[0])


_TERMINATED = ("poevp: terminated (SIGTERM); partial output removed, earlier outputs and finished "
               "sweep points kept")


def _run(argv: list[str], debug: bool) -> int:
    from poevp_optics.core.failures import describe

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
            print(_TERMINATED, file=sys.stderr)
            return 143
        if debug or isinstance(e, SystemExit):
            raise
        message, rc = describe(e)
        print(f"poevp: error: {message}", file=sys.stderr)
        return rc


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
