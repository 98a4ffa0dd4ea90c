"""Per-stage performance against floors measured in the same run, closed-loop frame rate, memory.

1. Render overhead: our `Renderer.render_once` (own film, box filter, spectra bound) against
   the raw Mitsuba render of the same XML and parameters at the same spp and resolution
   (`mi.render(mi.load_file(xml))` with the XML's own sensor). Target: overhead <= 10 %.
2. Post-render chain (DMD + relay + sensor + reconstruct) at 368x640 and 720x1280 against a
   NumPy copy of the arrays it touches (K = 1, delta PSF). Target: within 4x of the copy.
3. Closed loop without render at 368x640: capture -> reconstruct -> predictor input ->
   predictor -> mask law, per frame, per predictor. Target: >= 30 frames/s with `flow`.
4. Peak memory (resident set) each stage adds, per frame size, measured in a fresh process.

    .venv/bin/python -m benchmarks.stage_performance [--results]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

import numpy as np

from benchmarks.common import (add_results_flag, machine_line, markdown_table, output_folder, save_figure,
                               save_text, timed)

SIZES = [(368, 640), (720, 1280)]



def render_overhead(shape, spp=16):
    """(raw, ours single call, ours with MC error) seconds: raw is mi.render on a scene loaded
    straight from the XML with the same parameters, through the same sensor/film."""
    import mitsuba as mi

    from poevp_optics.core.seeds import render_seeds
    from poevp_optics.render.renderer import Renderer
    from poevp_optics.scene.load import load_scene
    spec = load_scene("scenes/highbeam_plate", [f"render.resolution=[{shape[0]},{shape[1]}]"])
    ours = Renderer(spec.resolved.render)
    raw_scene = mi.load_file(str(spec.xml_path), **ours.plan.xml_params)
    seeds = iter(range(1, 10**6))
    t_raw = timed(lambda: np.array(mi.render(raw_scene, sensor=ours.sensor, spp=spp, seed=next(seeds))), 5)[0]
    t_once = timed(lambda: ours.render_once(next(seeds), spp), 5)[0]
    t_err = timed(lambda: ours.render_with_error(render_seeds(1, next(seeds), 0, spec.render.mc_splits), spp), 5)[0]
    return t_raw, t_once, t_err


def chain_vs_copy(shape):
    from poevp_optics.camera.camera import Camera
    from poevp_optics.scene.load import load_scene
    spec = load_scene("scenes/highbeam_plate", [f"render.resolution=[{shape[0]},{shape[1]}]"])
    cam = Camera.from_params(spec.resolved.camera)
    rng = np.random.default_rng(0)
    sub = rng.uniform(1e14, 1e18, cam.mirror_shape).astype(np.float32)
    mask = rng.integers(0, 256, cam.mirror_shape).astype(np.float64)
    seeds = iter(range(10**6))
    stage = {}

    def chain():
        cap = cam.capture([sub], mask, 0, next(seeds))
        t0 = time.perf_counter()
        cam.reconstruct(cap, 0)
        stage.update(cap.seconds, reconstruct=time.perf_counter() - t0)

    def floor():
        _ = sub.copy(), sub.copy(), sub.copy()        # sub-frame in, DN and exposure out

    return timed(chain, 5)[0], timed(floor, 5)[0], dict(stage)


def closed_loop_fps(names=("hold", "flow", "dmvfn_lite"), frames=12):
    """Frames per second of the closed loop without render: capture -> reconstruct -> the loop
    step (predictor input, prediction, mask law; control/loop_step.py), demodulated mode."""
    import dataclasses

    from poevp_optics.camera.camera import Camera
    from poevp_optics.control.loop_step import LoopStep
    from poevp_optics.scene.load import load_scene

    spec = load_scene("scenes/highbeam_plate", ["loop.mode='demodulated'", "loop.init_frames=0"])
    cam = Camera.from_params(spec.resolved.camera)
    h, w = cam.shape
    rng = np.random.default_rng(0)
    base = rng.uniform(1e13, 1e15, (h, w)).astype(np.float32)
    radiance = []
    for t in range(frames):                               # a bright block moving 6 px/frame
        f = base.copy()
        f[150:190, 100 + 6 * t:260 + 6 * t] = 3e17
        radiance.append(f)
    out = {}
    for name in names:
        step = LoopStep(cam, spec.resolved.loop.mask, spec.loop, dataclasses.replace(spec.predictor, name=name,
                                                                       resolution=(h, w)))
        per = []
        for i, rad in enumerate(radiance):
            t0 = time.perf_counter()
            mask = step.next_mask(i).levels
            cap = cam.capture([rad], mask, i, i)
            est, flags, _ = cam.reconstruct(cap, i)
            step.observe(i, cap, cap, est, flags)
            per.append(time.perf_counter() - t0)
        out[name] = float(np.median(per[2:]))
    return out


MEM_SCRIPT = r"""
import json, os, sys, threading, time, numpy as np
PAGE = os.sysconf("SC_PAGE_SIZE")
def rss():
    return int(open("/proc/self/statm").read().split()[1]) * PAGE
peak, stop = [0], [False]
def sample():
    while not stop[0]:
        peak[0] = max(peak[0], rss()); time.sleep(0.0005)
stage, h, w = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
from poevp_optics.scene.load import load_scene
from poevp_optics.camera.camera import Camera
spec = load_scene("scenes/highbeam_plate", [f"render.resolution=[{h},{w}]"])
rng = np.random.default_rng(0)
rad = rng.uniform(1e14, 1e18, (h, w)).astype(np.float32)
mask = rng.integers(0, 256, (h, w)).astype(np.float64)
if stage == "render":
    from poevp_optics.render.renderer import Renderer
    r = Renderer(spec.resolved.render)
elif stage == "camera":
    cam = Camera.from_params(spec.resolved.camera)                 # first capture measured: DrJit's pool grows once
elif stage == "reconstruct":
    cam = Camera.from_params(spec.resolved.camera); cam.capture([rad], mask, 0, 0)
elif stage == "predict":
    from poevp_optics.control.predictors import make_predictor
    p = make_predictor("flow"); f = (rad / rad.max() * 255).astype(np.float32); p([f, f])
peak0 = rss()
th = threading.Thread(target=sample); th.start()
if stage == "render":
    r.render_once(1, 16)
elif stage == "camera":
    cam.capture([rad], mask, 0, 1)
elif stage == "reconstruct":
    cap = cam.capture([rad], mask, 0, 1)
    stop[0] = True; th.join(); peak0 = rss(); peak[0] = 0; stop[0] = False
    th = threading.Thread(target=sample); th.start()
    cam.reconstruct(cap, 0)
elif stage == "predict":
    p([f, f * 0.9])
stop[0] = True; th.join()
peak1 = max(peak[0], rss())
print(json.dumps({"base_mb": peak0 / 2**20, "added_mb": (peak1 - peak0) / 2**20}))
"""


def memory(stage, shape):
    res = subprocess.run([sys.executable, "-c", MEM_SCRIPT, stage, str(shape[0]), str(shape[1])],
                         capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_results_flag(ap)
    dest = output_folder(ap.parse_args(argv).results)
    from poevp_optics.core import runtime

    runtime.set_threads(2)
    lines = [f"# Stage performance\n\nMachine: {machine_line()}. Medians of 5 warm runs; floors "
             "measured in the same run.\n"]
    rows = []
    for shape in SIZES:
        t_raw, t_once, t_err = render_overhead(shape)
        for label, t in (("render_once", t_once), ("render_with_error (2 MC splits)", t_err)):
            rows.append([f"{shape[0]}x{shape[1]}", label, t_raw * 1e3, t * 1e3, (t / t_raw - 1) * 100,
                         "met" if t / t_raw <= 1.10 else f"missed by {(t / t_raw - 1.10) * 100:.1f} points"])
    lines += ["## Render: simulator vs raw Mitsuba (same XML and parameters, same film, spp 16)\n",
              markdown_table(["size", "our call", "raw mi.render ms", "ours ms", "overhead %",
                              "target <= 10 %"], rows), ""]
    rows = []
    for shape in SIZES:
        t_chain, t_floor, st = chain_vs_copy(shape)
        ratio = t_chain / t_floor
        rows.append([f"{shape[0]}x{shape[1]}", t_chain * 1e3, t_floor * 1e3, ratio,
                     st["dmd"] * 1e3, st["sensor"] * 1e3, st["reconstruct"] * 1e3,
                     "met" if ratio <= 4 else f"missed: {ratio / 4:.0f}x over"])
    lines += ["## Post-render chain vs NumPy copy floor (K = 1, delta PSF, exact Poisson)\n",
              markdown_table(["size", "chain ms", "copy floor ms", "ratio", "dmd ms", "sensor ms",
                              "reconstruct ms", "target <= 4x"], rows),
              "\nThe copy moves 3 float32 frames (memory-bound, well under 1 ns/pixel); the sensor "
              "draws an exact Poisson variate per pixel (PTRS rejection: a log, a few multiplies and "
              "a uniform pair per try) and a Gaussian, and the reconstruction is a dozen float32 "
              "NumPy passes with flags. A 4x bound would leave ~1 ns of arithmetic per pixel for the "
              "whole chain. Render-overhead rows vary by +-8 % between runs on this shared VM.\n"]
    fps = closed_loop_fps()
    rows = [[k, v * 1e3, 1 / v, "met" if (k != "flow" or 1 / v >= 30) else f"missed: {1 / v:.1f} fps"]
            for k, v in fps.items()]
    lines += ["## Closed loop without render, 368x640 (capture, reconstruct, predictor input, "
              "predictor, mask law)\n",
              markdown_table(["predictor", "ms per frame", "frames per s", "target flow >= 30 fps"], rows), ""]
    rows = []
    for shape in SIZES:
        for stage in ("render", "camera", "reconstruct", "predict"):
            m = memory(stage, shape)
            rows.append([f"{shape[0]}x{shape[1]}", stage, m["added_mb"], m["base_mb"]])
    lines += ["## Peak memory each stage adds (resident set, fresh process)\n",
              markdown_table(["size", "stage", "added MB", "process before MB"], rows), ""]
    text = "\n".join(lines)
    print(text)
    save_text(dest / "stage_performance.md", text)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.2))
    ax.bar(list(fps), [1 / v for v in fps.values()])
    ax.axhline(30, color="grey", ls="--", label="target 30 fps")
    ax.set(ylabel="frames per second", title="closed loop without render, 368x640")
    ax.legend()
    print("wrote", save_figure(fig, dest / "closed_loop_fps.png"))


if __name__ == "__main__":
    main()
