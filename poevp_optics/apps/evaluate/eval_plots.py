"""`poevp evaluate`'s figures: accuracy vs speed (one panel per E), accuracy vs E, a frame strip at
the speed where the predictors separate, plate crops with local-entropy maps (paper Sec. 5C).
Error bars: Wilson 95 % intervals (analysis/statistics.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from poevp_optics.analysis.metrics import local_entropy
from poevp_optics.core.io import atomic_path

STYLE = {"ldr": ("0.5", ":"), "fusion_classic": ("tab:brown", "--"), "fusion_deghost": ("tab:pink", "--"),
         "hold": ("tab:red", "-"), "flow": ("tab:blue", "-"), "dmvfn": ("tab:green", "-"),
         "dmvfn_lite": ("tab:olive", "-"), "track": ("tab:cyan", "-"), "track_net": ("tab:purple", "-"),
         "oracle": ("k", "-")}


def _save(fig, path: Path, plt) -> None:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _line(ax, xs, cells, method, key_of):
    pts = [(x, cells.get(key_of(x))) for x in xs]
    pts = [(x, c) for x, c in pts if c]
    if not pts:
        return
    x = np.array([p[0] for p in pts], dtype=float)
    y = np.array([c["alpr"]["pct"] for _, c in pts])
    lo = y - np.array([c["alpr"]["ci95"][0] for _, c in pts])
    hi = np.array([c["alpr"]["ci95"][1] for _, c in pts]) - y
    col, ls = STYLE.get(method, ("tab:gray", "-"))
    ax.errorbar(x, y, yerr=[lo, hi], color=col, ls=ls, marker="o", ms=3, capsize=2, lw=1.2, label=method)


def accuracy_plots(out: Path, cells: dict, cfg) -> None:
    """accuracy_vs_speed.png (panel per E) and accuracy_vs_E.png, ALPR accuracy with 95 % bars."""
    from poevp_optics.core.runtime import pyplot

    plt = pyplot()
    n = len(cfg.e_levels)
    fig, axes = plt.subplots(1, n, figsize=(4.6 * n, 3.6), squeeze=False, sharey=True)
    for ax, e in zip(axes[0], cfg.e_levels):
        for m in cfg.methods:
            _line(ax, cfg.speeds_px, cells, m, lambda v: f"lateral|{float(v):g}|{float(e):g}|{m}")
        ax.set_title(f"E = {e:g}", fontsize=9)
        ax.set_xlabel("plate speed (px/frame)")
        ax.set_xscale("log")
        ax.set_ylim(-3, 103)
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("full-ALPR accuracy (%)")
    axes[0, -1].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    _save(fig, out / "accuracy_vs_speed.png", plt)
    fig, ax = plt.subplots(figsize=(4.8, 3.6))
    for m in cfg.methods:
        _line(ax, cfg.e_sweep, cells, m, lambda e: f"lateral|{float(cfg.e_speed_px):g}|{float(e):g}|{m}")
    ax.set_xscale("log")
    ax.set_xlabel("over-exposure E (plate peak / saturation - 1)")
    ax.set_ylabel("full-ALPR accuracy (%)")
    ax.set_title(f"lateral, {cfg.e_speed_px:g} px/frame", fontsize=9)
    ax.set_ylim(-3, 103)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, out / "accuracy_vs_E.png", plt)


def strip_plot(path: Path, crops: dict, title: str) -> None:
    """Rows: methods; columns: scored frames; crops {method: {t: 8-bit crop}}."""
    from poevp_optics.core.runtime import pyplot

    plt = pyplot()
    methods = list(crops)
    frames = sorted({t for m in methods for t in crops[m]})
    fig, axes = plt.subplots(len(methods), len(frames), figsize=(1.9 * len(frames), 0.75 * len(methods) + 0.4),
                             squeeze=False)
    for i, m in enumerate(methods):
        for j, t in enumerate(frames):
            ax = axes[i, j]
            if t in crops[m]:
                ax.imshow(crops[m][t], cmap="gray", vmin=0, vmax=255)
            ax.set_xticks([])
            ax.set_yticks([])
            if j == 0:
                ax.set_ylabel(m, fontsize=7, rotation=0, ha="right", va="center")
            if i == 0:
                ax.set_title(f"t = {t}", fontsize=7)
    fig.suptitle(title, fontsize=8)
    fig.tight_layout()
    _save(fig, path, plt)


def entropy_examples(path: Path, crops: dict) -> None:
    """One plate crop per method and its local-entropy map (paper Sec. 5C, 9x9 windows)."""
    from poevp_optics.core.runtime import pyplot

    plt = pyplot()
    n = len(crops)
    fig, axes = plt.subplots(2, n, figsize=(2.2 * n, 2.2), squeeze=False)
    for j, (m, c) in enumerate(crops.items()):
        axes[0, j].imshow(c, cmap="gray", vmin=0, vmax=255)
        axes[0, j].set_title(m, fontsize=8)
        axes[1, j].imshow(local_entropy(c), cmap="magma", vmin=0, vmax=6)
        for a in axes[:, j]:
            a.axis("off")
    axes[1, 0].set_title("local entropy (bits)", fontsize=7)
    fig.tight_layout()
    _save(fig, path, plt)
