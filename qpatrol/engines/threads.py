"""Threads of the compiled engine: how many share out a batch's runs.

The compiled loop releases the GIL (``nogil``), and a batch's runs are independent
(each its own random stream, tables, maps and measures), so the runs of one batch can
be cut into contiguous **lanes**, each advanced by its own thread with its own working
arrays (:meth:`qpatrol.engines.numba_core.Loop.run`). A run computes the same numbers
whichever lane it falls in, so the files do not depend on the number of threads.

Config key ``threads`` (an execution key, like ``engine``): 0 (the default) means this
process's share of the cores: all of :func:`qpatrol.world.limits.cores` in a process of its
own, and what the pool that started a worker process gave it (:func:`set_share`: a
sweep's or ``reproduce``'s ``--jobs`` workers share the cores evenly, so two jobs on
two cores take one thread each, and dask workers take one); N > 0 means N. The numpy
engine always runs in one thread.
"""

from __future__ import annotations

from qpatrol.world import limits

#: The threads this process may use under ``threads: 0`` (None: every core); set in a
#: worker process by the pool that started it.
_share: int | None = None

#: Fewest agent-steps a call of the compiled loop must have to be cut into lanes: a
#: thread's hand-over costs tens of microseconds, a call of this size 0.2 to 0.6 ms
#: (calls are that short with a Q-update recorder, whose buffers bound a call to 8,192
#: agent-steps; a checkpointer that wants every step gets calls of one team step).
MIN_LANE_WORK = 1 << 12


def set_share(threads: int | None) -> None:
    """Give this process ``threads`` threads under ``threads: 0`` (None: every core)."""
    global _share
    _share = None if threads is None else max(1, int(threads))


def share_of(workers: int) -> int:
    """One of ``workers`` processes' share of this machine's cores (at least 1)."""
    return max(1, limits.cores() // max(1, workers))


def resolve(requested: int) -> int:
    """The threads a batch may use: ``requested`` if > 0, else this process's share
    (:func:`set_share`; every core, :func:`qpatrol.world.limits.cores`, when none was set)."""
    if requested > 0:
        return int(requested)
    return _share if _share is not None else limits.cores()


def lanes(n_runs: int, threads: int, work: int) -> list[tuple[int, int]]:
    """Contiguous ``(lo, hi)`` row ranges, one per thread, covering ``0..n_runs`` in
    order, as even as the runs allow; one range when ``threads`` is 1, when there is
    one run, or when a call's ``work`` (agent-steps) is below :data:`MIN_LANE_WORK`."""
    n = min(threads, n_runs)
    if n <= 1 or work < MIN_LANE_WORK:
        return [(0, n_runs)]
    cuts = [n_runs * i // n for i in range(n + 1)]
    return [(cuts[i], cuts[i + 1]) for i in range(n)]
