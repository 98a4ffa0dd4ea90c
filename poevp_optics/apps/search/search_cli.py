"""`poevp search`'s flags and command (apps/search/search.py runs it; cli.py adds the parser)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from poevp_optics.apps.cli_args import add_cluster_options, count_arg, positive_int, threads_arg, tls_options


def cmd_search(args, overrides_for) -> int:
    """Run `poevp search` (overrides_for(args, scene): a scene's --set and scale overrides)."""
    from poevp_optics.apps.run.runner import reads
    from poevp_optics.apps.search.search import Question, parse_params, search
    from poevp_optics.apps.search.space import Objective, parse_constraint
    from poevp_optics.apps.sweep.execute import ClusterSettings
    from poevp_optics.core.exceptions import SceneError
    from poevp_optics.core.io import check_output
    from poevp_optics.scene.load import load_scene

    scenes = [args.scene, *args.with_scene]
    bases = [overrides_for(args, s) for s in scenes]
    specs = [load_scene(s, b, cross_checks=False) for s, b in zip(scenes, bases)]
    metric, direction = (args.maximize, "maximize") if args.maximize else (args.minimize, "minimize")
    if not metric:
        raise SceneError("poevp search: give the objective, --maximize METRIC or --minimize METRIC")
    objective = Objective(metric, direction, tuple(parse_constraint(c) for c in args.constraint))
    q = Question(parse_params(args.param), objective, args.sampler, args.sampler_seed, args.startup_trials,
                 args.trials)
    out = Path(args.out) if args.out else Path("out") / f"{specs[0].name}-search"
    check_output(out, "search", protect=tuple(p for sp in specs for p in reads(sp)))
    cl = ClusterSettings(args.workers, args.scheduler, args.scheduler_file, args.shared_fs, args.retries,
                         args.threads, **tls_options(args))
    log = (lambda *a: None) if args.quiet else print
    df, best, refined = search(scenes, bases, q, out=out, cl=cl, reuse_render=not args.no_reuse_render,
                               progress=not args.quiet, yes=args.yes, log=log, refine=args.refine)
    if df is None:
        print(f"poevp: search {out}: no trial ran", file=sys.stderr)
        return 1
    counts = df["state"].value_counts().to_dict()
    print(f"poevp: search table {out}/trials.parquet: {len(df)} trials ("
          + ", ".join(f"{n} {s}" for s, n in sorted(counts.items())) + f"); plot {out}/search_plot.png")
    if best is None:
        print(f"poevp: no trial met every constraint with a finite {metric}; see {out}/trials.csv",
              file=sys.stderr)
        return 1
    print(f"poevp: best trial {best['trial']}: {metric} = {best['objective']:.6g} ({direction})")
    print(f"poevp: settings: {best['set_line']}")
    if refined is not None:
        print_refined(refined, metric, out)
    return 0


def print_refined(r: dict, metric: str, out: Path) -> None:
    """--refine's lines: the refined settings and both objectives from the camera, or why not."""
    if not r.get("refined"):
        print(f"poevp: refine: {r['note']} ({out}/refined.json)")
        return
    verdict = ("better than the best trial" if r["improved"] else
               "breaks a constraint; keep the best trial" if not r["feasible"] else
               "not better than the best trial; keep it")
    print(f"poevp: refined (differentiable camera, {r['iterations']} L-BFGS-B steps): model objective "
          f"{r['model_before']:.4g} -> {r['model_after']:.4g}; {metric} by the camera "
          f"{r['objective_before']:.6g} -> {r['objective_after']:.6g}: {verdict}")
    print(f"poevp: refined settings: {r['set_line']}")


def add_search_parser(sub, add_run_options, overrides) -> None:
    """`poevp search`'s flags. add_run_options: the scene and --set/--scale flags (cli.py);
    overrides(args): the run's overrides for args.scene."""
    p = sub.add_parser("search", help="optimise scene keys (Optuna) for a metric of the report over scenes, on Dask")
    add_run_options(p)
    p.add_argument("--with-scene", action="append", default=[], metavar="SCENE",
                   help="another scene the objective is averaged over (repeatable); every --set applies to each")
    p.add_argument("--param", action="append", default=[], required=True, metavar="KEY=RANGE",
                   help="a searched key: KEY=LOW:HIGH (float; integers when both are), KEY=log:LOW:HIGH, or "
                        "KEY=v1,v2,... (choices, TOML values) (repeatable)")
    goal = p.add_mutually_exclusive_group()
    goal.add_argument("--maximize", metavar="METRIC",
                      help="dotted path in report.json, e.g. metrics.plate_white_after_init.in_band_fraction")
    goal.add_argument("--minimize", metavar="METRIC", help="e.g. metrics.saturated_fraction_roi.encoded")
    p.add_argument("--constraint", action="append", default=[], metavar="METRIC<=X",
                   help="must hold on every scene: METRIC<=X or METRIC>=X, e.g. timing_budget.late_frames<=0 "
                        "(no late masks) (repeatable)")
    p.add_argument("--trials", type=positive_int, default=40, help="trials in all (default 40); rerunning with "
                   "more continues the search")
    p.add_argument("--sampler", choices=("tpe", "random"), default="tpe",
                   help="Optuna's TPE (default) or random search")
    p.add_argument("--sampler-seed", type=count_arg, default=0, metavar="S",
                   help="seed of every choice the sampler makes (default 0)")
    p.add_argument("--startup-trials", type=count_arg, default=10, metavar="N",
                   help="TPE's first N trials are drawn at random (default 10)")
    p.add_argument("--out", help="default out/<scene>-search; rerunning the same search resumes")
    p.add_argument("--workers", type=positive_int, help="local Dask worker processes (default: cores); a batch "
                   "holds as many trials as there are workers")
    add_cluster_options(p)
    p.add_argument("--no-reuse-render", action="store_true",
                   help="render every point (default: points with the same render inputs share one render)")
    p.add_argument("--refine", action="store_true",
                   help="after the trials, move the best trial's mask.vs/mask.a/mask.b along the differentiable "
                        "camera's gradient (paper's Eq. 2 law, metrics.plate_white_after_init.in_band_fraction), "
                        "run the camera there and write refined.json (or say why it cannot)")
    p.add_argument("--threads", type=threads_arg, help="DrJit/torch/OpenCV threads per worker")
    p.add_argument("--quiet", action="store_true")

    def run(args):
        def overrides_for(a, scene):
            return overrides(argparse.Namespace(**{**vars(a), "scene": scene}))
        return cmd_search(args, overrides_for)

    p.set_defaults(func=run)
