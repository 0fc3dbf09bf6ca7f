"""Drawing a patrol graph map (``qpatrol maps show NAME --png FILE`` on a graph)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402

from qpatrol.maps import BIG, SMALL_DOT, Map  # noqa: E402
from qpatrol.util import atomic  # noqa: E402

__all__ = ["draw_graph_map", "plot_graph_map"]


def draw_graph_map(ax, m: Map, numbers: bool = True) -> None:
    """Edges as lines, waypoints as small grey dots, vertices as circles (gold where they
    hold a dot, larger with a black rim for a big dot, white without one), charging stations
    as green squares and start vertices with their agent's number in bold blue (in a
    larger white circle, the dot they hold hidden behind it), as
    :func:`qpatrol.study.plots.draw_map` marks a grid. Drawn at ``m.xy`` (y up)."""
    n = m.n_targets
    xy = m.xy
    span = float(np.ptp(xy, axis=0).max()) or 1.0
    # every unit move is a segment: neighbours of each cell, each pair once
    c, p = np.nonzero(m.neighbors >= 0)
    nb = m.neighbors[c, p]
    keep = c < nb
    segs = np.stack([xy[c[keep]], xy[nb[keep]]], axis=1)
    ax.add_collection(LineCollection(segs, colors="0.6", linewidths=1.2, zorder=1))
    way = np.arange(n, m.n_cells)
    if way.size:
        ax.scatter(xy[way, 0], xy[way, 1], s=4, c="0.45", zorder=2, label="waypoint")
    size = 90 if n <= 60 else 45 if n <= 200 else 20
    dot = m.dot_kind[:n]
    plain = dot == 0
    for mask, face, s, rim, label in (
        (dot == SMALL_DOT, "#d4a017", size, "0.25", "vertex with a dot"),
        (dot == BIG, "#d4a017", size * 1.8, "k", "big dot"),
        (plain & ~np.isin(np.arange(n), m.homes), "white", size, "0.25", "vertex, no dot"),
    ):
        if mask.any():
            ax.scatter(
                xy[:n][mask, 0],
                xy[:n][mask, 1],
                s=s,
                c=face,
                edgecolors=rim,
                linewidths=0.8 if rim == "k" else 0.5,
                zorder=3,
                label=label,
            )
    if len(m.homes):
        ax.scatter(
            xy[m.homes, 0],
            xy[m.homes, 1],
            marker="s",
            s=size * 1.3,
            c="tab:green",
            edgecolors="k",
            linewidths=0.5,
            zorder=4,
            label="charging H",
        )
    if len(m.starts):
        ax.scatter(
            xy[m.starts, 0],
            xy[m.starts, 1],
            s=size * 2.2,
            c="white",
            edgecolors="tab:blue",
            linewidths=1.2,
            zorder=4,
            label="start k (holds a dot)",
        )
    for k, s in enumerate(m.starts):
        ax.text(
            xy[s, 0],
            xy[s, 1],
            str(k),
            ha="center",
            va="center",
            fontsize=9 if n <= 200 else 7,
            fontweight="bold",
            color="tab:blue",
            zorder=5,
        )
    if numbers:
        off = 0.012 * span
        for v in range(n):
            ax.text(
                xy[v, 0] + off,
                xy[v, 1] + off,
                str(v),
                ha="left",
                va="bottom",
                fontsize=5,
                color="0.35",
                zorder=6,
            )
    ax.set_aspect("equal")
    pad = 0.04 * span
    ax.set_xlim(xy[:, 0].min() - pad, xy[:, 0].max() + pad)
    ax.set_ylim(xy[:, 1].min() - pad, xy[:, 1].max() + pad)
    ax.set_xticks([])
    ax.set_yticks([])


def plot_graph_map(m: Map, path: str | Path) -> Path:
    """Draw a graph map with its vertex numbers to an image (format from the extension)."""
    w, h = np.ptp(m.xy, axis=0) + 1e-9
    width = 8.0
    height = float(np.clip(width * h / w, 3.0, 10.0)) + 0.9
    fig, ax = plt.subplots(figsize=(width, height))
    draw_graph_map(ax, m, numbers=m.n_targets <= 400)
    moves = int(m.edges[:, 2].sum()) if len(m.edges) else 0
    ax.set_title(
        f"{m.name}: {m.n_targets} vertices, {len(m.edges)} edges of {moves} moves "
        f"({m.n_cells} cells; small grey numbers: vertex)",
        fontsize=10,
    )
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.01), ncol=5, fontsize=8, frameon=False)
    fig.tight_layout()
    p = Path(path)
    try:
        with atomic.staged_file(p) as tmp:
            fmt = p.suffix.lstrip(".").lower() or "png"
            fig.savefig(tmp, dpi=150, format=fmt, bbox_inches="tight", pad_inches=0.1)
    finally:
        plt.close(fig)
    return p
