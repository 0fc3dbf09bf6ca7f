"""Figures. One function per figure, each reading only its own CSV.

Every ``figure_*``/``gamma``/``team_size`` function takes the CSV written by the
matching function of :mod:`qpatrol.study.figures` and an output path; the image format
follows the extension (``.png`` by default, ``.svg`` and ``.pdf`` too; Fig. 5's
animation is a ``.gif``). Each returns the path(s) it wrote.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter  # noqa: E402

from qpatrol.maps import BIG, SMALL_DOT, Map, get_map  # noqa: E402
from qpatrol.util import atomic  # noqa: E402
from qpatrol.util.csvio import read_csv  # noqa: E402

if TYPE_CHECKING:
    from matplotlib.figure import Figure

#: colours of the actions/directions, used by every Q-value figure.
DIR_COLOURS = {"N": "tab:green", "E": "tab:orange", "S": "tab:purple", "W": "tab:blue"}
DIRECTIONS = {"N": "North", "E": "East", "S": "South", "W": "West"}
#: one colour per agent (Fig. 5, 6), colour-blind friendly first four.
AGENT_COLOURS = (
    "#e6194b",
    "#3cb44b",
    "#4363d8",
    "#f58231",
    "#911eb4",
    "#42d4f4",
    "#f032e6",
    "#9a6324",
)
COMM_STYLE = {
    True: ("tab:blue", "o", "communication on"),
    False: ("tab:red", "s", "communication off"),
}


def draw_map(ax, m: Map, numbers: bool = True, dots: bool = True, starts: bool = True) -> None:
    """Walls, dots, charging stations, start cells and (optionally) state numbers."""
    rows, cols = m.shape
    ax.imshow(
        ~m.free,
        cmap="Greys",
        vmin=-0.3,
        vmax=1.6,
        interpolation="nearest",
        extent=(-0.5, cols - 0.5, rows - 0.5, -0.5),
    )
    r, c = m.coords[:, 0], m.coords[:, 1]
    if dots:
        small = m.dot_kind == SMALL_DOT
        ax.scatter(c[small], r[small], s=6, c="#d4a017", zorder=2, label="dot")
        big = m.dot_kind == BIG
        ax.scatter(
            c[big],
            r[big],
            s=40,
            c="#d4a017",
            edgecolors="k",
            linewidths=0.5,
            zorder=2,
            label="big dot",
        )
    hr, hc = m.coords[m.homes, 0], m.coords[m.homes, 1]
    ax.scatter(hc, hr, marker="s", s=60, c="tab:green", zorder=3, label="charging H")
    if starts:
        for k, s in enumerate(m.starts):
            ax.text(
                m.coords[s, 1],
                m.coords[s, 0],
                str(k),
                ha="center",
                va="center",
                fontsize=9,
                fontweight="bold",
                color="tab:blue",
                zorder=4,
            )
    if numbers:
        for s in range(m.n_cells):
            ax.text(
                c[s] + 0.42,
                r[s] - 0.42,
                str(s),
                ha="right",
                va="top",
                fontsize=4,
                color="0.35",
                zorder=1,
            )
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_xlim(-0.5, cols - 0.5)
    ax.set_ylim(rows - 0.5, -0.5)


def plot_map(m: Map, path: str | Path) -> Path:
    """Draw a map with its state numbers to an image (format from the extension)."""
    if m.is_graph:
        from qpatrol.study.graphplot import plot_graph_map

        return plot_graph_map(m, path)
    rows, cols = m.shape
    scale = 0.38 if m.n_cells < 400 else 0.28
    fig, ax = plt.subplots(figsize=(max(4.0, cols * scale), max(3.5, rows * scale + 0.8)))
    draw_map(ax, m, numbers=m.n_cells <= 400)
    ax.set_title(f"{m.name}: {m.n_cells} free cells (small grey numbers: state)", fontsize=10)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.01), ncol=3, fontsize=8, frameon=False)
    fig.tight_layout()
    p = Path(path)
    try:
        with atomic.staged_file(p) as tmp:
            fig.savefig(tmp, dpi=150, format=p.suffix.lstrip(".").lower() or "png")
    finally:
        plt.close(fig)
    return p


def check_image_path(path: str | Path, extra: tuple[str, ...] = ()) -> None:
    """Raise ValueError (one line) unless ``path`` has an image extension we can write."""
    fig = plt.figure()
    try:
        formats = set(fig.canvas.get_supported_filetypes()) | set(extra)
    finally:
        plt.close(fig)
    ext = Path(path).suffix.lstrip(".").lower()
    if ext not in formats:
        raise ValueError(
            f"{path}: unknown image format {('.' + ext) if ext else '(no extension)'}; "
            f"allowed: {', '.join('.' + f for f in sorted(formats))}"
        )


# --- helpers ---------------------------------------------------------------------------


def _save(fig, out: str | Path, dpi: int = 150) -> Path:
    p = Path(out)
    if not p.suffix:
        p = p.with_suffix(".png")
    try:
        with atomic.staged_file(p) as tmp:
            fig.savefig(
                tmp,
                dpi=dpi,
                bbox_inches="tight",
                pad_inches=0.1,
                format=p.suffix.lstrip(".").lower(),
            )
    finally:
        plt.close(fig)
    return p


def _fmt_num(x: float) -> str:
    return f"{x:g}"


def _read(csv: str | Path, columns: list[str]) -> pd.DataFrame:
    df = read_csv(csv)
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ValueError(f"{csv}: missing column(s) {', '.join(missing)}")
    return df


def _choice_marks(ax, df: pd.DataFrame, x: str = "update") -> None:
    """Filled markers on the W/E curves at the updates where that action was taken,
    and a strip of ticks under the axis for every action taken."""
    for letter, col in (("W", "q_west"), ("E", "q_east")):
        sel = df[df["action"] == letter]
        ax.scatter(
            sel[x],
            sel[col],
            s=14,
            color=DIR_COLOURS[letter],
            edgecolors="k",
            linewidths=0.4,
            zorder=4,
        )
    trans = ax.get_xaxis_transform()
    for letter in "NESW":
        sel = df[df["action"] == letter]
        if len(sel):
            ax.scatter(
                sel[x],
                np.full(len(sel), 0.035),
                marker="|",
                s=40,
                transform=trans,
                color=DIR_COLOURS[letter],
                zorder=5,
            )


def _log_y(ax, label: str, subs: tuple[float, ...] = (1.0, 2.0, 5.0)) -> None:
    """Log y-axis with plain-number tick labels (1, 2, 5 per decade by default)."""
    ax.set_yscale("log")
    ax.yaxis.set_major_locator(LogLocator(base=10, subs=subs))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda y, _: f"{y:g}"))
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_ylabel(label)


def _room_below(ax, values: np.ndarray, frac: float = 0.12) -> None:
    """Log y-limits that leave the bottom ``frac`` of the axes free for the tick strip."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v) & (v > 0)]
    if not v.size:
        return
    lo, hi = float(v.min()), float(v.max())
    span = max(np.log10(hi / lo), np.log10(3.0))
    ax.set_ylim(lo / 10 ** (span * frac / (1 - frac - 0.04)), hi * 10 ** (span * 0.04))


def _choice_legend(actions: set[str]) -> tuple[list, list[str]]:
    """Legend entries explaining the dots on the curves and the strip of ticks."""
    handles = [plt.Line2D([], [], ls="", marker="o", mfc="w", mec="k", ms=4)]
    labels = ["dot: W/E taken at that update"]
    for a in "NESW":
        if a in actions:
            handles.append(plt.Line2D([], [], ls="", marker="|", color=DIR_COLOURS[a], ms=8))
            labels.append(f"tick: {DIRECTIONS[a]} taken")
    return handles, labels


def _choice_counts(df: pd.DataFrame) -> str:
    counts = df["action"].value_counts()
    return ", ".join(f"{a} {int(counts[a])}" for a in "NESW" if a in counts)


# --- Fig. 2 ------------------------------------------------------------------------------


def figure_2(csv: str | Path, out: str | Path) -> Path:
    """Q(34, West) and Q(34, East) over the first updates, one panel per multiplier."""
    df = _read(csv, ["multiplier", "update", "q_west", "q_east", "action", "heading", "cell"])
    mults = sorted(df["multiplier"].unique())
    ncols = 2 if len(mults) > 1 else 1
    nrows = int(np.ceil(len(mults) / ncols))
    fig, axes = plt.subplots(nrows, ncols, figsize=(5.2 * ncols, 3.4 * nrows), squeeze=False)
    xmax = int(df["update"].max()) + 1
    for ax, mult in zip(axes.flat, mults, strict=False):
        d = df[df["multiplier"] == mult].sort_values("update")
        ax.plot(d["update"], d["q_west"], color=DIR_COLOURS["W"], lw=1.4, label="Q(s, West)")
        ax.plot(d["update"], d["q_east"], color=DIR_COLOURS["E"], lw=1.4, label="Q(s, East)")
        _choice_marks(ax, d)
        _log_y(ax, "Q-value (log scale)")
        _room_below(ax, d[["q_west", "q_east"]].to_numpy())
        ax.set_title(f"initial Q x{_fmt_num(mult)}  (choices: {_choice_counts(d)})", fontsize=9)
        ax.grid(alpha=0.3, lw=0.4)
        ax.set_xlim(0, xmax)
        ax.set_xlabel("update of the state (n-th time it is left)")
    for ax in axes.flat[len(mults) :]:
        ax.set_visible(False)
    h = df["heading"].iloc[0]
    cell = int(df["cell"].iloc[0])
    where = f" of {df['map'].iloc[0]}" if "map" in df.columns else ""
    handles, labels = axes.flat[0].get_legend_handles_labels()
    extra = _choice_legend(set(df["action"]))
    fig.legend(
        handles + extra[0],
        labels + extra[1],
        loc="lower center",
        ncol=7,
        fontsize=8,
        frameon=False,
        bbox_to_anchor=(0.5, -0.01),
        handletextpad=0.3,
    )
    fig.suptitle(
        f"Fig. 2: Q-values of West and East at state {cell}{where} (arrived heading {h}), "
        f"first {int(df['update'].max())} updates, per multiplier of the initial Q",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    return _save(fig, out)


# --- Fig. 3 and 4 -------------------------------------------------------------------------


def figure_3(csv: str | Path, out: str | Path, label: str = "Fig. 3") -> Path:
    """r, gamma max Q(s', a), Q(s, West) and Q(s, East) over the first updates of a state."""
    df = _read(csv, ["update", "reward", "bootstrap", "q_west", "q_east", "action", "heading"])
    df = df.sort_values("update")
    fig, (top, bottom) = plt.subplots(
        2, 1, figsize=(7.5, 5.6), sharex=True, gridspec_kw={"height_ratios": [1, 1.2]}
    )
    top.plot(
        df["update"], df["reward"], color="tab:green", lw=1.2, marker=".", ms=4, label="reward r"
    )
    top.plot(
        df["update"],
        df["bootstrap"],
        color="0.2",
        lw=1.2,
        ls="--",
        label=r"$\gamma\,\max_a Q(s', a)$",
    )
    _log_y(top, "reward / target term (log)")
    top.legend(fontsize=8, loc="upper right", ncol=2)
    top.grid(alpha=0.3, lw=0.4)
    bottom.plot(df["update"], df["q_west"], color=DIR_COLOURS["W"], lw=1.4, label="Q(s, West)")
    bottom.plot(df["update"], df["q_east"], color=DIR_COLOURS["E"], lw=1.4, label="Q(s, East)")
    _choice_marks(bottom, df)
    _log_y(bottom, "Q-value (log scale)")
    _room_below(bottom, df[["q_west", "q_east"]].to_numpy())
    bottom.grid(alpha=0.3, lw=0.4)
    bottom.set_xlabel("update of the state (n-th time it is left)")
    handles, labels = bottom.get_legend_handles_labels()
    extra = _choice_legend(set(df["action"]))
    bottom.legend(handles + extra[0], labels + extra[1], fontsize=7.5, loc="upper right", ncol=2)
    bottom.set_xlim(0, max(1, df["update"].max()) + 1)
    cell = int(df["cell"].iloc[0]) if "cell" in df.columns else "?"
    where = f" of {df['map'].iloc[0]}" if "map" in df.columns else ""
    gamma = f", gamma {_fmt_num(df['gamma'].iloc[0])}" if "gamma" in df.columns else ""
    fig.suptitle(
        f"{label}: state {cell}{where} (arrived heading {df['heading'].iloc[0]}), "
        f"first {len(df)} updates{gamma}\nchoices: {_choice_counts(df)}",
        fontsize=10,
    )
    fig.tight_layout()
    return _save(fig, out)


def figure_4(csv: str | Path, out: str | Path) -> Path:
    """Fig. 4: the plot of :func:`figure_3` for state 34 of map B."""
    return figure_3(csv, out, label="Fig. 4")


# --- gamma (§4) -----------------------------------------------------------------------------


def _errorbar(ax, x, mean, lo, hi, **kw):
    yerr = np.vstack([mean - lo, hi - mean])
    yerr = np.where(np.isfinite(yerr), yerr, 0.0)
    return ax.errorbar(x, mean, yerr=yerr, capsize=3, **kw)


def gamma(csv: str | Path, out: str | Path) -> Path:
    """First episode per gamma: steps to eat all dots, against the shortest walk; states seen."""
    df = _read(
        csv,
        [
            "gamma",
            "steps_mean",
            "steps_lo",
            "steps_hi",
            "distinct_states_mean",
            "lower_bound",
            "tour",
            "n",
        ],
    )
    df = df.sort_values("gamma")
    fig, (a, b) = plt.subplots(1, 2, figsize=(11.5, 4.6))
    _errorbar(
        a,
        df["gamma"],
        df["steps_mean"],
        df["steps_lo"],
        df["steps_hi"],
        color="tab:blue",
        marker="o",
        label="mean over complete runs, 95% t-interval",
    )
    if "steps_median" in df.columns:
        a.plot(
            df["gamma"],
            df["steps_median"],
            ls="",
            marker="_",
            ms=12,
            mew=1.5,
            color="tab:blue",
            label="median",
        )
    if "steps_min" in df.columns:
        a.plot(
            df["gamma"],
            df["steps_min"],
            ls="",
            marker="v",
            ms=5,
            color="tab:cyan",
            label="best run",
        )
    cut = df["truncated"] if "truncated" in df.columns else pd.Series(0, index=df.index)
    cap = df["max_episode_steps"] if "max_episode_steps" in df.columns else None
    if cap is not None and (cut > 0).any():
        sel = (cut > 0) & cap.notna()
        a.plot(
            df.loc[sel, "gamma"],
            cap[sel],
            ls="",
            marker="^",
            ms=8,
            color="tab:red",
            label="episode cut at max_episode_steps (runs cut/runs)",
        )
        for g, c, t, n in zip(
            df.loc[sel, "gamma"], cap[sel], cut[sel], df.loc[sel, "n"] + cut[sel], strict=True
        ):
            a.annotate(
                f"{int(t)}/{int(n)}",
                (g, c),
                textcoords="offset points",
                xytext=(0, 7),
                ha="center",
                fontsize=7,
                color="tab:red",
            )
    lb, tour = int(df["lower_bound"].iloc[0]), int(df["tour"].iloc[0])
    a.axhline(tour, color="k", ls="--", lw=1, label=f"computed tour: {tour} moves")
    a.axhline(lb, color="0.4", ls=":", lw=1.2, label=f"lower bound: {lb} moves")
    _log_y(a, "team steps to eat every dot (1st episode, log)")
    top = np.nanmax(
        np.r_[
            df["steps_hi"].to_numpy(float),
            df["steps_mean"].to_numpy(float),
            cap.to_numpy(float) if cap is not None else [],
            tour,
        ]
    )
    a.set_ylim(lb / 1.6, top * 2.5)
    a.set_xlabel(r"discount factor $\gamma$")
    a.set_title("Steps of the first episode vs the shortest dot-eating walk", fontsize=10)
    a.legend(fontsize=7.5, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, frameon=False)
    a.grid(alpha=0.3, lw=0.4)

    _errorbar(
        b,
        df["gamma"],
        df["distinct_states_mean"],
        df["distinct_states_lo"],
        df["distinct_states_hi"],
        color="tab:purple",
        marker="o",
        label="(cell, heading) states",
    )
    if "distinct_cells_mean" in df.columns:
        _errorbar(
            b,
            df["gamma"],
            df["distinct_cells_mean"],
            df["distinct_cells_lo"],
            df["distinct_cells_hi"],
            color="tab:green",
            marker="s",
            label="cells",
        )
    if "states" in df.columns:
        b.axhline(
            int(df["states"].iloc[0]),
            color="tab:purple",
            ls=":",
            lw=1,
            label=f"(cell, heading) pairs of the map: {int(df['states'].iloc[0])}",
        )
    if "cells" in df.columns:
        b.axhline(
            int(df["cells"].iloc[0]),
            color="k",
            ls="--",
            lw=1,
            label=f"free cells of the map: {int(df['cells'].iloc[0])}",
        )
    b.set_ylim(bottom=0)
    b.set_xlabel(r"discount factor $\gamma$")
    b.set_ylabel("distinct states entered (1st episode)")
    b.set_title("Exploration in the first episode (truncated ones included)", fontsize=10)
    b.legend(fontsize=7.5, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, frameon=False)
    b.grid(alpha=0.3, lw=0.4)
    for ax in (a, b):
        ax.set_xticks(df["gamma"])
    n = df["runs"] if "runs" in df.columns else df["n"]
    runs = f"{int(n.min())}" if n.min() == n.max() else f"{int(n.min())}-{int(n.max())}"
    where = f"{df['map'].iloc[0]}, " if "map" in df.columns else ""
    fig.suptitle(
        f"Discount factor and the first episode ({where}one agent, {runs} runs per "
        r"$\gamma$; mean and 95% t-interval over runs)",
        fontsize=11,
    )
    fig.tight_layout()
    return _save(fig, out)


# --- team size --------------------------------------------------------------------------------


def team_size(csv: str | Path, out: str | Path) -> Path:
    """Average idleness and division of labour vs team size, communication on and off."""
    df = _read(csv, ["agents", "communication", "avg_idleness_mean", "division_of_labour_mean"])
    df["communication"] = df["communication"].astype(str).str.lower().isin(["true", "1", "on"])
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    ks = sorted(df["agents"].unique())
    offsets = {True: -0.03, False: 0.03}
    for comm in (True, False):
        d = df[df["communication"] == comm].sort_values("agents")
        if d.empty:
            continue
        colour, marker, label = COMM_STYLE[comm]
        x = d["agents"] * 2 ** offsets[comm]
        m = "avg_idleness"
        _errorbar(
            a,
            x,
            d[f"{m}_mean"],
            d[f"{m}_lo"],
            d[f"{m}_hi"],
            color=colour,
            marker=marker,
            label=label,
        )
        m = "division_of_labour"
        _errorbar(
            b,
            x,
            d[f"{m}_mean"],
            d[f"{m}_lo"],
            d[f"{m}_hi"],
            color=colour,
            marker=marker,
            label=label,
        )
    xs = np.geomspace(min(ks), max(ks) * 1.1, 100)
    b.plot(xs, 1 / xs, color="0.4", ls=":", label="1/K (no division)")
    b.axhline(1.0, color="0.6", lw=0.8, ls="--", label="1 (full partition)")
    a.set_ylabel("average idleness (team steps)")
    a.set_title("Average idleness vs team size (mean over runs, 95% t-interval)", fontsize=10)
    b.set_ylabel("division of labour (share of top visitor)")
    b.set_title("Division of labour vs team size", fontsize=10)
    b.set_ylim(0, 1.05)
    for ax in (a, b):
        ax.set_xscale("log", base=2)
        ax.set_xticks(ks, [str(k) for k in ks])
        ax.minorticks_off()
        ax.set_xlabel("team size K (agents)")
        ax.grid(alpha=0.3, lw=0.4)
        ax.legend(fontsize=8)
    a.set_ylim(bottom=0)
    where = f"{df['map'].iloc[0]}, " if "map" in df.columns else ""
    runs = f"{int(df['runs'].min())} runs per point; " if "runs" in df.columns else ""
    fig.suptitle(
        f"Team size and communication ({where}{runs}the paper's learner, battery on, "
        "measures after warm-up)",
        fontsize=10,
    )
    fig.tight_layout()
    return _save(fig, out)


# --- Fig. 6 ----------------------------------------------------------------------------------


ARROW = {"N": (0.0, -1.0), "E": (1.0, 0.0), "S": (0.0, 1.0), "W": (-1.0, 0.0)}


def figure_6(csv: str | Path, out: str | Path) -> Path:
    """Agent 0's greedy action per cell over its visit map; beside it, its share of visits."""
    df = _read(csv, ["row", "col", "action", "visits_agent", "visits_all", "updates"])
    rows, cols = int(df["row"].max()) + 2, int(df["col"].max()) + 2
    r, c = df["row"].to_numpy(), df["col"].to_numpy()
    visits = np.full((rows, cols), np.nan)
    visits[r, c] = df["visits_agent"]
    share = np.full((rows, cols), np.nan)
    share[r, c] = df["visits_agent"] / df["visits_all"].where(df["visits_all"] > 0)
    wall = np.ones((rows, cols))
    wall[r, c] = np.nan
    k = int(df["agents"].iloc[0]) if "agents" in df.columns else None
    learnt = df["updates"].to_numpy() > 0
    u = np.array([ARROW[a][0] for a in df["action"]]) * 0.62
    v = np.array([ARROW[a][1] for a in df["action"]]) * 0.62
    cell_in = 0.25
    fig, axes = plt.subplots(1, 2, figsize=(cell_in * cols * 2 + 3.0, cell_in * rows + 1.3))
    fair = 1.0 / k if k else 0.5
    panels = (
        (
            visits,
            "viridis",
            (0, np.nanmax(visits) if np.isfinite(visits).any() else 1),
            "visits by agent 0 (cell entries)",
            "agent 0's visit counts",
        ),
        (
            share,
            "RdBu_r",
            (0, min(1.0, 2 * fair)),
            f"agent 0's share of the team's visits (white: 1/K = {fair:.2g}; "
            f"darkest red: {min(1.0, 2 * fair):.2g} or more)",
            "agent 0's share of all visits (red: more than 1/K)",
        ),
    )
    extent = (-0.5, cols - 0.5, rows - 0.5, -0.5)
    for ax, (img, cmap, (vmin, vmax), clabel, title) in zip(axes, panels, strict=True):
        ax.imshow(wall, cmap="Greys", vmin=0, vmax=4, extent=extent, interpolation="nearest")
        im = ax.imshow(img, cmap=cmap, vmin=vmin, vmax=vmax, extent=extent, interpolation="nearest")
        ax.quiver(
            c[learnt],
            r[learnt],
            u[learnt],
            v[learnt],
            angles="xy",
            scale_units="xy",
            scale=1,
            pivot="middle",
            units="xy",
            width=0.1,
            headwidth=3.2,
            headlength=3.0,
            headaxislength=2.6,
            color="w",
            edgecolor="k",
            linewidth=0.5,
        )
        if (~learnt).any():
            ax.scatter(c[~learnt], r[~learnt], marker="x", s=14, color="k", linewidths=0.9)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_xlim(-0.5, cols - 0.5)
        ax.set_ylim(rows - 0.5, -0.5)
        ax.set_title(title, fontsize=9)
        cb = fig.colorbar(im, ax=ax, fraction=0.035, pad=0.02)
        cb.set_label(clabel, fontsize=8)
        cb.ax.tick_params(labelsize=7)
    what = ""
    if "map" in df.columns:
        what = f" on {df['map'].iloc[0]}"
    if k and "episodes" in df.columns:
        what += f", team of {k}, after {int(df['episodes'].iloc[0])} episodes"
    note = "arrow: greedy action (max Q over non-wall moves) at the heading the cell is most often"
    note += " reached with"
    if (~learnt).any():
        note += "; x: never left while patrolling"
    fig.suptitle(f"Fig. 6: behaviour policy of agent 0{what}\n{note}", fontsize=9.5)
    fig.tight_layout()
    return _save(fig, out)


# --- Fig. 5 -----------------------------------------------------------------------------------


def figure_5(
    csv: str | Path,
    out: str | Path,
    still: str | Path | None = None,
    map: str | Map | None = None,
    frames: int = 180,
    trail: int = 8,
    fps: int = 8,
    dpi: int = 90,
    run: int | None = None,
) -> tuple[Path, Path]:
    """Animated GIF of the team patrolling (and a still PNG of its last frame).

    Each agent is a coloured disc with a fading trail of its last ``trail`` cells; a
    hollow disc is homing or charging (when the CSV has a ``mode`` column). The maze
    comes from the ``map`` argument or the CSV's ``map`` column. The GIF shows the
    first ``frames`` steps of the CSV (of run ``run``, default the first, if it has a
    ``run`` column); ``still`` defaults to ``out`` with a ``.png`` suffix.
    """
    df = _read(csv, ["step", "agent", "row", "col"])
    if "run" in df.columns:  # a trajectory of several runs: show the first (or ``run``)
        df = df[df["run"] == (df["run"].min() if run is None else run)]
    if map is None:
        if "map" not in df.columns:
            raise ValueError(f"{csv}: no map column; pass map=")
        map = str(df["map"].iloc[0])
    m = map if isinstance(map, Map) else get_map(map)
    steps = np.sort(df["step"].unique())[:frames]
    df = df[df["step"].isin(steps)].sort_values(["step", "agent"])
    k = int(df["agent"].max()) + 1
    pos = np.stack([df["col"].to_numpy(), df["row"].to_numpy()], axis=1).reshape(len(steps), k, 2)
    busy = np.zeros((len(steps), k), dtype=bool)
    if "mode" in df.columns:
        busy = (df["mode"].to_numpy() != "patrol").reshape(len(steps), k)

    rows, cols = m.shape
    fig, ax = plt.subplots(figsize=(cols * 0.25 + 0.4, rows * 0.25 + 0.9))
    draw_map(ax, m, numbers=False, dots=False, starts=False)
    colours = [AGENT_COLOURS[i % len(AGENT_COLOURS)] for i in range(k)]
    trails = []
    for _ in range(k):
        lc = LineCollection([], linewidths=4, capstyle="round", zorder=5)
        ax.add_collection(lc)
        trails.append(lc)
    discs = ax.scatter(
        pos[0, :, 0], pos[0, :, 1], s=110, c=colours, edgecolors="k", linewidths=0.8, zorder=6
    )
    title = ax.set_title("", fontsize=9)
    handles = [
        plt.Line2D([], [], ls="", marker="o", mfc=colours[i], mec="k", ms=7, label=f"agent {i}")
        for i in range(k)
    ]
    handles.append(
        plt.Line2D([], [], ls="", marker="s", mfc="tab:green", mec="none", ms=7, label="charging H")
    )
    if busy.any():
        handles.append(
            plt.Line2D(
                [], [], ls="", marker="o", mfc="w", mec="0.3", mew=2, ms=7, label="homing/charging"
            )
        )
    ax.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, 0.0),
        ncol=min(6, len(handles)),
        fontsize=8,
        frameon=False,
        handletextpad=0.2,
        columnspacing=0.8,
    )
    fig.tight_layout()

    def draw(f: int) -> None:
        lo = max(0, f - trail)
        for i in range(k):
            pts = pos[lo : f + 1, i]
            segs = np.stack([pts[:-1], pts[1:]], axis=1) if len(pts) > 1 else np.zeros((0, 2, 2))
            alphas = np.linspace(0.1, 0.7, max(1, len(segs)))
            rgba = np.array([matplotlib.colors.to_rgba(colours[i], a) for a in alphas])
            trails[i].set_segments(segs)
            trails[i].set_color(rgba[: len(segs)])
        discs.set_offsets(pos[f])
        discs.set_facecolors(["w" if b else colours[i] for i, b in enumerate(busy[f])])
        discs.set_edgecolors([colours[i] if b else "k" for i, b in enumerate(busy[f])])
        discs.set_linewidths([2.5 if b else 0.8 for b in busy[f]])
        title.set_text(f"Fig. 5: {k} agents patrolling {m.name}, team step {int(steps[f])}")

    out = Path(out)
    if out.suffix.lower() != ".gif":
        out = out.with_suffix(".gif")
    still_path = Path(still) if still is not None else out.with_suffix(".png")
    try:
        with atomic.staged_file(out) as tmp:
            _save_gif(fig, [*trails, discs, title], draw, len(steps), tmp, fps, dpi)
        draw(len(steps) - 1)
        with atomic.staged_file(still_path) as tmp:
            fig.savefig(tmp, dpi=150, format=still_path.suffix.lstrip(".").lower() or "png")
    finally:
        plt.close(fig)
    return out, still_path


def _save_gif(
    fig: Figure,
    moving: list,
    draw: Callable[[int], None],
    frames: int,
    path: Path,
    fps: int,
    dpi: int,
) -> None:
    """Write an animated GIF of ``frames`` frames: what does not move (maze, legend) is
    rendered once, and each frame only redraws the ``moving`` artists over it (after
    ``draw(f)`` updates them), as blitting does on screen. Ten times faster than
    rendering every frame whole (matplotlib's ``Animation.save``)."""
    from PIL import Image

    fig.set_dpi(dpi)
    canvas = fig.canvas
    for a in moving:
        a.set_animated(True)
    canvas.draw()  # everything but the moving artists
    background = canvas.copy_from_bbox(fig.bbox)
    images = []
    for f in range(frames):
        draw(f)
        canvas.restore_region(background)
        for a in moving:
            fig.draw_artist(a)
        images.append(Image.fromarray(np.asarray(canvas.buffer_rgba())).convert("RGB"))
    for a in moving:
        a.set_animated(False)
    images[0].save(
        path,
        format="GIF",
        save_all=True,
        append_images=images[1:],
        duration=int(1000 / fps),
        loop=0,
    )


__all__ = [
    "draw_map",
    "figure_2",
    "figure_3",
    "figure_4",
    "figure_5",
    "figure_6",
    "gamma",
    "plot_map",
    "team_size",
]


# --- strategies ----------------------------------------------------------------------------

STRATEGY_STYLE = {
    "qlearning": ("tab:red", "o"),
    "random": ("0.5", "x"),
    "conscientious": ("tab:blue", "s"),
    "shared-conscientious": ("tab:cyan", "D"),
    "cyclic": ("tab:green", "^"),
    "partition": ("tab:olive", "v"),
    "evap": ("tab:purple", "P"),
    "qlearning-idleness": ("tab:orange", "*"),
    # patrolling_sim's strategies: dashed-family colours, hollow-looking markers
    "hcr": ("tab:brown", "h"),
    "cc": ("tab:pink", "<"),
    "gbs": ("navy", ">"),
    "sebs": ("darkgoldenrod", "p"),
    "cbls": ("k", "+"),
    "dta-greedy": ("teal", "d"),
    "dta-ssi": ("slategray", "X"),
    "dta-ssi-part": ("darkgreen", "1"),
    "hpcc": ("indigo", "H"),
    # beyond the paper, like qlearning-idleness
    "learned-tour": ("magenta", "8"),
    "gravitational": ("sienna", "H"),  # SimPatrol's gravitational clients
}


def strategies(csv: str | Path, out: str | Path) -> Path:
    """Average and worst idleness vs team size for every strategy, with the walk's L/K."""
    df = _read(csv, ["policy", "agents", "avg_idleness_mean", "worst_idleness_mean"])
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6))
    ks = sorted(df["agents"].unique())
    names = _policy_order(set(df["policy"]))
    _strategy_errorbars(axes, df, ("avg_idleness", "worst_idleness"), names, spread=0.03)
    if "bound_per_robot" in df.columns and df["bound_per_robot"].notna().any():
        b = df.drop_duplicates("agents").sort_values("agents")
        axes[0].plot(
            b["agents"],
            b["bound_per_robot"] / 2,
            color="k",
            ls=":",
            lw=1,
            label="L/2K (K robots evenly spaced on the walk)",
        )
        axes[1].plot(
            b["agents"],
            b["bound_per_robot"],
            color="k",
            ls="--",
            lw=1,
            label="L/K (K robots evenly spaced on the walk)",
        )
        bound_line = [h for h in axes[0].get_lines() if h.get_label().startswith("L/2K")]
        axes[0].legend(handles=bound_line, fontsize=8, loc="lower left")
    axes[0].set_ylabel("average idleness (team steps)")
    axes[0].set_title("Average idleness (mean over runs, 95% t-interval)", fontsize=10)
    axes[1].set_ylabel("worst idleness (team steps)")
    axes[1].set_title("Worst idleness", fontsize=10)
    for ax in axes:
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_xticks(ks, [str(k) for k in ks])
        ax.minorticks_off()
        ax.set_xlabel("team size K (robots)")
        ax.grid(alpha=0.3, lw=0.4, which="both")
    axes[1].legend(fontsize=8, loc="center left", bbox_to_anchor=(1.01, 0.5))
    where = f"{df['map'].iloc[0]}, " if "map" in df.columns else ""
    runs = f"{int(df['runs'].min())} runs per point" if "runs" in df.columns else ""
    fig.suptitle(
        f"Patrol strategies ({where}{runs}; battery on, measures after warm-up)", fontsize=10
    )
    fig.tight_layout()
    return _save(fig, out)


def _style(name: str, i: int) -> tuple[str, str]:
    """Colour and marker of a strategy (a fixed one for the known, else from a cycle)."""
    if name in STRATEGY_STYLE:
        return STRATEGY_STYLE[name]
    extra = ("tab:orange", "tab:brown", "tab:pink", "k")
    return extra[i % len(extra)], "*"


def _strategy_errorbars(
    axes,
    df: pd.DataFrame,
    measures: tuple[str, ...],
    names: list[str],
    spread: float,
    emphasise: bool = False,
) -> None:
    """Mean and 95% interval of each measure against team size, one line per strategy,
    shifted a little sideways so that the intervals do not overlap (``emphasise``: the
    learners thicker, smaller markers)."""
    for i, name in enumerate(names):
        d = df[df["policy"] == name].sort_values("agents")
        colour, marker = _style(name, i)
        x = d["agents"] * 2 ** (spread * (i - len(names) / 2))
        style = {"ms": 4, "lw": 1.4 if name.startswith("qlearning") else 0.9} if emphasise else {}
        for ax, m in zip(axes, measures, strict=True):
            _errorbar(
                ax,
                x,
                d[f"{m}_mean"],
                d[f"{m}_lo"],
                d[f"{m}_hi"],
                color=colour,
                marker=marker,
                label=name,
                **style,
            )


def _policy_order(names: set[str]) -> list[str]:
    from qpatrol.strategies import NAMES

    return [n for n in NAMES if n in names] + sorted(names - set(NAMES))


POLICY_PANELS = (
    ("avg_idleness", "average idleness", 2),
    ("worst_idleness", "worst idleness", 1),
    ("mean_interval", "mean interval between visits", 1),
)


def policies(csv: str | Path, out: str | Path) -> Path:
    """One row per map: average idleness, worst idleness and mean interval against team
    size for every strategy (mean over runs, 95% t-interval), with the cyclic bound."""
    return _per_map(
        csv,
        out,
        POLICY_PANELS,
        "Learned against classic patrol ({runs}{window} after warm-up; battery off). "
        "L: the closed walk through every cell.",
    )


#: The field's figure: (measure, label, what divides L/K for the cyclic bound line, or 0
#: for none, log y-axis).
FIELD_PANELS = (
    ("avg_idleness", "average idleness", 2, True),
    ("worst_avg_idleness", "worst average idleness of a vertex", 1, True),
    ("qmi", "quadratic mean interval (QMI)", 1, True),
    ("freq_std", "std of visit frequencies", 0, True),
    ("interferences", "interferences", 0, False),
)


#: How robots meet in the field's benchmark, as the figures name it.
INTERACTION_TITLES = {
    "interference": "robots pass, and stop on an interference (patrolling_sim)",
    "none": "robots ignore each other (SimPatrol)",
    "exclusive": "one robot per cell (the paper's avoiding)",
}


def field(csv: str | Path, out: str | Path) -> Path:
    """The field's benchmark in the field's world (robots pass each other and stop on an
    interference, when the table has an ``interaction`` column): one row per patrol
    graph, the field's measures against team size for every strategy (mean over runs,
    95% t-interval), with the cyclic bound."""
    how = "interference"
    return _per_map(
        csv,
        out,
        FIELD_PANELS,
        "patrolling_sim's graphs, at the vertices ({runs}{window} after warm-up; battery "
        f"off; {INTERACTION_TITLES[how]}). L: the closed walk through every vertex.",
        select=lambda df: df[df["interaction"] == how] if "interaction" in df.columns else df,
    )


def field_models(csv: str | Path, out: str | Path) -> Path:
    """Does the ranking depend on how robots meet? One row per patrol graph, one column
    per interaction: every strategy's average idleness against team size (mean over
    runs), and in each panel's title the runs that went wrong there (a vertex never
    visited in the window, or blocked in more than half the robot-steps)."""
    cols = ["map", "interaction", "agents", "policy", "avg_idleness_mean", "bad_runs", "runs"]
    df = _read(csv, cols)
    maps = list(dict.fromkeys(df["map"]))
    ways = [h for h in INTERACTION_TITLES if h in set(df["interaction"])]
    names = _policy_order(set(df["policy"]))
    ks = sorted(df["agents"].unique())
    fig, axes = plt.subplots(
        len(maps), len(ways), figsize=(5.2 * len(ways), 3.3 * len(maps)), squeeze=False
    )
    for r, mname in enumerate(maps):
        top = df[df["map"] == mname]["avg_idleness_mean"]
        lo, hi = float(top[top > 0].min()), float(top.max())
        for c, how in enumerate(ways):
            ax = axes[r, c]
            d = df[(df["map"] == mname) & (df["interaction"] == how)]
            for i, name in enumerate(names):
                q = d[d["policy"] == name].sort_values("agents")
                colour, marker = _style(name, i)
                lw = (
                    1.5
                    if name in ("cyclic", "learned-tour") or name.startswith("qlearning")
                    else 0.9
                )
                ax.plot(q["agents"], q["avg_idleness_mean"], color=colour, marker=marker,
                        ms=3.5, lw=lw, label=name)  # fmt: skip
            ax.set_xscale("log", base=2)
            ax.set_ylim(lo / 1.3, hi * 1.3)
            _log_y(ax, "average idleness (team steps)" if c == 0 else "average idleness")
            ax.set_xticks(ks, [str(k) for k in ks])
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.grid(alpha=0.3, lw=0.4, which="both")
            if r == len(maps) - 1:
                ax.set_xlabel("team size K (robots)")
            bad, runs = int(d["bad_runs"].sum()), int(d["runs"].sum())
            ax.set_title(f"{mname}, {how}: {bad} of {runs} runs went wrong", fontsize=9.5)
    rows = _strategy_legend(fig, names)
    titles = "; ".join(f"{h}: {INTERACTION_TITLES[h]}" for h in ways)
    fig.suptitle(
        "The field's benchmark under each way robots meet (battery off, mean over runs)\n" + titles,
        fontsize=10,
        y=1.0 + 0.025 * rows + 0.012,
    )
    fig.tight_layout(rect=(0, 0, 1, 1.0 - 0.025 * rows * 3.3 * 4 / fig.get_figheight()))
    return _save(fig, out)


def _per_map(
    csv: str | Path,
    out: str | Path,
    panels: tuple,
    title: str,
    select: Callable[[pd.DataFrame], pd.DataFrame] | None = None,
) -> Path:
    """One row per map, one column per panel ``(measure, label, divisor of L/K or 0,
    log y)``: each measure against team size for every strategy, with the bound
    (``select``: the table's rows to draw, all by default)."""
    panels = tuple((*p, True)[:4] for p in panels)
    cols = [
        "map",
        "policy",
        "agents",
        *(f"{m}_{s}" for m, *_ in panels for s in "mean lo hi".split()),
    ]
    df = _read(csv, cols)
    if select is not None:
        df = select(df)
    maps = list(dict.fromkeys(df["map"]))
    names = _policy_order(set(df["policy"]))
    ks = sorted(df["agents"].unique())
    n = len(panels)
    fig, axes = plt.subplots(len(maps), n, figsize=(4.5 * n, 3.3 * len(maps)), squeeze=False)
    for r, mname in enumerate(maps):
        dm = df[df["map"] == mname]
        _strategy_errorbars(
            axes[r], dm, tuple(m for m, *_ in panels), names, spread=0.025, emphasise=True
        )
        b = dm.drop_duplicates("agents").sort_values("agents")
        has_bound = "bound_per_robot" in dm.columns and b["bound_per_robot"].notna().any()
        for c, (ax, (_m, label, div, log)) in enumerate(zip(axes[r], panels, strict=True)):
            if has_bound and div:
                walk = int(b["walk_length"].iloc[0])
                ax.plot(
                    b["agents"],
                    b["bound_per_robot"] / div,
                    color="k",
                    ls=":" if div == 2 else "--",
                    lw=1,
                    label=f"L/{'2' if div == 2 else ''}K (L = {walk})",
                )
                ax.legend(
                    handles=[h for h in ax.get_lines() if h.get_label().startswith("L/")],
                    fontsize=7,
                    loc="lower left",
                )
            ax.set_xscale("log", base=2)
            ylabel = f"{label} (team steps)" if c == 0 else label
            if log:
                _log_y(ax, ylabel)
            else:  # a count: its interval's lower end is cut at 0
                ax.set_ylabel(ylabel)
                ax.set_ylim(bottom=0)
            ax.set_xticks(ks, [str(k) for k in ks])
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.grid(alpha=0.3, lw=0.4, which="both")
            if r == len(maps) - 1:
                ax.set_xlabel("team size K (robots)")
            ax.set_title(f"{mname}: {label}", fontsize=10)
    rows = _strategy_legend(fig, names)
    runs = f"{int(df['runs'].min())} runs per point" if "runs" in df.columns else ""
    window = f", {int(df['window'].min()):,} steps measured" if "window" in df.columns else ""
    fig.suptitle(title.format(runs=runs, window=window), fontsize=10, y=1.0 + 0.025 * rows)
    fig.tight_layout(rect=(0, 0, 1, 1.0 - 0.025 * rows * 3.3 * 4 / fig.get_figheight()))
    return _save(fig, out)


def _step_label(x: float, _pos: object = None) -> str:
    """A tick in thousands of steps: 0, 50k, 100k."""
    return f"{x / 1000:,.0f}k" if x else "0"


def _fmt_steps(x: float, _pos: object = None) -> str:
    return f"{x:,.0f}"


def learning(csv: str | Path, out: str | Path) -> Path:
    """Average and worst idleness in windows along the run: learners as curves with a
    95% band over runs, the strategies that do not learn as flat lines at their mean
    after the first window."""
    cols = ["policy", "learns", "window", "last_step", "avg_idleness_mean", "worst_idleness_mean"]
    df = _read(csv, cols)
    names = _policy_order(set(df["policy"]))
    tours = "tour_ratio_mean" in df.columns and df["tour_ratio_mean"].notna().any()
    fig, axes = plt.subplots(1, 3 if tours else 2, figsize=(18 if tours else 13, 4.6))
    end = float(df["last_step"].max())
    for i, name in enumerate(names):
        d = df[df["policy"] == name].sort_values("window")
        colour, _ = _style(name, i)
        learns = bool(d["learns"].iloc[0])
        if tours and d["tour_ratio_mean"].notna().any():
            axes[2].plot(d["last_step"], d["tour_ratio_mean"], color=colour, lw=1.6, label=name)
            axes[2].fill_between(
                d["last_step"], d["tour_ratio_lo"], d["tour_ratio_hi"], color=colour, alpha=0.2
            )
        for ax, m in zip(axes[:2], ("avg_idleness", "worst_idleness"), strict=True):
            if learns:
                ax.plot(d["last_step"], d[f"{m}_mean"], color=colour, lw=1.6, label=name)
                ax.fill_between(
                    d["last_step"], d[f"{m}_lo"], d[f"{m}_hi"], color=colour, alpha=0.2, lw=0
                )
            else:
                level = d[d["window"] >= 1][f"{m}_mean"].mean()
                ax.plot([0, end], [level, level], color=colour, lw=1, ls="--", label=name)
    if tours:
        ax = axes[2]
        ax.axhline(1.0, color="0.3", lw=1, ls="--", label="cyclic's walk (L)")
        ax.set_ylabel("route length / L")
        ax.set_xlabel("team step (end of each window)")
        ax.xaxis.set_major_formatter(FuncFormatter(_step_label if end >= 20_000 else _fmt_steps))
        ax.set_xlim(0, end * 1.01)
        ax.grid(alpha=0.3, lw=0.4)
        ax.set_title("learned-tour: its route's length over cyclic's walk", fontsize=10)
    for ax, label in zip(axes[:2], ("average idleness", "worst idleness"), strict=True):
        _log_y(ax, f"{label} in the window (team steps)", subs=(1.0, 1.5, 2.0, 2.5, 3.0, 5.0, 7.0))
        ax.set_xlabel("team step (end of each window)")
        ax.xaxis.set_major_formatter(FuncFormatter(_step_label if end >= 20_000 else _fmt_steps))
        ax.set_xlim(0, end * 1.01)
        ax.grid(alpha=0.3, lw=0.4, which="both")
    handles, labels = axes[1].get_legend_handles_labels()
    if tours:
        axes[2].add_artist(axes[2].legend(fontsize=8, loc="upper right"))
    axes[-1].legend(handles, labels, fontsize=8, loc="center left", bbox_to_anchor=(1.01, 0.5))
    w = int(df["last_step"].min())
    where = f"{df['map'].iloc[0]}, K = {int(df['agents'].iloc[0])}, " if "map" in df.columns else ""
    runs = f"{int(df['runs'].min())} runs" if "runs" in df.columns else ""
    axes[0].set_title("Average idleness (mean over runs, 95% band)", fontsize=10)
    axes[1].set_title("Worst idleness", fontsize=10)
    fig.suptitle(
        f"Learning over time ({where}{runs}, windows of {w:,} steps; battery off). "
        "Dashed: strategies that do not learn, mean after their first window.",
        fontsize=10,
    )
    fig.tight_layout()
    return _save(fig, out)


# --- the security study ------------------------------------------------------------------


def _legend_title_save(fig, out: str | Path, names: list[str], title: str, room: float) -> Path:
    """The strategies' legend above the panels and ``title`` above it (``room``: the
    height per legend row, in figure fractions, for panels of 3.2 inches), then the figure
    saved at 120 dpi (many lines: a smaller file)."""
    rows = _strategy_legend(fig, names)
    fig.suptitle(title, fontsize=10, y=1.0 + room * rows)
    fig.tight_layout(rect=(0, 0, 1, 1.0 - room * rows * 6.4 / fig.get_figheight()))
    return _save(fig, out, dpi=120)


def _strategy_legend(fig, names: list[str]) -> int:
    """A figure-wide legend of the strategies above the panels; returns its rows."""
    handles = [
        plt.Line2D([], [], color=_style(n, i)[0], marker=_style(n, i)[1], ms=5, label=n)
        for i, n in enumerate(names)
    ]
    fig.legend(
        handles=handles,
        loc="upper center",
        ncol=min(len(names), 8),
        fontsize=9,
        bbox_to_anchor=(0.5, 1.0),
        frameon=False,
    )
    return -(-len(names) // 8)


def security(csv: str | Path, out: str | Path) -> Path:
    """Share of intruders caught against the attack's duration D, one line per strategy:
    a row per intruder (random, observer), a column per map and team size."""
    df = _read(
        csv,
        ["map", "agents", "policy", "intruder", "attack_steps", "capture_mean", "capture_min"],
    )
    cases = list(dict.fromkeys(zip(df["map"], df["agents"], strict=True)))
    intruders = list(dict.fromkeys(df["intruder"]))
    names = _policy_order(set(df["policy"]))
    fig, axes = plt.subplots(
        len(intruders), len(cases), figsize=(3.6 * len(cases), 3.2 * len(intruders)), squeeze=False
    )
    titles = {
        "random": "random intruder: share of (target, step) caught",
        "observer": "observer: share caught at its best target",
    }
    for r, who in enumerate(intruders):
        for c, (mname, k) in enumerate(cases):
            ax = axes[r][c]
            d = df[(df["intruder"] == who) & (df["map"] == mname) & (df["agents"] == k)]
            for i, name in enumerate(names):
                s = d[d["policy"] == name].sort_values("attack_steps")
                colour, marker = _style(name, i)
                lw = 1.6 if name.startswith("qlearning") else 0.9
                ax.plot(
                    s["attack_steps"], s["capture_mean"], color=colour, marker=marker, ms=4, lw=lw
                )
            ds = sorted(d["attack_steps"].unique())
            ax.set_xscale("log", base=2)
            ax.set_xticks(ds, [str(x) for x in ds])
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.set_ylim(-0.03, 1.03)
            ax.grid(alpha=0.3, lw=0.4, which="both")
            ax.set_title(f"{mname}, K = {k}", fontsize=10)
            if c == 0:
                ax.set_ylabel(titles.get(who, who), fontsize=8)
            if r == len(intruders) - 1:
                ax.set_xlabel("attack duration D (team steps)")
    runs = int(df["runs"].min()) if "runs" in df.columns else 0
    title = (
        f"Intruders caught (mean over {runs} runs; battery on; D from T/8 to 2T, T the map's "
        "targets)"
    )
    return _legend_title_save(fig, out, names, title, 0.03)


def security_failures(csv: str | Path, out: str | Path) -> Path:
    """Worst idleness in the timeline's windows around the failure of 2 robots (solid;
    the same team without failure, thin and faint), one line per strategy, a panel per
    map and team size."""
    df = _read(
        csv,
        ["map", "agents", "policy", "failures", "since_failure", "worst_idleness_mean"],
    )
    most = int(df["failures"].max())
    cases = list(dict.fromkeys(zip(df["map"], df["agents"], strict=True)))
    names = _policy_order(set(df["policy"]))
    n = len(cases)
    cols = min(n, 2)
    rows_p = -(-n // cols)
    fig, axes = plt.subplots(rows_p, cols, figsize=(6.2 * cols, 3.8 * rows_p), squeeze=False)
    for j, (mname, k) in enumerate(cases):
        ax = axes[j // cols][j % cols]
        d = df[(df["map"] == mname) & (df["agents"] == k)]
        for i, name in enumerate(names):
            colour, _ = _style(name, i)
            s = d[d["policy"] == name]
            base = s[s["failures"] == 0].sort_values("since_failure")
            hit = s[s["failures"] == most].sort_values("since_failure")
            ax.plot(base["since_failure"], base["worst_idleness_mean"], color=colour, lw=0.6,
                    alpha=0.35)  # fmt: skip
            lw = 1.6 if name.startswith("qlearning") else 1.0
            ax.plot(hit["since_failure"], hit["worst_idleness_mean"], color=colour, lw=lw)
        ax.axvline(0, color="k", lw=0.8, ls="--")
        _log_y(ax, "worst idleness in a window (team steps)")
        ax.grid(alpha=0.3, lw=0.4, which="both")
        ax.set_title(f"{mname}, K = {k}: {most} of {k} robots fail at step 0", fontsize=10)
        ax.set_xlabel("team steps since the failure (end of each 100-step window)")
    for j in range(n, rows_p * cols):
        axes[j // cols][j % cols].set_visible(False)
    runs = int(df["runs"].min()) if "runs" in df.columns else 0
    title = (
        f"Worst idleness around a failure (mean over {runs} runs; faint: the same team "
        "without failure)"
    )
    return _legend_title_save(fig, out, names, title, 0.025)


def security_recovery(csv: str | Path, out: str | Path) -> Path:
    """Worst idleness after the failure over before it, per strategy, for each number of
    robots failing (the same team without failure: grey), a panel per map and team size;
    a run that left a target unvisited for the whole window after the failure marks its
    bar with a cross ("never" in the report)."""
    df = _read(csv, ["map", "agents", "policy", "failures", "worst_ratio", "uncovered", "runs"])
    cases = list(dict.fromkeys(zip(df["map"], df["agents"], strict=True)))
    names = _policy_order(set(df["policy"]))
    fails = sorted(df["failures"].unique())
    colours = {0: "0.75", 1: "tab:blue", 2: "tab:red"}
    n = len(cases)
    cols = min(n, 2)
    rows_p = -(-n // cols)
    fig, axes = plt.subplots(rows_p, cols, figsize=(7.0 * cols, 3.6 * rows_p), squeeze=False)
    width = 0.8 / len(fails)
    x = np.arange(len(names))
    for j, (mname, k) in enumerate(cases):
        ax = axes[j // cols][j % cols]
        d = df[(df["map"] == mname) & (df["agents"] == k)].set_index(["policy", "failures"])
        for i, f in enumerate(fails):
            ratio = [d["worst_ratio"].get((nm, f), np.nan) for nm in names]
            lost = [d["uncovered"].get((nm, f), 0) for nm in names]
            xs = x + (i - (len(fails) - 1) / 2) * width
            label = "no failure" if f == 0 else f"{f} failed"
            ax.bar(xs, ratio, width, color=colours.get(f, f"C{i}"), label=label)
            for xi, r, lo in zip(xs, ratio, lost, strict=True):
                if lo and r == r:
                    ax.plot(xi, r, marker="x", color="k", ms=5)
        ax.axhline(1, color="k", lw=0.6)
        ax.set_yscale("log")
        ax.set_xticks(x, names, rotation=60, ha="right", fontsize=8)
        ax.set_ylabel("worst idleness after / before", fontsize=9)
        ax.grid(alpha=0.3, lw=0.4, axis="y", which="both")
        ax.set_title(f"{mname}, K = {k}", fontsize=10)
        if j == 0:
            ax.legend(fontsize=8, loc="upper left")
    for j in range(n, rows_p * cols):
        axes[j // cols][j % cols].set_visible(False)
    runs = int(df["runs"].min())
    fig.suptitle(
        f"Worst idleness after the failure over before it (mean over {runs} runs; x: some run "
        "left a target unvisited for the whole window after it)",
        fontsize=10,
    )
    fig.tight_layout()
    return _save(fig, out, dpi=120)  # (many lines: a smaller file)


def neural(csv: str | Path, out: str | Path) -> Path:
    """The neural policy: its training (average idleness of each batch of runs against
    team steps trained, one line per training seed, with cyclic and SEBS in the same
    setting as lines), and its study (per map and robots failing: the policy, mean over
    its training seeds with their range, beside the best strategy, SEBS and cyclic)."""
    df = read_csv(csv)
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(13, 4.6), gridspec_kw={"width_ratios": [1, 1.6]})
    curve = df[df["kind"] == "curve"]
    for seed, g in curve.groupby("seed"):
        label = f"PPO seed {int(seed)}"
        ax0.plot(g["team_steps"] / 1e6, g["avg_idleness_mean"], lw=1.2, label=label)
    base = df[df["kind"] == "baseline"]
    for pol, style in (("cyclic", ":"), ("sebs", "--")):
        b = base[base["policy"] == pol]["avg_idleness_mean"]
        if len(b):
            ax0.axhline(
                float(b.iloc[0]), color="k", ls=style, lw=1, label=f"{pol} ({b.iloc[0]:.1f})"
            )
    ax0.set_xlabel("team steps trained (millions, all runs)")
    ax0.set_ylabel("average idleness")
    ax0.set_title("training on ps_cumberland, 6 robots (1,000-step runs)", fontsize=9)
    ax0.legend(fontsize=7)
    study = df[df["kind"] == "study"]
    settings = list(dict.fromkeys(zip(study["map"], study["failures"], strict=True)))
    x = np.arange(len(settings))
    width = 0.2
    bars = {"neural": [], "best": [], "sebs": [], "cyclic": []}
    lo, hi, best_names = [], [], []
    for m, f in settings:
        d = study[(study["map"] == m) & (study["failures"] == f)]
        nn = d[d["policy"] == "neural"]["avg_idleness_mean"]
        bars["neural"].append(nn.mean())
        lo.append(nn.mean() - nn.min())
        hi.append(nn.max() - nn.mean())
        others = d[d["policy"] != "neural"]
        b = others.loc[others["avg_idleness_mean"].idxmin()]
        bars["best"].append(b["avg_idleness_mean"])
        best_names.append(str(b["policy"]))
        for pol in ("sebs", "cyclic"):
            v = others[others["policy"] == pol]["avg_idleness_mean"]
            bars[pol].append(float(v.iloc[0]) if len(v) else np.nan)
    for i, (name, vals) in enumerate(bars.items()):
        err = (lo, hi) if name == "neural" else None
        ax1.bar(x + (i - 1.5) * width, vals, width, yerr=err, capsize=2, label=name)
    for xi, (v, name) in enumerate(zip(bars["best"], best_names, strict=True)):
        ax1.text(xi - 0.5 * width, v, name, rotation=90, fontsize=6, ha="center", va="bottom")
    names = [f"{m.removeprefix('ps_')}\n{int(f)} failing" for m, f in settings]
    ax1.set_xticks(x, names, fontsize=7)
    ax1.set_ylabel("average idleness (mean over runs)")
    ax1.set_yscale("log")
    ax1.set_title(
        "6 robots, interference, 3,000 steps after 1,000; neural: mean and range over seeds",
        fontsize=9,
    )
    ax1.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, out)
