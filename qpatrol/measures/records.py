"""What a run leaves behind: Q-updates, traced states and episodes, as tables.

The simulator calls a :class:`Recorder` during each step with arrays over the runs
involved; the recorder keeps only what the config asks for and turns it into
``pandas.DataFrame`` tables at the end. CSV files are written with one fixed float
format (the shortest round-trip repr) so the same config and seed give byte-identical
files and a number read back is the number computed.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from qpatrol.world import GONE, EpisodeEnds, State

#: Float format of every CSV: None = Python's shortest repr that reads back to the
#: same float64, so files are exact, deterministic and replayable.
FLOAT_FORMAT = None

TRANSITION_COLUMNS = [
    "run",
    "step",
    "agent",
    "cell",
    "heading",
    "action",
    "reward",
    "next_cell",
    "next_heading",
    "alpha",
    "q_before",
    "q_after",
]
WATCH_COLUMNS = TRANSITION_COLUMNS + ["bootstrap", "q_north", "q_east", "q_south", "q_west", "dot"]
EPISODE_COLUMNS = [
    "run",
    "episode",
    "start_step",
    "steps",
    "dots_eaten",
    "distinct_cells",
    "complete",
    "distinct_states",
    "group",
]


def update_cols(
    cell, heading, action, reward, next_cell, next_heading, alpha, q_before, q_after,
    bootstrap, dot, q_row,
) -> dict[str, np.ndarray]:  # fmt: skip
    """The columns :meth:`Recorder.updates` takes, by name, from arrays ``[B]`` (and
    ``q_row`` ``[B, 4]``), in its order."""
    return {
        "cell": cell, "heading": heading, "action": action, "reward": reward,
        "next_cell": next_cell, "next_heading": next_heading, "alpha": alpha,
        "q_before": q_before, "q_after": q_after, "bootstrap": bootstrap, "dot": dot,
        "q_row": q_row,
    }  # fmt: skip


class Recorder:
    """Collects Q-updates (all, and those of watched cells) and episode ends.

    Args:
        run_ids: int ``[R]``, the run number written for each batch row.
        transitions: keep every Q-update.
        watch: states whose Q-updates are kept with the bootstrap term and Q row.
    """

    def __init__(
        self,
        run_ids: np.ndarray,
        transitions: bool = False,
        watch: list[int] | tuple[int, ...] = (),
    ):
        self.run_ids = np.asarray(run_ids, dtype=np.int64)
        self.transitions = transitions
        self.watch = np.asarray(sorted(watch), dtype=np.int64)
        self.wants_updates = transitions or self.watch.size > 0
        self._updates: list[list[np.ndarray]] = []
        self._episodes: list[list[np.ndarray]] = []

    def updates(
        self, t: int, runs: np.ndarray, agents: np.ndarray, cols: dict[str, np.ndarray]
    ) -> None:
        """Keep the Q-updates made at step ``t`` (all, or those of watched cells).

        ``runs``, ``agents``: int ``[B]`` batch rows and robots; ``cols`` holds ``[B]``
        arrays cell, heading, action, reward, next_cell, next_heading, alpha, q_before,
        q_after, bootstrap (gamma max Q(s')), dot (a dot was eaten on entering s') and
        ``q_row`` ``[B, D]`` (after; the first four written, NaN for actions past D).
        """
        if not self.transitions:
            keep = np.isin(cols["cell"], self.watch)
            if not keep.any():
                return
            runs, agents = runs[keep], agents[keep]
            cols = {name: x[keep] for name, x in cols.items()}
        m = runs.size
        q_row = np.full((m, 4), np.nan)  # actions past the map's D have no value
        k = min(4, cols["q_row"].shape[1])
        q_row[:, :k] = cols["q_row"][:, :k]
        self._updates.append(
            [self.run_ids[runs], np.full(m, t), agents]
            + [cols[name] for name in WATCH_COLUMNS[3:13]]
            + [q_row[:, 0], q_row[:, 1], q_row[:, 2], q_row[:, 3]]
            + [cols["dot"].astype(np.int64)]
        )

    def episodes(self, t: int, ends: EpisodeEnds) -> None:
        """Keep the episodes that ended at step ``t``."""
        if ends.runs.size == 0:
            return
        self._episodes.append(
            [
                self.run_ids[ends.runs],
                ends.episode,
                ends.start + 1,
                t - ends.start,
                ends.dots,
                ends.distinct_cells,
                ends.complete.astype(np.int64),
                ends.distinct_states,
                ends.groups,
            ]
        )

    def update_rows(self, ints: np.ndarray, floats: np.ndarray) -> None:
        """Keep Q-updates given as rows (the compiled engine's buffers,
        :mod:`qpatrol.engines.numba_core`): ints ``[U, 9]`` batch row, step, agent, cell,
        heading, action, next cell, next heading, dot; floats ``[U, 9]`` reward, alpha,
        q_before, q_after, bootstrap and the Q row after the update (N, E, S, W)."""
        if ints.shape[0] == 0:
            return
        i = [ints[:, j].copy() for j in range(9)]
        f = [floats[:, j].copy() for j in range(9)]
        self._updates.append(
            [self.run_ids[i[0]], i[1], i[2], i[3], i[4], i[5], f[0], i[6], i[7]]
            + [f[1], f[2], f[3], f[4], f[5], f[6], f[7], f[8], i[8]]
        )

    def episode_rows(self, rows: np.ndarray) -> None:
        """Keep episode ends given as rows int ``[E, 9]``: batch row, group, episode,
        start, dots, distinct cells, distinct states, complete, step ended (the compiled
        engine's buffer, :mod:`qpatrol.engines.numba_core`)."""
        if rows.shape[0] == 0:
            return
        r, g, ep, start, dots, cells, states, complete, t = (rows[:, i] for i in range(9))
        self._episodes.append(
            [self.run_ids[r], ep, start + 1, t - start, dots, cells, complete, states, g]
        )

    def _table(
        self, parts: list[list[np.ndarray]], columns: list[str], order: list[str]
    ) -> pd.DataFrame:
        if parts:
            cols = [np.concatenate([p[i] for p in parts]) for i in range(len(columns))]
        else:
            cols = [np.zeros(0, dtype=np.int64) for _ in columns]
        df = pd.DataFrame(dict(zip(columns, cols, strict=True)))
        return df.sort_values(order, kind="stable").reset_index(drop=True)

    def episode_table(self) -> pd.DataFrame:
        """One row per ended episode (complete or truncated), by run, group, episode."""
        df = self._table(self._episodes, EPISODE_COLUMNS, ["run", "group", "episode"])
        df["truncated"] = 1 - df["complete"]
        return df

    def update_table(self) -> pd.DataFrame:
        """All recorded Q-updates (``WATCH_COLUMNS``), by run, step and agent."""
        df = self._table(self._updates, WATCH_COLUMNS, ["run", "step", "agent"])
        for col in (
            "reward",
            "alpha",
            "q_before",
            "q_after",
            "bootstrap",
            "q_north",
            "q_east",
            "q_south",
            "q_west",
        ):
            df[col] = df[col].astype(np.float64)
        return df

    def transition_table(self) -> pd.DataFrame | None:
        """``transitions.csv``: one row per Q-update, or None if not recorded."""
        return self.update_table()[TRANSITION_COLUMNS] if self.transitions else None

    def watch_table(self) -> pd.DataFrame | None:
        """``watch.csv``: the Q-updates of watched states, or None if none are watched."""
        if not self.watch.size:
            return None
        df = self.update_table()
        return df[df["cell"].isin(self.watch)].reset_index(drop=True)


class Tail:
    """Every agent's cell over each run's last ``n`` team steps (a ring buffer per run);
    -1 for a robot that failed (:mod:`qpatrol.world.failures`)."""

    def __init__(self, n: int, state: State):
        self.n = n
        if n:
            self.pos = np.zeros((state.n_runs, n, state.pos.shape[1]), dtype=np.int64)

    def observe(self, state: State) -> None:
        """Call after each step: stores the cells of the runs that took this step."""
        if self.n:
            ran = np.flatnonzero(state.steps_done == state.t)
            # a robot that failed stands nowhere: cell -1
            cells = np.where(state.mode[ran] == GONE, -1, state.pos[ran])
            self.pos[ran, (state.t - 1) % self.n] = cells

    def table(self, state: State, run_ids: np.ndarray, coords: np.ndarray) -> pd.DataFrame | None:
        """``trajectory.csv``: run, step, agent, cell, row, col (None when off)."""
        if not self.n:
            return None
        parts = []
        for i, run in enumerate(np.asarray(run_ids).tolist()):
            last = int(state.steps_done[i])
            steps = np.arange(max(1, last - self.n + 1), last + 1)
            cells = self.pos[i, (steps - 1) % self.n]  # [T, K]
            k = cells.shape[1]
            parts.append(
                pd.DataFrame(
                    {
                        "run": run,
                        "step": np.repeat(steps, k),
                        "agent": np.tile(np.arange(k), steps.size),
                        "cell": cells.ravel(),
                    }
                )
            )
        df = pd.concat(parts, ignore_index=True)
        cell = df["cell"].to_numpy()
        here = cell >= 0  # -1: a robot that failed (row and col -1 too)
        df["row"] = np.where(here, coords[np.maximum(cell, 0), 0], -1)
        df["col"] = np.where(here, coords[np.maximum(cell, 0), 1], -1)
        return df


def to_csv_text(df: pd.DataFrame) -> str:
    """CSV text with the fixed float format and Unix newlines."""
    return df.to_csv(index=False, float_format=FLOAT_FORMAT, lineterminator="\n")
