"""Random streams: one ``numpy.random.Generator`` per run, from ``SeedSequence`` children.

Run ``r`` of sweep point ``p`` draws from ``SeedSequence(seed, spawn_key=(p, r))``
(``train`` is point 0), so a run's numbers depend only on the root seed and its
coordinates, never on which other runs share its batch, on ``--jobs`` or on the
backend. Each step consumes exactly ``2 * agents`` uniforms from every run's
stream, whether they are used or not, so the streams stay aligned.
"""

from __future__ import annotations

import numpy as np


def run_seed(seed: int, point: int, r: int) -> np.random.SeedSequence:
    """The stream of run ``r`` of sweep point ``point``: ``SeedSequence(seed,
    spawn_key=(point, r))``."""
    return np.random.SeedSequence(seed, spawn_key=(point, r))


def run_seeds(seed: int, runs: int | range, point: int = 0) -> list[np.random.SeedSequence]:
    """:func:`run_seed` of each run index r."""
    idx = range(runs) if isinstance(runs, int) else runs
    return [run_seed(seed, point, r) for r in idx]


class Streams:
    """Per-step uniforms ``[R, K, 2]`` for a batch of runs, drawn in blocks.

    The Python loop over runs happens once per ``block`` steps, not in every step.
    Drawing ``(B, K, 2)`` doubles twice gives the same numbers as ``(2B, K, 2)`` once,
    so the block size never changes a result.
    """

    #: Steps drawn at once by :meth:`next` unless told otherwise.
    BLOCK = 512

    def __init__(self, seeds: list[np.random.SeedSequence], agents: int, block: int = BLOCK):
        self.generators = [np.random.Generator(np.random.PCG64(s)) for s in seeds]
        self.agents = agents
        self.block = block
        self._buf = np.empty((len(seeds), 0, agents, 2))
        self._i = 0

    def next(self) -> np.ndarray:
        """float ``[R, K, 2]``: the uniforms of the next step."""
        if self._i >= self._buf.shape[1]:
            buf = np.empty((len(self.generators), self.block, self.agents, 2))
            for r, g in enumerate(self.generators):
                g.random(out=buf[r])  # the numbers of g.random((block, agents, 2))
            self._buf = buf
            self._i = 0
        u = self._buf[:, self._i]
        self._i += 1
        return u

    def take(self, n: int, out: np.ndarray | None = None) -> np.ndarray:
        """float ``[R, n, K, 2]``: the uniforms of the next ``n`` steps at once.

        The same numbers :meth:`next` would give over those steps (what is left of the
        current block first, then fresh draws), so the two may be mixed freely. With
        ``out`` (float64 ``[R, n, K, 2]``, C-contiguous) they are drawn into it, without
        new allocations or copies (the compiled engine reuses one buffer per block).
        """
        left = self._buf[:, self._i : self._i + n]
        self._i += left.shape[1]
        more = n - left.shape[1]
        if out is None:
            if more == 0:
                return left
            out = np.empty((len(self.generators), n, self.agents, 2))
        out[:, : left.shape[1]] = left
        if more:
            for r, g in enumerate(self.generators):
                g.random(out=out[r, left.shape[1] :])
        return out

    def pending(self) -> int:
        """Steps of uniforms drawn into the current block and not yet taken."""
        return self._buf.shape[1] - self._i

    def draw(self, n: int, lo: int, hi: int, out: np.ndarray) -> np.ndarray:
        """float ``[hi - lo, n, K, 2]``: the next ``n`` steps' uniforms of runs
        ``lo..hi-1`` only, drawn into ``out``. Only when nothing is pending
        (:meth:`pending`); after every run has drawn its ``n`` steps (each run once),
        the streams stand where :meth:`take` of ``n`` would have left them."""
        if self.pending():
            raise RuntimeError("Streams.draw: uniforms of the current block are pending")
        for r in range(lo, hi):
            self.generators[r].random(out=out[r - lo])
        return out
