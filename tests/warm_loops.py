"""Compile the compiled engine's loops into numba's cache before a parallel test run.

Each loop (:func:`qpatrol.engines.compiled_loop`: ``any``, ``qlearning``,
``qlearning-solo``, ``qlearning-team``) is compiled on first use in tens of seconds on
an empty cache: the lone and team learners' once per kind of map (a grid, a graph),
``any`` and ``qlearning`` once for both. When the workers of
a parallel run meet a loop at once, one compiles it and the others wait for it
(:mod:`qpatrol.engines.coldstart`), idle. ``tests/conftest.py`` runs this module in two
processes before the workers start, which share the loops out between them (each
claims the next one not yet claimed, the longest to compile first), so that both cores
compile and the workers then load every loop from the cache. Results do not depend on
it: a warm cache only saves time.

``python tests/warm_loops.py LOOP@KIND ...`` (KIND: ``grid`` or ``graph``) compiles
those loops; ``python tests/warm_loops.py --claim FOLDER`` the loops of :data:`ORDER`
that no other process has claimed in ``FOLDER``.
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

#: Every loop, the longest to compile first (on an empty cache, one process each:
#: ``any@grid`` about as long as all the others together, then the Q-learning loops,
#: ``vector@graph``). ``any`` and ``qlearning`` are one machine code for grids and
#: graphs (:class:`qpatrol.engines.numba_core.Loop`): their graph's version is the
#: grid's, loaded from the cache by the tests, and not listed (a second process would
#: compile it again beside the first). ``vector@graph`` is the batched env's kernel and
#: features (:mod:`qpatrol.engines.vector`, :mod:`qpatrol.strategies.features`; its
#: tests run on patrol graphs only).
ORDER = [
    "any@grid",
    "qlearning@grid",
    "qlearning-team@graph",
    "vector@graph",
    "qlearning-solo@grid",
    "qlearning-team@grid",
    "qlearning-solo@graph",
]
#: How many processes compile at once (one per core of the machine the suite is sized for).
PROCESSES = 2


def config(name: str):
    """The config of loop ``LOOP@KIND``: a few steps of one small run."""
    from qpatrol.config import from_flat

    loop, kind = name.split("@")
    flat = {"map": MAPS[kind], "agents": 2, "runs": 1, "steps": 20, "engine": "numba"}
    flat.update({"battery.enabled": False, "record.warmup": 0, **LOOPS[loop]})
    return from_flat(flat)


def warm(names: list[str]) -> None:
    from qpatrol.engines import coldstart
    from qpatrol.run import simulate

    # the processes of the warm-up never compile one loop twice (each claims its own);
    # the engine's lock between processes is one per loop name, not per kind of map, so
    # it would make a grid's compile of a loop wait for the graph's (``qlearning-team``'s
    # two, one after the other instead of side by side)
    coldstart._wait_for_others = lambda loop, poll=0.25: 0.0
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


def claim(folder: str, name: str) -> bool:
    """Whether this process is the first to claim loop ``name`` in ``folder``."""
    import os

    try:
        os.close(os.open(os.path.join(folder, name), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    return True


if __name__ == "__main__":
    if sys.argv[1:2] == ["--claim"]:
        for name in ORDER:
            if claim(sys.argv[2], name):
                warm([name])
    else:
        warm(sys.argv[1:])
