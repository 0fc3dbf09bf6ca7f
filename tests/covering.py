"""Covering tables: fewer rows than a product of settings, every pair of values kept.

A test run on every combination of n settings costs their product; the bugs the
engine-equality and sweep tests have met are in what one or two settings do together.
A table in which every pair of values of any two settings occurs in some row tests
each of those pairs, in a fraction of the rows.
"""

from __future__ import annotations

import itertools

#: The four pairs of two booleans, and the same four as an orthogonal array of three
#: booleans (every pair of values of any two of the three columns occurs once).
BOTH2 = [(True, True), (True, False), (False, True), (False, False)]
BOTH3 = [(True, True, True), (True, False, False), (False, True, False), (False, False, True)]


def covers_every_pair(rows: list[tuple], domains: list[tuple]) -> bool:
    """Every pair of values of any two columns of ``rows`` occurs in some row (a covering
    subset of the product of ``domains``: what two settings do together is tested)."""
    return all(
        {(r[i], r[j]) for r in rows} == set(itertools.product(domains[i], domains[j]))
        for i, j in itertools.combinations(range(len(domains)), 2)
    )


def pairs(domains: list[tuple], rows: list[tuple]) -> list[tuple]:
    """``rows``, checked to cover every pair of values of ``domains`` (at collection)."""
    assert covers_every_pair(rows, domains), rows
    assert all(len(r) == len(domains) for r in rows)
    return rows
