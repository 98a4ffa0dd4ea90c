"""`poevp train-predictor` and `poevp train-data`: their flags and commands (apps/train/train_data.py
renders a scene's sequences, apps/train/train_track.py and apps/train/train.py train on them); cli.py adds
the parsers."""

from __future__ import annotations

import os
import time
from pathlib import Path

from poevp_optics.apps.cli_args import add_cluster_options, positive_int, tls_options
from poevp_optics.core import runtime
from poevp_optics.core.exceptions import UserError


def data_config(args):
    """apps/train/train_data.py DataConfig from the train-data / train-predictor flags."""
    from poevp_optics.apps.train.train_data import DataConfig

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


def command_line(cmd: str, args) -> str:
    """The command as parsed (every option given or defaulted): reruns the same training."""
    skip = {"func", "scene", "command"} | ({"minutes", "val_sequences"} if getattr(args, "name", "") == "track_net" else set())
    opts = [f"--{k.replace('_', '-')}" + ("" if v is True else f" {v}") for k, v in sorted(vars(args).items())
            if k not in skip and v not in (None, False)]
    return " ".join(["poevp", cmd, str(args.scene or ""), *opts]).replace("  ", " ")


def data_cluster(args):
    from poevp_optics.apps.sweep.sweep import ClusterSettings

    return ClusterSettings(None, args.scheduler, args.scheduler_file, args.shared_fs, args.retries, args.threads,
                           **tls_options(args))


def cmd_train_data(args) -> int:
    from poevp_optics.apps.train.train_data import build_data

    runtime.set_threads(args.threads)
    t0 = time.perf_counter()
    data = build_data(args.scene, data_config(args), cluster=data_cluster(args), progress=not args.quiet)
    m = data.manifest
    print(f"poevp train-data: {args.scene}: {', '.join(f'{s} {n}' for s, n in m['split']['sequences'].items())} "
          f"sequences, sha256 {data.sha256[:16]}, {'rendered' if data.rendered else 'from the cache'} "
          f"({time.perf_counter() - t0:.0f} s now; rendering took {m['timing']['render_seconds']:.0f} s) -> {data.folder}")
    return 0


def cmd_train(args) -> int:
    runtime.set_threads(args.threads)
    if args.data_only:
        if not args.scene:
            raise UserError("train-predictor --data-only: name the SCENE whose data to build")
        return cmd_train_data(args)
    if args.data == "paths" and (args.scene or args.name == "track_net"):
        raise UserError("train-predictor --data paths: the motion-path frames train dmvfn or dmvfn_lite "
                        "without a SCENE")
    if not 0.0 <= args.saturation_weight < float("inf"):
        raise UserError(f"--saturation-weight {args.saturation_weight}: a finite weight >= 0")
    if args.name == "track_net":
        from poevp_optics.apps.train.train_track import train_track_net_scene
        from poevp_optics.core.paths import ASSETS_DIR

        scene = args.scene or "highbeam_plate"
        weights = Path(args.weights_out) if args.weights_out else Path(args.out) / f"track_net_{Path(scene).name}.safetensors"
        if weights.resolve() == (ASSETS_DIR / "predictor/track_net.safetensors").resolve():
            raise UserError(f"--weights-out {weights}: the shipped track_net weights come from "
                            "apps/train/train_track.py; write a scene-trained model elsewhere")
        t0 = time.perf_counter()
        rec = train_track_net_scene(scene, data_config(args), steps=args.max_steps or 3000,
                                    batch=args.batch or 128, lr=args.lr or 3e-3, seed=args.seed,
                                    device=args.device, checkpoint_dir=Path(args.out) / f"track_net_{Path(scene).name}",
                                    resume=args.resume, checkpoint_every=args.checkpoint_every,
                                    weights_out=weights, cluster=data_cluster(args), progress=not args.quiet,
                                    command=command_line("train-predictor", args))
        b, t = rec["budget"], rec["test"].get("all", {})
        print(f"poevp: trained track_net on {scene} for {b['steps']} steps ({b['epochs']:.0f} epochs, "
              f"{b['train_seconds']:.0f} s training, {b['data_seconds']:.0f} s data, device {b['device']}); "
              f"held-out median centroid error {t.get('track_net', float('nan')):.2f} px "
              f"(constant velocity {t.get('constant_velocity', float('nan')):.2f}, track "
              f"{t.get('track', float('nan')):.2f}; n = {t.get('n', 0)}) -> {weights} "
              f"({time.perf_counter() - t0:.0f} s in all)")
        return 0
    from poevp_optics.apps.train.train import train

    weights = Path(args.weights_out) if args.weights_out else Path("out/predictor") / f"{args.name}.safetensors"
    n_train = int(str(args.sequences or 48).split(",")[0])
    frames_data, source, t_data = None, None, time.perf_counter()
    if args.scene:
        from poevp_optics.apps.train.train_data import build_data

        data = build_data(args.scene, data_config(args), cluster=data_cluster(args), progress=not args.quiet)
        frames_data = (data.splits["train"]["frames"], data.splits["val"]["frames"])
        source = f"{data.manifest['scene']} (apps/train/train_data.py, sha256 {data.sha256})"
    elif args.data == "paths":
        from poevp_optics.apps.train.path_frames import path_frames, source_line

        n_val = args.val_sequences
        frames, res = args.frames or 8, data_config(args).resolution if args.resolution else (368, 640)
        workers = args.threads or os.cpu_count() or 1
        frames_data = (path_frames("train", n_train, frames, res, workers), path_frames("val", n_val, frames, res, workers))
        source = source_line(n_train, n_val, frames, res)
    procedural = {"resolution": data_config(args).resolution} if args.resolution else {}
    rec = train(args.name, minutes=args.minutes, sequences=n_train,
                frames=args.frames or 6, val_sequences=args.val_sequences, batch=args.batch or 4,
                lr=args.lr or 2e-3, seed=args.seed, out=Path(args.out), weights_out=weights,
                max_steps=args.max_steps, frames_data=frames_data, device=args.device, source=source,
                command=command_line("train-predictor", args), saturation_weight=args.saturation_weight,
                float16_weights=args.float16_weights, progress=not args.quiet,
                data_seconds=time.perf_counter() - t_data, **procedural)
    v = rec["validation"]
    print(f"poevp: trained {args.name} for {rec['steps']} steps ({rec['train_seconds']:.0f} s); "
          f"validation highlight IoU {v['model']['highlight_iou']:.3f} (hold {v['hold']['highlight_iou']:.3f}, "
          f"flow {v['flow']['highlight_iou']:.3f}), PSNR {v['model']['psnr_db']:.2f} dB -> {weights}")
    return 0


def add_train_data_options(p) -> None:
    """train-data / train-predictor: what to render (apps/train/train_data.py DataConfig) and where."""
    p.add_argument("--sequences", help="N train sequences (val, test N/4 each) or TRAIN,VAL,TEST "
                   "(default 96,24,24 for a scene: about 4 min of rendering for highbeam_plate, 8 for night_road on 2 cores; dmvfn without SCENE: 48)")
    p.add_argument("--frames", type=positive_int, help="frames per sequence (default 8; dmvfn without SCENE 6)")
    p.add_argument("--resolution", help="HxW training resolution (default 184x320; dmvfn without SCENE 368x640)")
    p.add_argument("--spp", type=positive_int, help="samples per pixel (default 4)")
    p.add_argument("--data-seed", type=int, default=0, help="the data's seed streams")
    p.add_argument("--threads", type=positive_int)
    p.add_argument("--quiet", action="store_true")
    add_cluster_options(p)


def add_train_parsers(sub) -> None:
    """`poevp train-predictor` and `poevp train-data` (apps/train/train_track.py, train.py, train_data.py)."""
    p = sub.add_parser("train-predictor", help="train track_net, dmvfn_lite or dmvfn on sequences rendered from a scene")
    p.add_argument("scene", nargs="?", help="scene whose renders to train on (apps/train/train_data.py); default: "
                   "highbeam_plate (track_net) or the procedural highbeam_plate set (dmvfn)")
    p.add_argument("--name", default="dmvfn_lite", choices=("dmvfn_lite", "dmvfn", "track_net"))
    p.add_argument("--minutes", type=float, default=10.0, help="dmvfn: training time budget")
    p.add_argument("--val-sequences", type=positive_int, default=8, help="dmvfn without SCENE")
    p.add_argument("--batch", type=positive_int, help="default 128 (track_net), 4 (dmvfn)")
    p.add_argument("--lr", type=float, help="default 3e-3 (track_net), 2e-3 (dmvfn)")
    p.add_argument("--seed", type=int, default=0, help="weights' init and batches")
    p.add_argument("--max-steps", type=positive_int, help="training steps (track_net: default 3000; dmvfn: "
                   "stops at N steps or after --minutes, whichever comes first)")
    p.add_argument("--out", default="out/train", help="checkpoints (resumable); track_net's weights")
    p.add_argument("--weights-out", help="default: out/train/track_net_<scene>.safetensors (track_net), "
                   "out/predictor/<name>.safetensors (dmvfn); a scene loads other weights than the shipped "
                   "assets/predictor/ ones with [predictor] weights = PATH")
    p.add_argument("--resume", action="store_true", help="continue from the checkpoint in --out (same run only)")
    p.add_argument("--checkpoint-every", type=positive_int, default=500, help="track_net: steps between checkpoints")
    p.add_argument("--device", default="auto", choices=("cpu", "cuda", "auto"),
                   help="auto: cuda when torch.cuda.is_available()")
    p.add_argument("--data-only", action="store_true", help="build the data (as train-data) and stop")
    p.add_argument("--data", default="plates", choices=("plates", "paths"),
                   help="dmvfn without SCENE: 'plates', the procedural highbeam_plate set; 'paths', 1-3 "
                   "highlighted cars on motion paths at once (apps/train/path_frames.py; default 8 frames)")
    p.add_argument("--saturation-weight", type=float, default=0.0,
                   help="dmvfn: weight of 1 - the predicted and true saturated regions' soft IoU beside the L1 loss")
    p.add_argument("--float16-weights", action="store_true",
                   help="dmvfn: store the weights as half floats (half the file; they load into the float32 network)")
    add_train_data_options(p)
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("train-data", help="render a scene's predictor training data (cached by content)")
    p.add_argument("scene")
    add_train_data_options(p)
    p.set_defaults(func=cmd_train_data)
