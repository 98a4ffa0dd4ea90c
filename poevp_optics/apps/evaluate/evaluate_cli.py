"""`poevp evaluate`'s flags and the evaluation's configuration built from them (apps/evaluate/evaluate.py
EvalConfig holds the defaults); cli.py adds the parser."""

from __future__ import annotations

from pathlib import Path

from poevp_optics.core.exceptions import UserError


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

    from poevp_optics.apps.evaluate.evaluate import BASE, EvalConfig, quick_config
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
           "paper_law": args.paper_law, "camera": args.camera,
           "paper_effects": tuple(x for x in args.paper_effects.split(",") if x) if args.paper_effects else None,
           "overrides": tuple(args.overrides) if args.overrides else None}
    return dataclasses.replace(cfg, **{k: v for k, v in new.items() if v is not None})


def cmd_evaluate(args) -> int:
    from poevp_optics.apps.evaluate.evaluate import check_config, evaluate
    from poevp_optics.apps.run.runner import run_in_folder

    cfg = _eval_config(args)
    check_config(cfg)
    out = Path(args.out) if args.out else Path("out") / ("evaluate-quick" if args.quick else "evaluate")
    log = (lambda *a: None) if args.quiet else print
    report = run_in_folder("evaluate", out, args.threads, lambda stage: evaluate(stage, cfg, log=log))
    if report.get("zero_reads"):
        print(f"poevp: {report['zero_reads']}")
    for e, v in report["findings"]["separating_speed_px"].items():
        print(f"poevp: E = {e}: " + (f"hold < 50 % while flow/dmvfn > 80 % from {v:g} px/frame" if v is not None
                                      else "no separating speed in the sweep"))
    print(f"poevp: evaluation -> {out}/evaluation.md")
    return 0


def add_evaluate_parser(sub, add_job_options) -> None:
    """`poevp evaluate`'s flags (apps/evaluate/evaluate.py EvalConfig holds the defaults)."""
    p = sub.add_parser("evaluate", help="plate recognition (full ALPR) over speed, E and motion: LDR vs fusion vs POE-VP")
    p.add_argument("scene", nargs="?", help="a scene with a plate (render.roi_shape); default highbeam_plate")
    p.add_argument("--quick", action="store_true", help="CI size: 1 text, 4 and 40 px/frame at E = 9, lateral and reversal, "
                   "predictors hold, flow, oracle (about a minute)")
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
                   help="ldr_highlight scenes: Eq. 2's reading or one of ours (default: threshold_linear in "
                        "the paper's camera, the reading that reproduces the paper; exposure_controller in ours)")
    p.add_argument("--camera", choices=("physical", "paper"),
                   help="ldr_highlight scenes: this project's camera (default) or the paper's code-value simulation "
                        "(noiseless Hadamard product, clip at 255: Table 2 like for like)")
    p.add_argument("--paper-effects", dest="paper_effects",
                   help="with --camera paper: add dmd_floor,smoothing,noise,linear_light (one at a time attributes "
                        "the loss from the paper's camera to ours)")
    p.add_argument("--e-reading", dest="e_reading", choices=("display", "linear"),
                   help="E -> plate peak: display (paper Sec. 4.A, 8-bit values x (E+1), default) or linear")
    p.add_argument("--loop-mode", dest="loop_mode", choices=("open", "raw", "demodulated"),
                   help="what the predictor sees (default demodulated; open: paper Fig. 3)")
    p.add_argument("--set", dest="overrides", action="append", metavar="KEY=VALUE",
                   help="set a scene key for every run, after the protocol's own, TOML value syntax (repeatable): "
                        "mask.envelope=\"predictor_error\"")
    add_job_options(p, "default out/evaluate")
    p.set_defaults(func=cmd_evaluate)
