"""Temporal discretisation error of K radiance sub-frames against run time.

A bright Gaussian highlight (peak 30x full well, sigma 6 px) crosses a 368x640 frame at
2000 px/s (60 px in one 30 ms exposure) behind a mask ramp; the noise-free DMD-plane exposure
with K equal sub-frames is compared with a K = 1024 reference. The time weights of each
sub-interval are exact for the PWM schedule, so the only error is the radiance sampled at K
instants. Render cost is the dominant cost of K in a real run: the table also gives the
sub-frame count x measured render time per sub-frame of the default scene (spp 16).

    python -m benchmarks.subframes_error
"""

from __future__ import annotations

import time

import numpy as np

from benchmarks.common import machine_line, markdown_table, save_figure, save_text

H, W = 368, 640


def moving_highlight(t_s, speed_px_per_s=2000.0, x0=200.0):
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    cx = x0 + speed_px_per_s * t_s
    return 1e15 + 3e17 * np.exp(-((x - cx) ** 2 + (y - H / 2) ** 2) / (2 * 6.0 ** 2))


def plane_exposure(cam, spec, k, mask):
    times = spec.subframe_times_s(0) if k == spec.render.subframes else None
    t0, t1 = spec.exposure_window_s(0)
    mids = t0 + (np.arange(k) + 0.5) * (t1 - t0) / k
    subs = [moving_highlight(t).astype(np.float32) for t in mids]
    start = time.perf_counter()
    cap = cam.capture(subs, mask, 0, seed=1)
    return cap.signal_e.astype(np.float64), time.perf_counter() - start, times


def main():
    from poevp_optics.camera import Camera
    from poevp_optics.scene import load_scene
    from poevp_optics.sensor import NoiseSwitches

    spec = load_scene("scenes/highbeam_plate", [f"render.resolution=[{H},{W}]"])
    cam = Camera(spec, NoiseSwitches(False, False, True, False, False, False))
    mask = np.tile(np.linspace(0, 255, W), (H, 1)).round()
    ref, _, _ = plane_exposure(cam, spec, 1024, mask)
    rows = []
    for k in (1, 2, 4, 8, 16, 32, 64, 128, 256):
        e, secs, _ = plane_exposure(cam, spec, k, mask)
        err = float(np.sqrt(np.mean((e - ref) ** 2)) / np.mean(ref))
        err_max = float(np.max(np.abs(e - ref)) / np.max(ref))
        rows.append([k, err, err_max, secs * 1e3])
    # render cost per sub-frame of the default scene (spp 16, warm)
    from poevp_optics.render import Renderer
    r = Renderer(spec)
    r.set_time(0.01)
    r.render_once(1, 16)
    t0 = time.perf_counter()
    for i in range(3):
        r.render_once(2 + i, 16)
    per_sub = (time.perf_counter() - t0) / 3
    for row in rows:
        row.append(row[0] * per_sub)
    header = ["K", "rel. RMS error", "max error / peak", "camera ms", "render s (K x spp16)"]
    text = (f"# Sub-frame (K) error against run time\n\nMoving highlight, 60 px per exposure, "
            f"mask ramp, reference K = 1024. Machine: {machine_line()}.\n\n"
            f"{markdown_table(header, rows)}\n\nFitted slope of log error vs log K: "
            f"{np.polyfit(np.log([r[0] for r in rows[2:]]), np.log([r[1] for r in rows[2:]]), 1)[0]:.2f} "
            f"(midpoint sampling of a smooth motion: -2 expected once K resolves the motion).\n")
    print(text)
    save_text("subframes_error.md", text)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    ax.loglog([r[4] for r in rows], [r[1] for r in rows], "o-")
    for r in rows:
        ax.annotate(f"K={r[0]}", (r[4], r[1]), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xlabel("render time of K sub-frames at spp 16 (s)")
    ax.set_ylabel("relative RMS error of the exposure")
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title("temporal discretisation error vs run time")
    print("wrote", save_figure(fig, "subframes_error.png"))


if __name__ == "__main__":
    main()
