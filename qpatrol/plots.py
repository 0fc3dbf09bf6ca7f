"""Figures. One function per figure, each reading only its own data."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from qpatrol.maps import BIG, SMALL_DOT, Map  # noqa: E402


def draw_map(ax, m: Map, numbers: bool = True) -> None:
    """Walls, dots, charging stations, start cells and (optionally) state numbers."""
    rows, cols = m.shape
    ax.imshow(~m.free, cmap="Greys", vmin=-0.3, vmax=1.6, interpolation="nearest",
              extent=(-0.5, cols - 0.5, rows - 0.5, -0.5))
    r, c = m.coords[:, 0], m.coords[:, 1]
    small = m.dot_kind == SMALL_DOT
    ax.scatter(c[small], r[small], s=6, c="#d4a017", zorder=2, label="dot")
    big = m.dot_kind == BIG
    ax.scatter(c[big], r[big], s=40, c="#d4a017", edgecolors="k", linewidths=0.5, zorder=2,
               label="big dot")
    hr, hc = m.coords[m.homes, 0], m.coords[m.homes, 1]
    ax.scatter(hc, hr, marker="s", s=60, c="tab:green", zorder=3, label="charging H")
    for k, s in enumerate(m.starts):
        ax.text(m.coords[s, 1], m.coords[s, 0], str(k), ha="center", va="center",
                fontsize=9, fontweight="bold", color="tab:blue", zorder=4)
    if numbers:
        for s in range(m.n_cells):
            ax.text(c[s] + 0.42, r[s] - 0.42, str(s), ha="right", va="top", fontsize=4,
                    color="0.35", zorder=1)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_xlim(-0.5, cols - 0.5)
    ax.set_ylim(rows - 0.5, -0.5)


def plot_map(m: Map, path: str | Path) -> Path:
    """Draw a map with its state numbers to an image (format from the extension)."""
    rows, cols = m.shape
    scale = 0.38 if m.n_cells < 400 else 0.28
    fig, ax = plt.subplots(figsize=(max(4.0, cols * scale), max(3.5, rows * scale + 0.8)))
    draw_map(ax, m, numbers=m.n_cells <= 400)
    ax.set_title(f"{m.name}: {m.n_cells} free cells (small grey numbers: state)", fontsize=10)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.01), ncol=3, fontsize=8,
              frameon=False)
    fig.tight_layout()
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=150)
    plt.close(fig)
    return p


__all__ = ["draw_map", "plot_map", "np"]
