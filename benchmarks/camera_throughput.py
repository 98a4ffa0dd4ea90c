"""Post-render chain throughput (DMD + relay + sensor + reconstruct) vs a NumPy copy floor.

At 368x640 and 720x1280, with K = 1 and K = 4 radiance sub-frames, the chain of the default
scene (8-bit IMX253, exact Poisson, delta and Gaussian PSF) is timed (median of repeats, warm
kernels) beside the floor measured in the same run: a NumPy copy of the same arrays the chain
touches (K sub-frames in, one DN frame and one exposure map out).

    .venv/bin/python -m benchmarks.camera_throughput [--results]
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks.common import (add_results_flag, machine_line, markdown_table, output_folder, save_figure,
                               save_text, timed)



def measure(shape, k, psf):
    from poevp_optics.camera.camera import Camera
    from poevp_optics.scene.load import load_scene
    spec = load_scene("scenes/highbeam_plate", [f"render.resolution=[{shape[0]},{shape[1]}]",
                                                f"relay.psf='{psf}'", "relay.sigma_px=1.2"])
    cam = Camera.from_params(spec.resolved.camera)
    rng = np.random.default_rng(0)
    subs = [rng.uniform(1e14, 1e18, cam.mirror_shape).astype(np.float32) for _ in range(k)]
    mask = rng.integers(0, 256, cam.mirror_shape).astype(np.float64)
    seeds = iter(range(10**6))

    def chain():
        cap = cam.capture(subs, mask, 0, next(seeds))
        cam.reconstruct(cap, 0)

    def floor():
        _ = [s.copy() for s in subs]
        _ = subs[0].copy()
        _ = subs[0].copy()

    t_chain = timed(chain, 7)[0]
    t_floor = timed(floor, 7)[0]
    cap = cam.capture(subs, mask, 0, 1)
    return [f"{shape[0]}x{shape[1]}", k, psf, t_chain * 1e3, t_floor * 1e3, t_chain / t_floor,
            cap.seconds["dmd"] * 1e3, cap.seconds["relay"] * 1e3, cap.seconds["sensor"] * 1e3]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_results_flag(ap)
    dest = output_folder(ap.parse_args(argv).results)
    rows = []
    for shape in [(368, 640), (720, 1280)]:
        for k in (1, 4):
            for psf in ("delta", "gaussian"):
                rows.append(measure(shape, k, psf))
    header = ["size", "K", "psf", "chain ms", "NumPy copy floor ms", "ratio", "dmd ms",
              "relay ms", "sensor ms"]
    text = (f"# Post-render chain throughput\n\nDMD + relay + sensor + reconstruct (exact "
            f"Poisson, 8-bit) against a NumPy copy of the same arrays, medians of 7 warm runs, "
            f"one process. Machine: {machine_line()}.\n\n{markdown_table(header, rows)}\n")
    print(text)
    save_text(dest / "camera_throughput.md", text)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 3.5))
    labels = [f"{r[0]} K={r[1]} {r[2]}" for r in rows]
    ax.barh(labels, [r[5] for r in rows])
    ax.set_xlabel("chain time / NumPy copy floor")
    ax.set_title("post-render chain vs copy floor")
    print("wrote", save_figure(fig, dest / "camera_throughput.png"))


if __name__ == "__main__":
    main()
