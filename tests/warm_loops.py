"""Compile the compiled engine's loops into numba's cache before a parallel test run.

Each loop (:func:`qpatrol.engines.compiled_loop`: ``any``, ``qlearning``,
``qlearning-solo``, ``qlearning-team``) is one machine code per kind of map (a grid, a
graph), compiled on first use in tens of seconds on an empty cache. When the workers of
a parallel run meet a loop at once, one compiles it and the others wait for it
(:mod:`qpatrol.engines.coldstart`), idle. ``tests/conftest.py`` runs this module in two
processes before the workers start, each compiling half of the eight, so that both
cores compile and the workers then load every loop from the cache. Results do not
depend on it: a warm cache only saves time.

``python tests/warm_loops.py LOOP@KIND ...`` (KIND: ``grid`` or ``graph``).
"""

from __future__ import annotations

import sys

#: The settings that select each loop (besides ``engine: numba``).
LOOPS = {
    "any": {"policy": "random"},
    "qlearning": {"policy": "qlearning", "record.transitions": True},
    "qlearning-solo": {"policy": "qlearning", "agents": 1},
    "qlearning-team": {"policy": "qlearning"},
}
MAPS = {"grid": "map_b", "graph": "ps_grid"}

#: Two halves of about equal compile time (``any`` costs about as much as the others).
HALVES = (
    ["any@grid", "qlearning@graph", "qlearning-solo@graph", "qlearning-team@grid"],
    ["any@graph", "qlearning@grid", "qlearning-solo@grid", "qlearning-team@graph"],
)


def config(name: str):
    """The config of loop ``LOOP@KIND``: a few steps of one small run."""
    from qpatrol.config import from_flat

    loop, kind = name.split("@")
    flat = {"map": MAPS[kind], "agents": 2, "runs": 1, "steps": 20, "engine": "numba"}
    flat.update({"battery.enabled": False, "record.warmup": 0, **LOOPS[loop]})
    return from_flat(flat)


def warm(names: list[str]) -> None:
    from qpatrol.run import simulate

    for name in names:
        simulate(config(name))


if __name__ == "__main__":
    warm(sys.argv[1:])
