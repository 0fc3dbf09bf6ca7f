"""numpy's PCG64 inside the compiled loop: each run's uniforms drawn where they are used.

A run's stream is numpy's ``PCG64`` bit generator (:func:`qpatrol.world.rng.generators`):
a 128-bit state ``s`` stepped by ``s <- s M + inc (mod 2**128)``, each step giving the
64-bit word ``rotr(hi(s) ^ lo(s), hi(s) >> 58)`` and each double ``(word >> 11) /
2**53`` (``Generator.random``). Here a state is four uint64 words ``(state low, state
high, inc low, inc high)`` (:meth:`qpatrol.world.rng.Streams.words`, ``[R, 4]``), and the
arithmetic is numpy's own, so the doubles are the same to the bit
(``tests/test_pcg.py``). The compiled loop draws each robot's two uniforms of a step
here (:func:`step_uniforms`), a run's state in registers, instead of reading them from
a block drawn beforehand by ``Generator.random``, which costs a trip through memory and
a Python call per run and block.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

#: numpy's PCG64 multiplier ``M`` (PCG_DEFAULT_MULTIPLIER_128), high and low words.
MULT = (2549297995355413924 << 64) | 4865540595714422341
_M128 = (1 << 128) - 1
M_HI, M_LO = np.uint64(MULT >> 64), np.uint64(MULT & (2**64 - 1))
#: ``M**2 mod 2**128``: two steps at once (``s <- s M**2 + inc (M + 1)``).
M2_HI = np.uint64((MULT * MULT & _M128) >> 64)
M2_LO = np.uint64(MULT * MULT & (2**64 - 1))
#: 2**-53, numpy's ``next_double`` scale.
_SCALE = 1.0 / 9007199254740992.0


@intrinsic
def mul_add(typingctx, a_lo, a_hi, b_lo, b_hi, c_lo, c_hi):
    """``a b + c mod 2**128`` of three 128-bit numbers given as (low, high) uint64 words;
    returns ``(low, high)``. One 128-bit multiply in LLVM (a 64 x 64 -> 128 product and
    two 64-bit ones on x86-64)."""
    u64 = types.uint64
    sig = types.UniTuple(u64, 2)(u64, u64, u64, u64, u64, u64)

    def codegen(context, builder, signature, args):
        i128 = ir.IntType(128)
        shift = ir.Constant(i128, 64)

        def join(lo, hi):
            return builder.or_(builder.zext(lo, i128), builder.shl(builder.zext(hi, i128), shift))

        a, b, c = join(args[0], args[1]), join(args[2], args[3]), join(args[4], args[5])
        x = builder.add(builder.mul(a, b), c)
        lo = builder.trunc(x, ir.IntType(64))
        hi = builder.trunc(builder.lshr(x, shift), ir.IntType(64))
        return context.make_tuple(builder, signature.return_type, [lo, hi])

    return sig, codegen


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def uniform(s_lo, s_hi):
    """The double that PCG64 gives in the state ``(s_lo, s_hi)`` reached by a step:
    ``(rotr(hi ^ lo, hi >> 58) >> 11) / 2**53``, in [0, 1)."""
    x = s_hi ^ s_lo
    rot = s_hi >> np.uint64(58)
    word = (x >> rot) | (x << ((np.uint64(64) - rot) & np.uint64(63)))
    # the word's top 53 bits fit an int64: one signed conversion, the same double
    return np.float64(np.int64(word >> np.uint64(11))) * _SCALE


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def double_inc(inc_lo, inc_hi):
    """``inc (M + 1) mod 2**128``: the increment of two steps at once."""
    return mul_add(inc_lo, inc_hi, M_LO, M_HI, inc_lo, inc_hi)


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def two_steps(s_lo, s_hi, inc_lo, inc_hi, inc2_lo, inc2_hi):
    """Two steps from the state ``(s_lo, s_hi)``: ``(first lo, first hi, second lo,
    second hi)``, the states whose :func:`uniform` are the next two doubles. The second
    comes from the first state given, not from the first step (``s M**2 + inc (M +
    1)``, ``inc2`` from :func:`double_inc`), so that a run's chain of dependent
    multiplications is one per pair of draws."""
    a_lo, a_hi = mul_add(s_lo, s_hi, M_LO, M_HI, inc_lo, inc_hi)
    b_lo, b_hi = mul_add(s_lo, s_hi, M2_LO, M2_HI, inc2_lo, inc2_hi)
    return a_lo, a_hi, b_lo, b_hi


@njit(cache=True, nogil=True, _nrt=False)
def advance(words_r, delta):
    """Step the state ``words_r`` (uint64 ``[4]``: state low, high, inc low, high) by
    ``delta`` >= 0 draws in place, in O(log delta) (numpy's ``pcg_advance_lcg_128``:
    the same state as ``delta`` draws)."""
    s_lo, s_hi, inc_lo, inc_hi = words_r[0], words_r[1], words_r[2], words_r[3]
    acc_m_lo, acc_m_hi = np.uint64(1), np.uint64(0)
    acc_p_lo, acc_p_hi = np.uint64(0), np.uint64(0)
    cur_m_lo, cur_m_hi = M_LO, M_HI
    cur_p_lo, cur_p_hi = inc_lo, inc_hi
    zero = np.uint64(0)
    while delta > 0:
        if delta & 1:
            acc_m_lo, acc_m_hi = mul_add(acc_m_lo, acc_m_hi, cur_m_lo, cur_m_hi, zero, zero)
            acc_p_lo, acc_p_hi = mul_add(acc_p_lo, acc_p_hi, cur_m_lo, cur_m_hi, cur_p_lo, cur_p_hi)
        # cur_plus <- (cur_mult + 1) cur_plus; cur_mult <- cur_mult**2
        cur_p_lo, cur_p_hi = mul_add(cur_m_lo, cur_m_hi, cur_p_lo, cur_p_hi, cur_p_lo, cur_p_hi)
        cur_m_lo, cur_m_hi = mul_add(cur_m_lo, cur_m_hi, cur_m_lo, cur_m_hi, zero, zero)
        delta >>= 1
    s_lo, s_hi = mul_add(acc_m_lo, acc_m_hi, s_lo, s_hi, acc_p_lo, acc_p_hi)
    words_r[0], words_r[1] = s_lo, s_hi


@njit(cache=True, nogil=True, _nrt=False)
def fill(words_r, out):
    """Draw ``out.size`` doubles of the stream ``words_r`` into ``out`` (flat order) and
    step the state past them: ``Generator.random(out=out)``, to the bit."""
    s_lo, s_hi, inc_lo, inc_hi = words_r[0], words_r[1], words_r[2], words_r[3]
    flat = out.reshape(-1)
    for i in range(flat.size):
        s_lo, s_hi = mul_add(s_lo, s_hi, M_LO, M_HI, inc_lo, inc_hi)
        flat[i] = uniform(s_lo, s_hi)
    words_r[0], words_r[1] = s_lo, s_hi


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def store(words_r, s_lo, s_hi, skipped):
    """Store the state ``(s_lo, s_hi)`` in ``words_r`` and step it past ``skipped``
    draws more: those of the steps a run sat out at the end of a block (a stream gives
    ``2 x agents`` uniforms per step whether the run takes them or not)."""
    words_r[0], words_r[1] = s_lo, s_hi
    if skipped > 0:
        advance(words_r, skipped)


@njit(cache=True, nogil=True, _nrt=False, inline="always")
def step_uniforms(stream, ur):
    """Draw one team step's uniforms into ``ur`` float64 ``[K, 2]`` (robot k's epsilon
    and tie-break draws, in the order ``Generator.random((K, 2))`` gives them) from
    ``stream`` ``(state lo, state hi, inc lo, inc hi, inc2 lo, inc2 hi)`` (``inc2``:
    :func:`double_inc`). Returns the state after the draws ``(lo, hi)``."""
    s_lo, s_hi, inc_lo, inc_hi, inc2_lo, inc2_hi = stream
    for k in range(ur.shape[0]):
        a_lo, a_hi, s_lo, s_hi = two_steps(s_lo, s_hi, inc_lo, inc_hi, inc2_lo, inc2_hi)
        ur[k, 0] = uniform(a_lo, a_hi)
        ur[k, 1] = uniform(s_lo, s_hi)
    return s_lo, s_hi
