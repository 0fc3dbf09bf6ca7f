"""Seeding a batch at once (:func:`qpatrol.world.rng.state_words`, :class:`RunKey`) gives the
streams numpy's own ``SeedSequence`` gives, to the bit."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from qpatrol.world import rng

SEEDS = [0, 1, 7, 12345, 2**32 - 1, 2**32, 2**40 + 3, 2**130 + 77]  # 1 to 5 words
POINTS = [0, 1, 5, 2**31, 2**32 - 1, 2**33 + 9]  # the last two words long
RUNS = np.array([0, 1, 2, 3, 100, 2047, 65536, 2**32 - 1])


def numpy_words(seed: int, point: int, r: int) -> np.ndarray:
    return np.random.SeedSequence(seed, spawn_key=(point, r)).generate_state(4, np.uint64)


@pytest.mark.parametrize("seed", SEEDS)
def test_state_words_are_seedsequences(seed: int) -> None:
    for point in POINTS:
        got = rng.state_words(seed, point, RUNS)
        want = np.array([numpy_words(seed, point, int(r)) for r in RUNS])
        assert got.dtype == np.uint64 and got.shape == (RUNS.size, 4)
        np.testing.assert_array_equal(got, want)


def test_state_words_of_no_runs_and_bad_input() -> None:
    assert rng.state_words(0, 0, np.array([], dtype=np.int64)).shape == (0, 4)
    with pytest.raises(ValueError, match="seed and point must be >= 0"):
        rng.state_words(-1, 0, np.array([0]))
    with pytest.raises(ValueError, match="seed and point must be >= 0"):
        rng.state_words(0, 0, np.array([2**32]))


def test_generators_of_keys_draw_what_seedsequences_draw() -> None:
    # keys of two points and two seeds, interleaved with SeedSequences, and a run number
    # too large for the batched seeding (it falls back to numpy's SeedSequence)
    seeds: list[rng.Seed] = [
        rng.RunKey(3, 2, 0),
        rng.run_seed(9, 0, 4),
        rng.RunKey(3, 0, 5),
        rng.RunKey(3, 2, 1),
        rng.RunKey(11, 2, 2**33),
        rng.RunKey(3, 2, 7),
    ]
    got = rng.generators(seeds)
    for s, g in zip(seeds, got, strict=True):
        seq = s.sequence() if isinstance(s, rng.RunKey) else s
        ref = np.random.Generator(np.random.PCG64(seq))
        assert g.bit_generator.state == ref.bit_generator.state
        np.testing.assert_array_equal(g.random(50), ref.random(50))


def test_streams_of_keys_and_of_seedsequences_agree() -> None:
    a = rng.Streams(rng.run_keys(5, range(3, 9), point=4), agents=3, block=7)
    b = rng.Streams(rng.run_seeds(5, range(3, 9), point=4), agents=3, block=7)
    for _ in range(10):
        np.testing.assert_array_equal(a.next(), b.next())
    np.testing.assert_array_equal(a.take(20), b.take(20))


def test_a_seeded_generator_pickles_and_goes_on() -> None:
    g = rng.generators([rng.RunKey(3, 2, 0)])[0]
    g.random(10)
    back = pickle.loads(pickle.dumps(g))
    ref = np.random.Generator(np.random.PCG64(rng.run_seed(3, 2, 0)))
    ref.random(10)
    np.testing.assert_array_equal(back.random(5), ref.random(5))


def test_a_keyed_generator_names_its_key_and_seedsequence() -> None:
    g = rng.generators([rng.RunKey(6, 3, 8)])[0]
    seq = g.bit_generator.seed_seq
    assert isinstance(seq, rng.KeyWords) and seq.key == rng.RunKey(6, 3, 8)
    assert seq.sequence().entropy == 6 and seq.sequence().spawn_key == (3, 8)
    np.testing.assert_array_equal(seq.words, numpy_words(6, 3, 8))
    with pytest.raises(ValueError, match="four uint64 words"):
        seq.generate_state(8)


def test_key_names_its_seedsequence() -> None:
    s = rng.RunKey(4, 1, 9).sequence()
    assert s.entropy == 4 and s.spawn_key == (1, 9)
    assert rng.run_keys(4, range(2, 4), 1) == [rng.RunKey(4, 1, 2), rng.RunKey(4, 1, 3)]
