"""Patrol strategies: each chooses the moves of the patrolling robots, and may learn.

A strategy is one module of this package, named after its ``policy`` with ``-`` written
``_`` (``shared-conscientious`` lives in ``shared_conscientious.py``), that defines a
class ``Strategy`` derived from :class:`qpatrol.strategies.base.Strategy`. The world
(:mod:`qpatrol.world`) does not know which one runs; adding a strategy takes one new
file and its name in :data:`qpatrol.config.POLICIES`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from qpatrol.config import LEARNED_POLICIES, POLICIES

if TYPE_CHECKING:
    from qpatrol.strategies.base import Strategy

#: Every classic strategy, by its ``policy`` name (the studies sweep them all).
NAMES: tuple[str, ...] = POLICIES
#: Policies learned outside qpatrol and read from a file (``neural``): allowed as a
#: ``policy`` too, and measured against :data:`NAMES` by ``qpatrol sweep neural``.
LEARNED: tuple[str, ...] = LEARNED_POLICIES


def strategy_class(name: str) -> type[Strategy]:
    """The ``Strategy`` class of policy ``name``."""
    if name not in NAMES + LEARNED:
        raise ValueError(f"unknown policy {name!r}; allowed: {', '.join(NAMES + LEARNED)}")
    module = importlib.import_module(f"qpatrol.strategies.{name.replace('-', '_')}")
    return module.Strategy


def learns(name: str) -> bool:
    """True when policy ``name`` learns as it patrols (and so needs a longer warm-up)."""
    return strategy_class(name).learns


def make(name: str, *args: Any, **kwargs: Any) -> Strategy:
    """A new strategy of policy ``name`` (arguments as :class:`base.Strategy`)."""
    return strategy_class(name)(*args, **kwargs)
