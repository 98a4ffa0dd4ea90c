"""The run's timeline figure (the paper's Fig. 7 analogue): over three frames, the sensor
exposure, the DMD window with its bit-planes, the capture's readout, the predictor + mask compute,
the mask's transfer and load, and when each mask reaches the DMD; late masks marked in red; with
a global attenuator (camera/attenuator.py), its settling after the command (red when it would
settle after the next exposure starts).

Times come from the run's MaskClock records (control/timing_budget.py) and the frame clock
(core/timing.py); the bit-planes from camera/dmd.py's Schedule. Written as
`timeline_plot.png` in the run's output folder.
"""

from __future__ import annotations

from pathlib import Path

ROWS = ("sensor exposure", "DMD window (bit-planes)", "readout (bus)", "predictor + mask",
        "mask transfer + load")


def timeline_frames(clock, init_frames: int, frames: int) -> list[int]:
    """Three consecutive frames around the first closed-loop frame (its capture's predecessor
    included, so the first mask's whole path shows)."""
    first = max(0, min(init_frames - 1, frames - 3))
    return list(range(first, min(first + 3, frames)))


def _bars(ax, y, spans, color, **kw):
    ax.broken_barh([(a * 1e3, (b - a) * 1e3) for a, b in spans if b > a], (y - 0.35, 0.7),
                   facecolors=color, **kw)


def _dmd_row(ax, y, schedule_of, shown_frames, records):
    """The window of each frame with its bit-planes (shade by plane weight), late switch marked."""
    for i in shown_frames:
        sched = schedule_of(i)
        for b, t0, t1 in sched.plane_intervals():
            shade = 0.25 + 0.6 * b / max(sched.bits - 1, 1)
            _bars(ax, y, [(t0, t1)], (shade, shade, 0.9), edgecolor="white", linewidth=0.3)
        rec = records.get(i)
        if rec and rec.get("late"):          # the part of the window that shows the previous mask
            w0, w1 = sched.window_start_s, sched.window_start_s + sched.window_s
            _bars(ax, y, [(w0, min(rec["ready_s"], w1))], (1.0, 0.0, 0.0, 0.35), hatch="////",
                  edgecolor="red", linewidth=0.5)
            ax.text(w0 * 1e3, y + 0.45, f"late {(rec['ready_s'] - w0) * 1e3:.2f} ms: previous mask",
                    color="red", fontsize=6, ha="left")


def write_timeline(out: Path, timing, clock, schedule_of, init_frames: int, frames: int,
                   attenuator_settle_s: float | None = None) -> Path:
    """Draw the timeline of three frames into out/timeline_plot.png; returns the path.
    attenuator_settle_s: the attenuator's settling time (s), drawn after each compute (None: no
    attenuator row)."""
    from poevp_optics.core.io import atomic_path
    from poevp_optics.core.runtime import pyplot

    plt = pyplot()
    shown = timeline_frames(clock, init_frames, frames)
    records = {r["frame"]: r for r in clock.records}
    fig, ax = plt.subplots(figsize=(9.0, 3.2))
    rows = ROWS + (("attenuator settle",) if attenuator_settle_s is not None else ())
    ys = {name: len(rows) - k for k, name in enumerate(rows)}
    _bars(ax, ys["sensor exposure"], [timing.exposure_window_s(i) for i in shown], "0.55")
    _dmd_row(ax, ys["DMD window (bit-planes)"], schedule_of, shown, records)
    for i in shown:
        rec = records.get(i + 1)          # the mask computed from frame i's capture
        if rec is None:
            continue
        end, c0 = rec["exposure_end_s"], rec["compute_start_s"]
        c1 = c0 + rec["compute_s"]
        _bars(ax, ys["readout (bus)"], [(end, end + clock.readout_s)], "tab:green")
        _bars(ax, ys["predictor + mask"], [(c0, c1)], "tab:orange")
        _bars(ax, ys["mask transfer + load"], [(c1, rec["ready_s"])], "tab:purple")
        if attenuator_settle_s is not None:
            late = c1 + attenuator_settle_s > timing.exposure_window_s(i + 1)[0]
            _bars(ax, ys["attenuator settle"], [(c1, c1 + attenuator_settle_s)], "red" if late else "tab:olive")
        color = "red" if rec["late"] else "tab:blue"
        ax.annotate("", xy=(max(rec["window_start_s"], rec["ready_s"]) * 1e3, ys["DMD window (bit-planes)"] - 0.35),
                    xytext=(rec["ready_s"] * 1e3, ys["mask transfer + load"] - 0.35),
                    arrowprops={"arrowstyle": "->", "color": color, "lw": 0.8})
        ax.text(c0 * 1e3, ys["mask transfer + load"] - 0.75,
                f"mask {i + 1}: slack {rec['slack_s'] * 1e3:+.2f} ms", fontsize=6, color=color)
    for i in shown:
        ax.axvline(timing.frame_start_s(i) * 1e3, color="0.8", lw=0.6, ls="--", zorder=0)
        ax.text(timing.frame_start_s(i) * 1e3, len(rows) + 0.55, f"frame {i}", fontsize=7)
    ax.set_yticks(list(ys.values()), list(ys))
    ax.set_ylim(0.0, len(rows) + 0.9)
    ax.set_xlabel("time (ms)")
    s = clock.summary()
    ax.set_title(f"budget {s['budget_s'] * 1e3:.2f} ms ({clock.spec.compute}), gap {s['gap_s'] * 1e3:.2f} ms, "
                 f"late_mask = {clock.spec.late_mask}, on-time up to {s['on_time_fps']:.1f} fps", fontsize=8)
    ax.tick_params(labelsize=7)
    fig.tight_layout()
    path = Path(out) / "timeline_plot.png"
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
    return path
