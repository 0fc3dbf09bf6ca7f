"""Q-tables kept lazily (``learning.table: lazy``): a row per cell a robot has stood in.

The values read and written are those of the dense table, so every result is the same
to the bit, on both engines; ``q_table.npz`` keeps the rows given out and their cells
(:func:`qpatrol.strategies.qlearning.dense_tables` reads either form back).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_engines import META, same_arrays, same_files

from qpatrol.config import from_flat
from qpatrol.maps import get_map
from qpatrol.run import checkpoint as ck
from qpatrol.run import simulate, write_run
from qpatrol.strategies import qlearning
from qpatrol.world import limits

#: Fewer steps than pacman's 300 cells, so that a robot's rows (steps + 2) are fewer too.
BASE = {"policy": "qlearning", "runs": 2, "seed": 5, "steps": 120, "agents": 3}

CASES = {
    "grid": {"map": "pacman"},
    "battery, epsilon, cell states": {
        "map": "pacman",
        "battery.enabled": True,
        "learning.epsilon": 0.2,
        "learning.state_space": "cell",
    },
    "graph with waypoints": {"map": "ps_cumberland", "steps": 100},
    "lone robot, episodes": {"map": "pacman", "agents": 1, "max_episode_steps": 40},
}


def _tables(folder: Path, runs: int, agents: int) -> list[tuple[np.ndarray, np.ndarray]]:
    with np.load(folder / "q_table.npz") as z:
        return [qlearning.dense_tables(z, r, k) for r in range(runs) for k in range(agents)]


@pytest.mark.parametrize("case", list(CASES))
def test_lazy_tables_give_the_dense_results(tmp_path, case):
    """Every file of a run (summary, episodes, visits, trajectory) is the dense tables'
    on both engines, the tables read back are the dense ones, and the engines give out
    the same rows in the same order."""
    flat = {**BASE, **CASES[case]}
    dense = write_run(
        simulate(from_flat({**flat, "learning.table": "dense", "engine": "numpy"})),
        tmp_path / "dense",
        meta=META,
    )
    lazy, objs = {}, {}
    for engine in ("numpy", "numba"):
        result = simulate(from_flat({**flat, "learning.table": "lazy", "engine": engine}))
        objs[engine] = result.strategy
        lazy[engine] = write_run(result, tmp_path / engine, meta=META)
    strategy = objs["numpy"]
    assert strategy.slot is not None and strategy.rows == flat["steps"] + 2
    assert strategy.q.shape[2] < get_map(flat["map"]).n_cells
    same_arrays(objs["numpy"], objs["numba"])
    same_files(lazy["numpy"], lazy["numba"], flat)
    for name in ("summary.json", "episodes.csv", "visits.npz", "trajectory.csv"):
        if (dense / name).exists():
            assert (dense / name).read_bytes() == (lazy["numpy"] / name).read_bytes(), name
    k = flat["agents"]
    for (qd, nd), (ql, nl) in zip(_tables(dense, 2, k), _tables(lazy["numpy"], 2, k), strict=True):
        assert np.array_equal(qd, ql) and np.array_equal(nd, nl)
    # a robot has rows only for cells it stood in: those it entered and its first
    with np.load(lazy["numpy"] / "visits.npz") as z:
        visits = z["visits"]
    with np.load(lazy["numpy"] / "q_table.npz") as z:
        rows = (z["slot"] >= 0).sum(axis=-1)
        assert z["q"].shape[2] == rows.max()
    assert (rows <= (visits > 0).sum(axis=-1) + 1).all()


def test_a_lazy_row_that_does_not_start_at_the_initial_values_is_seen(monkeypatch):
    """Deliberate break: rows given out as they are in the pool (zeros, not the initial
    values) change the robots' choices, and the results differ from the dense tables'."""
    flat = {**BASE, "map": "pacman", "engine": "numpy"}
    dense = simulate(from_flat({**flat, "learning.table": "dense"}))
    fresh = qlearning.Strategy.use_run_values

    def zeros(self, values, table=True):
        fresh(self, values, table)
        if table and self.slot is not None:
            self.q[...] = 0.0

    monkeypatch.setattr(qlearning.Strategy, "use_run_values", zeros)
    broken = simulate(from_flat({**flat, "learning.table": "lazy"}))
    assert broken.summary != dense.summary


def test_lazy_tables_resume_from_a_checkpoint(tmp_path):
    """A run stopped halfway and resumed (on the other engine) keeps its rows: the files
    of an uninterrupted run."""
    flat = {**BASE, "map": "pacman", "learning.table": "lazy", "steps": 100}
    whole = write_run(simulate(from_flat(flat)), tmp_path / "whole", meta=META)

    class StopAt(ck.Checkpointer):
        every_step = True

        def tick(self, position, payload):
            if position == 47:
                self.request_stop()
            super().tick(position, payload)

    with pytest.raises(ck.Interrupted):
        simulate(
            from_flat({**flat, "engine": "numba"}), checkpoint=StopAt(tmp_path / "cp", every=0)
        )
    rest = simulate(
        from_flat({**flat, "engine": "numpy"}), checkpoint=ck.Checkpointer(tmp_path / "cp", every=0)
    )
    same_files(whole, write_run(rest, tmp_path / "rest", meta=META), flat)


def test_auto_keeps_tables_lazily_only_where_they_would_be_large():
    """``auto``: dense up to ``LAZY_BYTES`` per run, else ``steps + 2`` rows a robot;
    never more rows than cells. The memory estimate follows the rows."""
    floor = get_map("pacman")
    cfg = from_flat({**BASE, "map": "pacman", "agents": 8, "steps": 10_000})
    assert limits.table_rows(cfg, floor.n_cells, 8, 4) == floor.n_cells
    big = 200_000  # cells: 8 robots x 200,000 cells x 16 x 12 bytes = 293 MiB
    assert limits.table_rows(cfg, big, 8, 4) == 10_002
    assert limits.table_rows(cfg, big, 1, 4) == big  # 37 MiB: dense
    lazy = from_flat({**BASE, "map": "pacman", "learning.table": "lazy", "steps": 50})
    assert limits.table_rows(lazy, floor.n_cells, 3, 4) == 52
    assert limits.table_rows(lazy, 40, 3, 4) == 40
    dense = from_flat({**BASE, "map": "pacman", "learning.table": "dense", "steps": 50})
    saved = 3 * (floor.n_cells - 52) * 16 * 12 - 3 * (floor.n_cells + 1) * 4
    assert limits.bytes_per_run(dense, floor) - limits.bytes_per_run(lazy, floor) == saved
