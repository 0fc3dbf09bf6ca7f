"""qpatrol.util.arrays: flat positions pick the elements fancy indexing picks, and the
reductions over ports give numpy's values, to the bit."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from qpatrol.util.arrays import at, flat, port_any, port_max, take_rows


@given(st.integers(1, 5), st.integers(1, 4), st.integers(1, 9), st.integers(0, 2**32 - 1))
def test_flat_positions_are_the_fancy_index(r, k, c, seed):
    rng = np.random.default_rng(seed)
    a = rng.integers(0, 1000, (r, k, c, 3))
    rows = rng.integers(0, r, 7)
    ks = rng.integers(0, k, 7)
    cells = rng.integers(0, c, 7)
    ports = rng.integers(0, 3, 7)
    assert (flat(a)[at(a.shape, rows, ks, cells, ports)] == a[rows, ks, cells, ports]).all()
    assert (take_rows(a, at(a.shape, rows, ks, cells)) == a[rows, ks, cells]).all()
    assert (flat(a, 2)[at(a.shape, rows, ks)] == a[rows, ks]).all()
    # a scalar among the indices, broadcast; the first axis's size is never read
    assert (flat(a)[at((-1, *a.shape[1:]), rows, 0, cells, 1)] == a[rows, 0, cells, 1]).all()
    # a write through the view lands in the array
    b = a.copy()
    flat(b)[at(b.shape, rows, ks, cells, ports)] = -1
    c_ = a.copy()
    c_[rows, ks, cells, ports] = -1
    assert (b == c_).all()


def test_flat_refuses_an_array_it_cannot_view():
    a = np.zeros((4, 6))
    with pytest.raises(ValueError, match="not C-contiguous"):
        flat(a[:, ::2])
    assert np.shares_memory(flat(a[1:3]), a)  # a slice of runs is still one block


@given(st.integers(0, 2**32 - 1), st.integers(1, 8))
def test_port_reductions_are_numpys(seed, d):
    rng = np.random.default_rng(seed)
    q = rng.choice([-np.inf, -0.0, 0.0, 1.5, 2.0, np.nan, 3.0], (6, 5, d))
    got, want = port_max(q), q.max(axis=-1)
    assert np.array_equal(got, want, equal_nan=True)
    # the sign of a zero maximum is numpy's where the zeros agree in sign; among zeros of
    # both signs neither IEEE 754 nor numpy fixes it (numpy's own max gives either,
    # depending on the processor's vector instructions)
    zero = q == 0
    mixed = (zero & np.signbit(q)).any(axis=-1) & (zero & ~np.signbit(q)).any(axis=-1)
    defined = ~((want == 0) & mixed)
    assert np.array_equal(np.signbit(got)[defined], np.signbit(want)[defined])
    legal = rng.random((6, 5, d)) < 0.3
    assert (port_any(legal) == legal.any(axis=-1)).all()
