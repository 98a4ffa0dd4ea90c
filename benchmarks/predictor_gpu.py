"""The video predictor's network on a CUDA GPU: DMVFN and DMVFN-lite forward time at 368x640 and at
the DMD's 1080x1920, float32 and float16 autocast, with the host-device copies of the loop.

The loop's step on a GPU: two captured 8-bit frames go to the device, the network predicts the next
frame (voxel flow plus its two warps, `DMVFN.forward`), the prediction comes back for the mask law.
Timed with CUDA events around that whole step (copies included) and around the network alone;
median and 90th percentile of 50 warm calls after 10 warm-ups, batch 1. The shipped or given
weights are used where they exist (the routing module then decides which blocks run, as in the
loop); else a seeded random initialisation with every block running, the worst case.

Paper (POE-VP, Sec. 5): video prediction plus mask 16.9 ms on an RTX 3090 at the prototype's
resolution. DMVFN: Hu et al., CVPR 2023 (control/predictors/dmvfn.py).

    python -m benchmarks.predictor_gpu [--results] [--weights PATH]

Needs a CUDA device (torch.cuda.is_available()); without one it says so in one line and exits 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from benchmarks.common import add_results_flag, markdown_table, output_folder, save_text

SIZES = ((368, 640), (1080, 1920))


def time_step(model, h: int, w: int, dtype, repeats: int = 50) -> tuple[float, float, float]:
    """(network median ms, step median ms, step p90 ms) for one (h, w) frame pair on the GPU."""
    import torch

    c = model.cfg.channels
    rng = np.random.default_rng(0)
    host = [torch.from_numpy(rng.integers(0, 256, (1, c, h, w), dtype=np.uint8)).pin_memory() for _ in range(2)]
    net, step = [], []
    for i in range(repeats + 10):
        e0, e1, e2, e3 = (torch.cuda.Event(enable_timing=True) for _ in range(4))
        e0.record()
        frames = [t.cuda(non_blocking=True).float() / 255.0 for t in host]
        e1.record()
        with torch.no_grad(), torch.autocast("cuda", dtype=dtype, enabled=dtype != torch.float32):
            pred, _, _ = model(frames[0], frames[1])
        e2.record()
        pred.float().cpu()
        e3.record()
        torch.cuda.synchronize()
        if i >= 10:
            net.append(e1.elapsed_time(e2))
            step.append(e0.elapsed_time(e3))
    return float(np.median(net)), float(np.median(step)), float(np.percentile(step, 90))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_results_flag(ap)
    ap.add_argument("--weights", type=Path, help="full DMVFN weights (default: the shipped ones, if any)")
    args = ap.parse_args(argv)
    import torch

    if not torch.cuda.is_available():
        print("predictor_gpu: torch sees no CUDA device here; this benchmark times the network on a GPU",
              file=sys.stderr)
        return 2
    from poevp_optics.control.predictors.dmvfn import DMVFN, FULL, LITE, count_parameters, default_weights, load_weights

    rows = []
    for name, cfg in (("dmvfn", FULL), ("dmvfn_lite", LITE)):
        path = args.weights if (name == "dmvfn" and args.weights) else default_weights(name)
        if path.exists():
            model, _ = load_weights(path, expect=cfg)
            source = f"{path.name} (routing as trained)"
        else:
            torch.manual_seed(0)
            model = DMVFN(cfg).eval()
            if model.routing is not None:          # no weights: every block runs (worst case)
                model.routing = None
            source = "random init, all blocks"
        model = model.cuda().eval()
        for h, w in SIZES:
            for dtype, label in ((torch.float32, "float32"), (torch.float16, "float16 autocast")):
                net, step, p90 = time_step(model, h, w, dtype)
                rows.append([name, source, f"{h}x{w}", label, net, step, p90])
        del model
        torch.cuda.empty_cache()
    gpu = torch.cuda.get_device_name(0)
    header = ["predictor", "weights", "frames", "precision", "network ms (median)", "step ms (median)",
              "step ms (p90)"]
    n_full = count_parameters(DMVFN(FULL))
    text = (f"# The video predictor on a GPU\n\nOne frame pair in, one predicted frame out, batch 1, on "
            f"{gpu} (torch {torch.__version__}, CUDA {torch.version.cuda}). *Network*: the forward pass "
            f"(voxel flow and both warps); *step*: the copies of the two 8-bit frames to the device "
            f"and of the prediction back, plus the network. Median and 90th percentile of 50 warm "
            f"calls (CUDA events). The full DMVFN has {n_full / 1e6:.2f} M parameters. Paper: video "
            f"prediction plus mask 16.9 ms on an RTX 3090.\n\n{markdown_table(header, rows)}\n")
    print(text)
    save_text(output_folder(args.results) / "predictor_gpu.md", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
