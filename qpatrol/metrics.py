"""Patrolling measures of a finished batch of runs, one dict per run.

Standard measures of the multi-agent patrolling literature (Machado et al. 2002;
Chevaleyre 2004), over the steps after ``record.warmup``:

* idleness of cell c at step t: ``t - last visit of c`` (0 at the start);
* ``avg_idleness``: mean over cells and measured steps; ``worst_idleness``: the max;
* ``mean_interval`` / ``max_interval``: between two successive visits of a cell;
* ``coverage``: share of cells visited at least once;
* ``division_of_labour``: for each visited cell the share of its visits made by its
  most frequent visitor, averaged over cells (1/K: none, 1: a full partition).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from qpatrol.env import State


def division_of_labour(visits: np.ndarray) -> np.ndarray:
    """float ``[R]`` from visit counts int ``[R, K, C]`` (NaN for a run with no visit)."""
    total = visits.sum(axis=1)  # [R, C]
    share = np.full(total.shape, np.nan)
    np.divide(visits.max(axis=1), total, out=share, where=total > 0)
    visited = total > 0
    counts = visited.sum(axis=1)
    sums = np.where(visited, share, 0.0).sum(axis=1)
    return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)


def summarize(state: State, episodes: pd.DataFrame, run_ids: np.ndarray) -> list[dict[str, Any]]:
    """Per-run measures as plain dicts (JSON-ready), in batch order."""
    dol = division_of_labour(state.visits)
    coverage = (state.visits.sum(axis=1) > 0).mean(axis=1)
    out = []
    for i, run in enumerate(np.asarray(run_ids).tolist()):
        ep = episodes[episodes["run"] == run]
        done = ep[ep["complete"] == 1]
        measured = int(state.measured[i])
        gaps = int(state.gap_count[i])
        out.append(
            {
                "run": int(run),
                "steps": int(state.steps_done[i]),
                "episodes_completed": int(len(done)),
                "episodes_truncated": int((ep["complete"] == 0).sum()),
                "mean_steps_per_episode": float(done["steps"].mean()) if len(done) else None,
                "coverage": float(coverage[i]),
                "avg_idleness": float(state.idle_sum[i] / measured) if measured else None,
                "worst_idleness": int(state.idle_max[i]) if measured else None,
                "mean_interval": float(state.gap_sum[i] / gaps) if gaps else None,
                "max_interval": int(state.gap_max[i]) if gaps else None,
                "division_of_labour": None if np.isnan(dol[i]) else float(dol[i]),
                "waits": int(state.waits[i].sum()),
            }
        )
    return out
