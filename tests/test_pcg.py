"""numpy's PCG64 in the compiled loop, and the streams' words it steps.

The compiled loop draws a run's uniforms from its stream's state (four uint64 words)
where the numpy engine reads blocks drawn by ``Generator.random``; the numbers, and
where each stream stands afterwards, must be numpy's to the bit. The reference here is numpy itself:
``Generator.random``, ``PCG64.advance`` and the generators' states.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from qpatrol.config import from_flat
from qpatrol.world import rng
from qpatrol.world.rng import Streams, run_seeds

pcg = pytest.importorskip("qpatrol.engines.compiled.pcg")
numba = pytest.importorskip("numba")

M64 = (1 << 64) - 1


def words_of(g: np.random.Generator) -> np.ndarray:
    st = g.bit_generator.state["state"]
    s, inc = st["state"], st["inc"]
    return np.array([s & M64, s >> 64, inc & M64, inc >> 64], dtype=np.uint64)


def state_of(words: np.ndarray) -> int:
    return int(words[0]) | int(words[1]) << 64


@numba.njit
def pairs(words_r, n):
    """``n`` pairs of uniforms drawn as the kernels draw them (two_steps, uniform)."""
    s_lo, s_hi, inc_lo, inc_hi = words_r[0], words_r[1], words_r[2], words_r[3]
    inc2_lo, inc2_hi = pcg.double_inc(inc_lo, inc_hi)
    out = np.empty((n, 2))
    for i in range(n):
        a_lo, a_hi, s_lo, s_hi = pcg.two_steps(s_lo, s_hi, inc_lo, inc_hi, inc2_lo, inc2_hi)
        out[i, 0] = pcg.uniform(a_lo, a_hi)
        out[i, 1] = pcg.uniform(s_lo, s_hi)
    pcg.store(words_r, s_lo, s_hi, 0)
    return out


@pytest.mark.parametrize("seed", [0, 1, 12345, 2**63 + 5])
def test_fill_draws_generator_random_to_the_bit(seed):
    g = np.random.Generator(np.random.PCG64(seed))
    w = words_of(g)
    out = np.empty((37, 3, 2))
    pcg.fill(w, out)
    assert np.array_equal(out, g.random((37, 3, 2)))
    assert state_of(w) == g.bit_generator.state["state"]["state"]


@pytest.mark.parametrize("seed", [3, 99])
def test_two_steps_give_consecutive_draws(seed):
    g = np.random.Generator(np.random.PCG64(seed))
    w = words_of(g)
    got = pairs(w, 500)
    assert np.array_equal(got, g.random((500, 2)))
    assert state_of(w) == g.bit_generator.state["state"]["state"]


def test_uniform_of_a_hand_made_state():
    """The output function by hand: hi = 2**63 + 5 (rotation 32), lo = 7."""
    hi, lo = (1 << 63) | 5, 7
    x = hi ^ lo
    rot = hi >> 58
    word = ((x >> rot) | (x << (64 - rot))) & M64
    assert pcg.uniform(np.uint64(lo), np.uint64(hi)) == (word >> 11) / 2.0**53


@pytest.mark.parametrize("delta", [0, 1, 2, 7, 12345, 2**40 + 3])
def test_advance_is_numpys(delta):
    bg = np.random.PCG64(2024)
    g = np.random.Generator(bg)
    w = words_of(g)
    pcg.advance(w, delta)
    bg.advance(delta)
    assert state_of(w) == bg.state["state"]["state"]


def test_store_steps_past_the_skipped_draws():
    g = np.random.Generator(np.random.PCG64(8))
    w = words_of(g)
    pcg.store(w, w[0], w[1], 10)
    g.random(10)
    assert state_of(w) == g.bit_generator.state["state"]["state"]


def test_numpys_advance_goes_back_by_the_period_less_n():
    """What ``Streams.words`` relies on to give back pending uniforms."""
    bg = np.random.PCG64(5)
    st = bg.state["state"]
    bg.advance(1000)
    bg.advance((1 << 128) - 1000)
    assert bg.state["state"] == st


def test_words_give_back_pending_uniforms_and_generators_catch_up():
    """A numpy engine took 3 of a block of 8 steps: the words stand after those 3. A
    caller that draws 10 steps from the words and steps them leaves the generators
    where ``take(10)`` would have; ``next`` then agrees, and so does a pickle."""
    seeds = run_seeds(7, 4)
    a, b = Streams(seeds, 3, block=8), Streams(seeds, 3, block=8)
    for _ in range(3):
        assert np.array_equal(a.next(), b.next())
    w = b.words()
    assert b.pending() == 0
    drawn = np.empty((4, 10, 3, 2))
    for r in range(4):
        pcg.fill(w[r], drawn[r])
    assert np.array_equal(drawn, a.take(10))
    assert b.words() is w  # the same array, still ahead of the generators
    c = pickle.loads(pickle.dumps(b))  # pickled while its words were ahead
    nb = b.next()
    assert np.array_equal(nb, a.next())
    assert np.array_equal(c.next(), nb)
    assert [g.bit_generator.state for g in a.generators] == [
        g.bit_generator.state for g in b.generators
    ]


def test_words_refuse_another_bit_generator():
    s = Streams(run_seeds(1, 2), 1)
    s.generators[1] = np.random.Generator(np.random.MT19937(1))
    with pytest.raises(TypeError, match="run 1 draws from MT19937"):
        s.words()


def test_old_pickles_of_streams_still_load():
    """A checkpoint written before the words held ``generators`` in the object."""
    s = Streams(run_seeds(2, 2), 2, block=4)
    old = {
        "generators": rng.generators(run_seeds(2, 2)),
        "agents": 2,
        "block": 4,
        "_buf": np.empty((2, 0, 2, 2)),
        "_i": 0,
    }
    t = Streams.__new__(Streams)
    t.__setstate__(old)
    assert np.array_equal(t.next(), s.next())
    assert np.array_equal(t.words(), s.words())


@pytest.mark.parametrize(("agents", "max_ep", "steps"), [(1, 250, 900), (3, 90, 300)])
def test_the_loop_draws_what_the_numpy_engine_draws(
    monkeypatch, tmp_path, rooms_map, agents, max_ep, steps
):
    """The compiled loop, drawing each step's uniforms from the words, against the numpy
    engine, whose streams draw them with ``Generator.random``: every file is the same;
    and every run's stream ends a whole number of team steps' draws from its start, the
    same number for every run, runs that met their episode quota early too (the loop
    steps their words past the steps they sat out)."""
    from qpatrol import run
    from qpatrol.run import write_run

    made: list[tuple[tuple, Streams]] = []

    class Spy(Streams):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append((a, self))

    monkeypatch.setattr(run, "Streams", Spy)
    monkeypatch.setattr(run, "COMPILED_BLOCK", 1024)  # blocks of 1024 // (5 K) steps
    monkeypatch.setattr(run, "COMPILED_MIN_STEPS", 64)
    flat = {
        "map": str(rooms_map),
        "seed": 4,
        "runs": 5,
        "agents": agents,
        "steps": steps,
        "episodes": 3,
        "max_episode_steps": max_ep,
        "learning.epsilon": 0.1,
        "battery.enabled": False,
    }
    files = {}
    for engine in ("numpy", "numba"):
        made.clear()
        result = run.simulate(from_flat({**flat, "engine": engine}))
        ((args, streams),) = made
        out = write_run(result, tmp_path / engine, meta={"started": "-", "ended": "-"})
        files[engine] = {p.name: p.read_bytes() for p in out.iterdir() if p.name != "meta.json"}
        done = result.state.steps_done  # runs stopped at different steps, mid-block
        assert len(set(done.tolist())) >= 3 and done.max() < steps
    assert files["numba"] == files["numpy"]
    # where each stream of the compiled run stands: n team steps' draws from its start
    ends = [g.bit_generator.state["state"]["state"] for g in streams.generators]
    fresh = Streams(*args).generators
    per_step = agents * 2
    fresh[0].bit_generator.advance(int(done.max()) * per_step)
    n = int(done.max())
    while fresh[0].bit_generator.state["state"]["state"] != ends[0]:
        assert n < steps + 1, "run 0's stream is not a whole number of steps on"
        fresh[0].bit_generator.advance(per_step)
        n += 1
    for r, g in enumerate(fresh[1:], start=1):
        g.bit_generator.advance(n * per_step)
        assert g.bit_generator.state["state"]["state"] == ends[r], r


def test_every_compiled_function_of_the_loop_is_keyed_on_the_package():
    """numba keys a function's on-disk cache on its own file: the loop and the kernels
    it calls (not inlined) inline the draws of this file and the strategies' code, so
    their caches must follow every file of ``qpatrol.engines.compiled`` (``key_cache``)
    or an edit there would run stale machine code."""
    from qpatrol.engines import numba_core

    called = [
        f
        for f in vars(numba_core).values()
        if hasattr(f, "py_func")
        and f.py_func.__module__ == numba_core.__name__
        and f.targetoptions.get("inline") != "always"
    ]
    assert {f.__name__ for f in called} >= {"run_block", "_solo_qlearning", "_team_qlearning"}
    for f in called:
        stamp = getattr(getattr(f._cache, "_cache_file", None), "_source_stamp", None)
        if stamp is not None:  # numba's private cache object, as key_cache finds it
            assert stamp[0] == "qpatrol", f.__name__


def test_every_compiled_function_of_the_package_is_keyed_on_the_package():
    """Every function of ``qpatrol.engines.compiled`` that numba compiles as a function
    of its own (not inlined) inlines code of other files of the package: its cache too
    must follow them all (``numba_core._key_caches``)."""
    import importlib
    import pkgutil

    from numba.core.dispatcher import Dispatcher

    from qpatrol.engines import compiled, numba_core  # noqa: F401 (keys the caches)

    seen = []
    for info in pkgutil.iter_modules(compiled.__path__):
        mod = importlib.import_module(f"{compiled.__name__}.{info.name}")
        for f in vars(mod).values():
            if (
                isinstance(f, Dispatcher)
                and f.py_func.__module__ == mod.__name__
                and f.targetoptions.get("inline") != "always"
            ):
                seen.append(f)
                stamp = getattr(getattr(f._cache, "_cache_file", None), "_source_stamp", None)
                if stamp is not None:
                    assert stamp[0] == "qpatrol", f"{mod.__name__}.{f.__name__}"
    assert {f.__name__ for f in seen} >= {"end", "enter", "visit", "update", "_score"}
