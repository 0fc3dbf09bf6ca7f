"""Random streams: one ``numpy.random.Generator`` per run, from ``SeedSequence`` children.

Run ``r`` of sweep point ``p`` draws from ``SeedSequence(seed, spawn_key=(p, r))``
(``train`` is point 0), so a run's numbers depend only on the root seed and its
coordinates, never on which other runs share its batch, on ``--jobs`` or on the
backend. Each step consumes exactly ``2 * agents`` uniforms from every run's
stream, whether they are used or not, so the streams stay aligned.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np


def run_seed(seed: int, point: int, r: int) -> np.random.SeedSequence:
    """The stream of run ``r`` of sweep point ``point``: ``SeedSequence(seed,
    spawn_key=(point, r))``."""
    return np.random.SeedSequence(seed, spawn_key=(point, r))


def run_seeds(seed: int, runs: int | range, point: int = 0) -> list[np.random.SeedSequence]:
    """:func:`run_seed` of each run index r."""
    idx = range(runs) if isinstance(runs, int) else runs
    return [run_seed(seed, point, r) for r in idx]


class RunKey(NamedTuple):
    """Run ``run`` of sweep point ``point`` under root seed ``seed``: the stream of
    ``SeedSequence(seed, spawn_key=(point, run))`` (:func:`run_seed`), named without
    building the SeedSequence. :class:`Streams` seeds a batch of keys at once
    (:func:`state_words`): 2,048 generators in 8.8 ms instead of 31.5 ms."""

    seed: int
    point: int
    run: int

    def sequence(self) -> np.random.SeedSequence:
        """The SeedSequence this key stands for."""
        return run_seed(self.seed, self.point, self.run)


def run_keys(seed: int, runs: int | range, point: int = 0) -> list[RunKey]:
    """:class:`RunKey` of each run index r (the streams of :func:`run_seeds`)."""
    idx = range(runs) if isinstance(runs, int) else runs
    return [RunKey(seed, point, r) for r in idx]


Seed = np.random.SeedSequence | RunKey

# numpy's SeedSequence (numpy/random/bit_generator.pyx, after M. O'Neill's seed_seq
# alternative): its hash constants, pool of 4 words, 32-bit arithmetic
_INIT_A, _MULT_A = 0x43B0D7E5, 0x931E8875
_INIT_B, _MULT_B = 0x8B51F9DD, 0x58F38DED
_MIX_L, _MIX_R = 0xCA01F9DD, 0x4973F715
_POOL = 4
_M32 = 0xFFFFFFFF
_M64 = (1 << 64) - 1


def _words32(n: int) -> list[int]:
    """The 32-bit words of a non-negative int, least significant first (0: one word),
    as SeedSequence splits its entropy and spawn key."""
    out = [n & _M32]
    n >>= 32
    while n:
        out.append(n & _M32)
        n >>= 32
    return out


def state_words(seed: int, point: int, runs: np.ndarray) -> np.ndarray:
    """uint64 ``[R, 4]``: ``SeedSequence(seed, spawn_key=(point, r)).generate_state(4,
    np.uint64)`` for each r of ``runs`` (int ``[R]``, each below 2**32; the seed and the
    point may be any non-negative ints), the words a
    PCG64 is seeded with, computed for all runs at once with SeedSequence's own
    arithmetic (``tests/test_rng.py`` compares them with numpy's)."""
    runs = np.asarray(runs, dtype=np.int64)
    if seed < 0 or point < 0 or (runs.size and (runs.min() < 0 or runs.max() > _M32)):
        raise ValueError("state_words: seed and point must be >= 0, runs in 0..2**32-1")
    n = runs.size
    ent = _words32(seed)
    ent += [0] * (_POOL - len(ent))  # a spawn key follows: the run entropy fills the pool
    cols = [np.full(n, w, dtype=np.uint32) for w in ent + _words32(point)]
    cols.append(runs.astype(np.uint32))
    hc = _INIT_A

    def hashmix(value: np.ndarray) -> np.ndarray:
        nonlocal hc
        value = value ^ np.uint32(hc)
        hc = (hc * _MULT_A) & _M32
        value = value * np.uint32(hc)
        return value ^ (value >> np.uint32(16))

    def mix(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        r = np.uint32(_MIX_L) * x - np.uint32(_MIX_R) * y
        return r ^ (r >> np.uint32(16))

    pool = [hashmix(cols[i]) for i in range(_POOL)]
    for i_src in range(_POOL):
        for i_dst in range(_POOL):
            if i_src != i_dst:
                pool[i_dst] = mix(pool[i_dst], hashmix(pool[i_src]))
    for i_src in range(_POOL, len(cols)):
        for i_dst in range(_POOL):
            pool[i_dst] = mix(pool[i_dst], hashmix(cols[i_src]))
    hb = _INIT_B
    out = np.empty((n, 8), dtype=np.uint32)
    for i in range(8):
        v = pool[i % _POOL] ^ np.uint32(hb)
        hb = (hb * _MULT_B) & _M32
        v = v * np.uint32(hb)
        out[:, i] = v ^ (v >> np.uint32(16))
    lo, hi = out[:, 0::2].astype(np.uint64), out[:, 1::2].astype(np.uint64)
    return lo | (hi << np.uint64(32))


class KeyWords:
    """The seed sequence of a generator that :func:`generators` seeded from a
    :class:`RunKey` (what its ``bit_generator.seed_seq`` is, and what a checkpoint
    saves with it): the key, and the four words a PCG64 asks its seed sequence for,
    ``generate_state(4, np.uint64)`` of the key's SeedSequence, computed beforehand by
    :func:`state_words`. :meth:`sequence` builds that SeedSequence."""

    def __init__(self, key: RunKey, words: np.ndarray):
        self.key = key
        self.words = words

    def generate_state(self, n_words: int, dtype: type = np.uint32) -> np.ndarray:
        if n_words != 4 or np.dtype(dtype) != np.uint64:
            raise ValueError("KeyWords hold PCG64's four uint64 words only; use .sequence()")
        return self.words

    def sequence(self) -> np.random.SeedSequence:
        """The SeedSequence of the key (its ``generate_state(4, np.uint64)`` is
        ``words``)."""
        return self.key.sequence()


np.random.bit_generator.ISeedSequence.register(KeyWords)


def generators(seeds: Sequence[Seed]) -> list[np.random.Generator]:
    """A PCG64 ``Generator`` per seed (SeedSequence or :class:`RunKey`); the keys of one
    (seed, point) are seeded together by :func:`state_words`, and their generators'
    seed sequences are :class:`KeyWords`."""
    out: list[np.random.Generator | None] = [None] * len(seeds)
    groups: dict[tuple[int, int], list[int]] = {}
    for i, s in enumerate(seeds):
        if isinstance(s, RunKey) and 0 <= s.run <= _M32:
            groups.setdefault((s.seed, s.point), []).append(i)
        else:
            seq = s.sequence() if isinstance(s, RunKey) else s
            out[i] = np.random.Generator(np.random.PCG64(seq))
    for (seed, point), rows in groups.items():
        words = state_words(seed, point, np.array([seeds[i].run for i in rows]))
        for i, w in zip(rows, words, strict=True):
            out[i] = np.random.Generator(np.random.PCG64(KeyWords(seeds[i], w)))
    return out  # type: ignore[return-value]


class Streams:
    """Per-step uniforms ``[R, K, 2]`` for a batch of runs, drawn in blocks.

    The Python loop over runs happens once per ``block`` steps, not in every step.
    Drawing ``(B, K, 2)`` doubles twice gives the same numbers as ``(2B, K, 2)`` once,
    so the block size never changes a result. The compiled engine's loop draws
    the same numbers itself, from the streams' states (:meth:`words`), and the
    generators catch up before anyone else draws from or saves them.
    """

    #: Steps drawn at once by :meth:`next` unless told otherwise.
    BLOCK = 512

    def __init__(self, seeds: Sequence[Seed], agents: int, block: int = BLOCK):
        self._gens = generators(seeds)
        self.agents = agents
        self.block = block
        self._buf = np.empty((len(seeds), 0, agents, 2))
        self._i = 0
        # the streams' PCG64 states as words (see words()): one array for the batch's
        # life, valid or not; where valid and ``_ahead``, the generators lag behind it
        self._words = np.zeros((len(seeds), 4), dtype=np.uint64)
        self._words_valid = False
        self._ahead = False
        self._extra: list[tuple[int, int]] = []  # each generator's (has_uint32, uinteger)

    @property
    def generators(self) -> list[np.random.Generator]:
        """The runs' generators, brought up to date with :meth:`words` first (and the
        words then read again when next asked for: the caller may draw)."""
        self._sync()
        self._words_valid = False
        return self._gens

    def words(self) -> np.ndarray:
        """uint64 ``[R, 4]``: each run's PCG64 state as words (state low, high, inc low,
        high), for a caller that draws the stream's next uniforms itself, in order and to
        the bit, and steps these words past them
        (:mod:`qpatrol.engines.compiled.pcg`). Uniforms drawn into the current block
        and not yet taken (:meth:`pending`) are given back first: the words stand where
        the taken ones left the stream. The same array at every call; the generators
        catch up when next used (:attr:`generators`, :meth:`next`, :meth:`take`, a
        checkpoint: :meth:`__getstate__`)."""
        if not self._words_valid:
            back = self.pending() * self.agents * 2
            self._buf = self._buf[:, :0]
            self._i = 0
            self._extra = []
            for r, g in enumerate(self._gens):
                bg = g.bit_generator
                if not isinstance(bg, np.random.PCG64):
                    raise TypeError(f"Streams.words: run {r} draws from {type(bg).__name__}")
                if back:  # numpy's jump, by back draws less than its period: back
                    bg.advance((1 << 128) - back)
                st = bg.state
                s, inc = st["state"]["state"], st["state"]["inc"]
                self._words[r] = (s & _M64, s >> 64, inc & _M64, inc >> 64)
                self._extra.append((st["has_uint32"], st["uinteger"]))
            self._words_valid = True
        self._ahead = True
        return self._words

    def _sync(self) -> None:
        """Set the generators to the words' states, when the words ran ahead."""
        if self._words_valid and self._ahead:
            for g, w, (has, extra) in zip(
                self._gens, self._words.tolist(), self._extra, strict=True
            ):
                g.bit_generator.state = {
                    "bit_generator": "PCG64",
                    "state": {"state": w[0] | w[1] << 64, "inc": w[2] | w[3] << 64},
                    "has_uint32": has,
                    "uinteger": extra,
                }
            self._ahead = False

    def __getstate__(self) -> dict:
        """The attributes a checkpoint saves: the generators caught up with the words."""
        self._sync()
        d = dict(self.__dict__)
        d["_words_valid"] = False
        return d

    def __setstate__(self, d: dict) -> None:
        """Set the attributes :meth:`__getstate__` gave (or a dict of ``generators``
        without words, which it gave before the words existed)."""
        if "generators" in d:  # saved before the words
            d["_gens"] = d.pop("generators")
            d.update(
                _words=np.zeros((len(d["_gens"]), 4), dtype=np.uint64),
                _words_valid=False,
                _ahead=False,
                _extra=[],
            )
        self.__dict__.update(d)

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
