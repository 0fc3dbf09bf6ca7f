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

#: Two halves of about equal compile time (``any`` costs about as much as the others);
#: ``vector@graph`` is the batched env's kernel and features
#: (:mod:`qpatrol.engines.vector`, :mod:`qpatrol.strategies.features`; its tests run on
#: patrol graphs only).
HALVES = (
    ["any@grid", "qlearning@graph", "qlearning-solo@graph", "qlearning-team@grid"],
    ["any@graph", "qlearning@grid", "qlearning-solo@grid", "qlearning-team@graph", "vector@graph"],
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
        if name.startswith("vector@"):
            warm_vector(MAPS[name.split("@")[1]])
        else:
            simulate(config(name))


def warm_vector(map_name: str) -> None:
    """A few steps of the batched env on the compiled engine, and its features."""
    import importlib.util

    if importlib.util.find_spec("gymnasium") is None:
        return
    from qpatrol.envs import PatrolVectorEnv

    env = PatrolVectorEnv(None, [f"map={map_name}", "agents=2"], num_envs=2, max_steps=3)
    _, infos = env.reset(seed=0)
    env.step(infos["action_mask"].argmax(-1))
    env.graph()


if __name__ == "__main__":
    warm(sys.argv[1:])
