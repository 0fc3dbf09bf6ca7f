"""Experiment configuration: one schema, validated on load.

Every key is a dotted name (``learning.gamma``) with a type, a default, an allowed
range and a help line. The same schema validates YAML files, ``--set KEY=VALUE``
overrides and sweep values, and is printed by ``qpatrol config keys``. A bad value
raises :class:`ConfigError` whose message is one line naming the key and what is
allowed.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import os
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from qpatrol.util.data import shipped_dir
from qpatrol.util.inputs import (
    MAX_YAML_BYTES,
    BoundedLoader,
    InputError,
    not_a_file,
    read_text_capped,
    short_repr,
)


class ConfigError(ValueError):
    """An invalid configuration; the message names the key and what is allowed."""


@dataclass(frozen=True)
class Field:
    """One config key: its type, default, allowed values and help text."""

    key: str
    kind: str  # "int", "float", "bool", "str", "choice", "cells", "durations"
    default: Any
    help: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False  # low bound excluded
    choices: tuple[str, ...] = ()
    nullable: bool = False
    #: the strategies (``policy``) that read this key; empty = every one of them
    used_by: tuple[str, ...] = ()

    def allowed(self) -> str:
        """Plain words for what values this key takes."""
        if self.kind == "choice":
            text = "one of " + ", ".join(self.choices)
        elif self.kind == "bool":
            text = "true or false (on/off)"
        elif self.kind == "cells":
            text = "a list of state numbers (ints >= 0)"
        elif self.kind == "durations":
            text = "auto, or a list of team steps (ints >= 1)"
        elif self.kind == "str":
            text = "a string"
        else:
            noun = "an integer" if self.kind == "int" else "a number"
            if self.low is not None and self.high is not None:
                lo = "(" if self.low_open else "["
                text = f"{noun} in {lo}{_num(self.low)}, {_num(self.high)}]"
            elif self.low is not None:
                text = f"{noun} {'>' if self.low_open else '>='} {_num(self.low)}"
            else:
                text = noun
        if self.nullable:
            text += " or null"
        return text


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else str(x)


F = Field
#: Every patrol strategy, by its ``policy`` name (one module each in qpatrol/strategies/);
#: the paper's learner first (the default).
POLICIES: tuple[str, ...] = (
    "qlearning",
    "random",
    "conscientious",
    "shared-conscientious",
    "cyclic",
    "partition",
    "evap",
    "qlearning-idleness",
    "hcr",
    "cc",
    "gbs",
    "sebs",
    "dta-greedy",
    "dta-ssi",
    "dta-ssi-part",
    "cbls",
    "learned-tour",
    "hpcc",
    "gravitational",
)
#: Learned policies read from a file of weights (``neural.weights``): valid ``policy``
#: values, kept apart from :data:`POLICIES` (every classic strategy, which the named
#: studies sweep) and measured against them by ``qpatrol sweep neural``.
LEARNED_POLICIES: tuple[str, ...] = ("neural",)
#: How robots meet (``team.interaction``): one per cell (the paper's avoiding), passing
#: each other with patrolling_sim's interference stops, or ignoring each other.
INTERACTIONS: tuple[str, ...] = ("exclusive", "interference", "none")
#: Keys read as another key (``alias -> (key, {alias value: key value})``): the old
#: ``team.avoid_collisions`` switch is ``team.interaction`` exclusive or none.
ALIASES: dict[str, tuple[str, dict[bool, str]]] = {
    "team.avoid_collisions": ("team.interaction", {True: "exclusive", False: "none"}),
}
QL = ("qlearning",)
QI = ("qlearning-idleness",)
SCHEMA: tuple[Field, ...] = (
    F("map", "str", "map_a", "map name in maps/ (see `qpatrol maps list`) or path to a map file"),
    F("agents", "int", 4, "robots in the team", low=1, high=1024),
    F(
        "policy",
        "choice",
        "qlearning",
        "patrol strategy: the paper's Q-learning, a classic baseline, or a trained "
        "neural policy (neural)",
        choices=POLICIES + LEARNED_POLICIES,
    ),
    F("runs", "int", 1, "independent runs, each with its own seed", low=1, high=100000),
    F("seed", "int", 0, "root seed; run r draws from SeedSequence(seed, spawn_key=(r,))", low=0),
    F(
        "steps",
        "int",
        5000,
        "team steps per run (an upper bound when `episodes` is set)",
        low=1,
        high=10**9,
    ),
    F(
        "episodes",
        "int",
        None,
        "stop a run after this many episodes have ended (null: run all `steps`)",
        low=1,
        nullable=True,
    ),
    F(
        "max_episode_steps",
        "int",
        10000,
        "an episode still running after this many team steps ends as truncated (null: never)",
        low=1,
        nullable=True,
    ),
    F(
        "learning.gamma",
        "float",
        0.1,
        "discount factor",
        low=0.0,
        high=1.0,
        low_open=False,
        used_by=QL,
    ),
    F(
        "learning.multiplier",
        "float",
        100.0,
        "scale of the initial Q-values",
        low=0.0,
        low_open=True,
        high=1e12,
        used_by=QL,
    ),
    F("learning.q_init.north", "float", 3.0, "initial Q of North (before multiplier)", used_by=QL),
    F("learning.q_init.east", "float", 2.0, "initial Q of East (before multiplier)", used_by=QL),
    F("learning.q_init.south", "float", 1.0, "initial Q of South (before multiplier)", used_by=QL),
    F("learning.q_init.west", "float", 2.0, "initial Q of West (before multiplier)", used_by=QL),
    F(
        "learning.epsilon",
        "float",
        0.0,
        "probability of a uniformly random legal move",
        low=0.0,
        high=1.0,
        used_by=QL,
    ),
    F(
        "learning.table",
        "choice",
        "auto",
        "Q-tables dense, or lazily with rows only for the cells a robot reads (same "
        "results); auto: lazily above 256 MiB of dense tables per run",
        choices=("auto", "dense", "lazy"),
        used_by=QL,
    ),
    F(
        "learning.state_space",
        "choice",
        "cell_heading",
        "Q-table state: (cell, heading) as in the paper, or cell alone (ablation)",
        choices=("cell_heading", "cell"),
        used_by=QL,
    ),
    F(
        "learning.initial_heading",
        "choice",
        "north",
        "heading an agent has before its first move (on a patrol graph, whose headings "
        "are ports, it is port 0 whatever this says)",
        choices=("north", "east", "south", "west"),
    ),
    F("reward.dot_value", "float", 1.0, "reward for eating a dot", low=0.0, used_by=QL),
    F(
        "reward.big_dot_value",
        "float",
        5.0,
        "reward for eating a big dot (`o`)",
        low=0.0,
        used_by=QL,
    ),
    F(
        "reward.incremental_value",
        "float",
        1.0,
        "maximum of incrementalDot, reached when a "
        "cell has been unvisited for `idle_horizon` steps",
        low=0.0,
        used_by=QL,
    ),
    F(
        "reward.idle_horizon",
        "float",
        100.0,
        "team steps of idleness at which incrementalDot saturates",
        low=0.0,
        low_open=True,
        used_by=QL,
    ),
    F(
        "reward.lambda",
        "float",
        1.0,
        "weight of lambda = dots eaten / state visits in the episode (0 turns it off)",
        low=0.0,
        used_by=QL,
    ),
    F(
        "team.communication",
        "bool",
        True,
        "share one dot map and one last-visit map (off: each agent has private ones)",
    ),
    F(
        "team.interaction",
        "choice",
        "exclusive",
        "how robots meet: `exclusive` (one robot per cell, never a swap: the paper's "
        "avoiding, with right of way and pushes), `interference` (robots pass each other; "
        "one that comes within `interference_radius` of a lower-numbered robot stops, as "
        "in patrolling_sim) or `none` (robots ignore each other, as in SimPatrol); "
        "`team.avoid_collisions: on/off` is read as exclusive/none",
        choices=INTERACTIONS,
    ),
    F(
        "team.interference_radius",
        "int",
        2,
        "interference: moves (shortest path) within which a robot meets a lower-numbered "
        "one (patrolling_sim's 2 m, at 1 m a move)",
        low=0,
        high=16,
    ),
    F(
        "team.interference_steps",
        "int",
        3,
        "interference: team steps a robot stops after it meets another "
        "(patrolling_sim's 3 s, at 1 m/s and 1 m a move)",
        low=1,
        high=10**6,
    ),
    F(
        "team.interference_cooldown",
        "int",
        10,
        "interference: team steps from one stop of a robot before it may meet again "
        "(patrolling_sim's 10 s); more than interference_steps",
        low=2,
        high=10**6,
    ),
    F("battery.enabled", "bool", True, "simulate battery, homing and charging"),
    F("battery.capacity", "int", 1000, "moves on a full charge", low=1),
    F("battery.margin", "int", 5, "spare moves kept when deciding to go home", low=0),
    F("battery.charge_steps", "int", 50, "team steps spent charging at `H`", low=0),
    F(
        "battery.initial_charge",
        "choice",
        "staggered",
        "charge at the start: `full` for every robot, or `staggered` (robot k of K starts "
        "with capacity - floor(k x capacity / K), so the team does not go home all at once)",
        choices=("full", "staggered"),
    ),
    F(
        "failures.robots",
        "int",
        0,
        "robots that fail at team step `failures.at`, chosen from each run's own stream, and "
        "leave the map for good (0: none)",
        low=0,
        high=63,
    ),
    F(
        "failures.at",
        "int",
        0,
        "the team step at whose end the `failures.robots` robots fail (required when they "
        "are more than 0; the measures then start there)",
        low=0,
    ),
    F(
        "evap.evaporation",
        "float",
        0.02,
        "share of the pheromone that evaporates every team step",
        low=0.0,
        low_open=True,
        high=1.0,
        used_by=("evap",),
    ),
    F(
        "gravity.propagation",
        "choice",
        "edge",
        "gravitational: where a target's pull acts: on the first port of a shortest path to "
        "it (edge), on each port by the far target's combined mass over the port's length "
        "(node) or not divided (node_no_distance), on every port by the port's length plus "
        "the far target's distance (mixed)",
        choices=("edge", "node", "node_no_distance", "mixed"),
        used_by=("gravitational",),
    ),
    F(
        "gravity.growth",
        "choice",
        "arithmetic",
        "gravitational: a target's mass from its idleness I: I (arithmetic), "
        "(1 + growth_rate)^(I - 1) (geometric) or 1 (none)",
        choices=("arithmetic", "geometric", "none"),
        used_by=("gravitational",),
    ),
    F(
        "gravity.growth_rate",
        "float",
        0.05,
        "gravitational: the geometric growth's rate per step of idleness (SimPatrol's 0.05)",
        low=0.0,
        low_open=True,
        high=10.0,
        used_by=("gravitational",),
    ),
    F(
        "gravity.exponent",
        "float",
        2.0,
        "gravitational: a target's pull is its mass over (moves to it)^exponent",
        low=0.0,
        high=10.0,
        used_by=("gravitational",),
    ),
    F(
        "gravity.combination",
        "choice",
        "sum",
        "gravitational: how the pulls on one port combine (sum or max)",
        choices=("sum", "max"),
        used_by=("gravitational",),
    ),
    F(
        "tour.neighbours",
        "int",
        8,
        "learned-tour: nearest targets a 2-opt or or-opt proposal may join a target to",
        low=1,
        high=64,
        used_by=("learned-tour",),
    ),
    F(
        "tour.kick_after",
        "int",
        2000,
        "learned-tour: proposals without a shorter order before a restart from the best "
        "order with a double bridge",
        low=1,
        used_by=("learned-tour",),
    ),
    F(
        "tour.learn_steps",
        "int",
        None,
        "learned-tour: team steps during which the learners propose changes; then the "
        "robots keep the best route found (null: they learn for the whole run)",
        low=0,
        nullable=True,
        used_by=("learned-tour",),
    ),
    F(
        "neural.weights",
        "str",
        None,
        "neural: the policy's weights, an .npz file written by `python -m "
        "qpatrol.learners.ppo` or the name of one shipped with qpatrol (null: the one "
        "trained on ps_cumberland with 6 robots, seed 0)",
        nullable=True,
        used_by=("neural",),
    ),
    F(
        "neural.greedy",
        "bool",
        False,
        "neural: take the policy's most probable port (ties by the run's stream) instead "
        "of drawing a port from its probabilities with the run's stream",
        used_by=("neural",),
    ),
    F(
        "bayes.g1",
        "float",
        0.1,
        "gbs/sebs: the posterior of a gain of 0 (patrolling_sim's G1)",
        low=0.0,
        low_open=True,
        high=1.0,
        used_by=("gbs", "sebs"),
    ),
    F(
        "bayes.g2",
        "float",
        100.0,
        "gbs/sebs: the gain (idleness / moves) from which the posterior is 1 (patrolling_sim's G2)",
        low=0.0,
        low_open=True,
        used_by=("gbs", "sebs"),
    ),
    F(
        "bayes.edge_min",
        "float",
        1.0,
        "gbs/sebs: the least edge length, in moves, a gain divides by (patrolling_sim's edge_min)",
        low=0.0,
        low_open=True,
        used_by=("gbs", "sebs"),
    ),
    F(
        "dta.theta_idleness",
        "float",
        1.0,
        "dta-*: the utility's weight of a target's idleness (patrolling_sim's theta_idleness)",
        low=-1000.0,
        high=1000.0,
        used_by=("dta-greedy", "dta-ssi", "dta-ssi-part"),
    ),
    F(
        "dta.greedy_navigation",
        "float",
        -0.5,
        "dta-greedy: the utility's weight of the moves to a target "
        "(patrolling_sim's theta_navigation)",
        low=-1000.0,
        high=1000.0,
        used_by=("dta-greedy",),
    ),
    F(
        "dta.greedy_origin",
        "float",
        -2.0,
        "dta-greedy: the utility's weight of a target's moves from the robot's start cell "
        "(patrolling_sim's theta_distance_from_origin)",
        low=-1000.0,
        high=1000.0,
        used_by=("dta-greedy",),
    ),
    F(
        "dta.ssi_navigation",
        "float",
        0.0,
        "dta-ssi, dta-ssi-part: the utility's weight of the moves to a target "
        "(patrolling_sim's theta_navigation)",
        low=-1000.0,
        high=1000.0,
        used_by=("dta-ssi", "dta-ssi-part"),
    ),
    F(
        "hpcc.idleness_weight",
        "float",
        1.0,
        "hpcc: the weight of a target's normalised idleness in its goal's utility and of its "
        "normalised staleness in the route's arc costs (patrolling_sim: 1)",
        low=0.0,
        high=1000.0,
        used_by=("hpcc",),
    ),
    F(
        "hpcc.distance_weight",
        "float",
        1.0,
        "hpcc: the weight of a target's normalised nearness in its goal's utility and of an "
        "arc's normalised length in the route's arc costs (patrolling_sim: 1)",
        low=0.0,
        high=1000.0,
        used_by=("hpcc",),
    ),
    F(
        "qidle.gamma",
        "float",
        0.9,
        "discount factor of qlearning-idleness (beyond the paper)",
        low=0.0,
        high=1.0,
        used_by=QI,
    ),
    F(
        "qidle.alpha",
        "float",
        0.1,
        "learning rate of qlearning-idleness; 0: 1/N(s,a), the paper's rule",
        low=0.0,
        high=1.0,
        used_by=QI,
    ),
    F(
        "qidle.epsilon",
        "float",
        0.0,
        "qlearning-idleness: probability of a random open move at step 0, decaying "
        "linearly to 0 at qidle.explore_steps",
        low=0.0,
        high=1.0,
        used_by=QI,
    ),
    F(
        "qidle.explore_steps",
        "int",
        5000,
        "qlearning-idleness: team steps over which exploration decays to 0 (0: none)",
        low=0,
        used_by=QI,
    ),
    F(
        "qidle.q_init",
        "float",
        0.0,
        "qlearning-idleness: initial Q-value of every (state, action)",
        low=-1e6,
        high=1e6,
        used_by=QI,
    ),
    F(
        "qidle.reward",
        "choice",
        "idleness",
        "qlearning-idleness reward: idleness of the cell entered / (cells / robots), or "
        "`dot`: the paper's reward (ablation)",
        choices=("idleness", "dot"),
        used_by=QI,
    ),
    F(
        "qidle.known_reward",
        "bool",
        True,
        "qlearning-idleness: add the reward each move would earn (read on the maps before "
        "choosing) to the learned Q, which then learns the value after the move",
        used_by=QI,
    ),
    F(
        "qidle.reward_cap",
        "float",
        3.0,
        "qlearning-idleness: largest idleness reward (in units of cells / robots)",
        low=0.0,
        low_open=True,
        high=1e6,
        used_by=QI,
    ),
    F(
        "qidle.state",
        "choice",
        "cell_heading_idle",
        "qlearning-idleness state: (cell, heading, direction of the most idle neighbour), "
        "or without the idleness feature (`cell_heading`) or the heading (`cell_idle`)",
        choices=("cell_heading_idle", "cell_heading", "cell_idle"),
        used_by=QI,
    ),
    F(
        "qidle.share",
        "bool",
        True,
        "qlearning-idleness: with communication on, the team learns into one shared Q-table",
        used_by=QI,
    ),
    F("record.transitions", "bool", False, "write transitions.csv, one row per Q-update"),
    F("record.watch", "cells", [], "states whose Q-updates are traced to watch.csv"),
    F(
        "record.trajectory",
        "int",
        0,
        "write trajectory.csv: every agent's cell in each run's last N team steps (0: off)",
        low=0,
        high=10**6,
    ),
    F("record.warmup", "int", 0, "team steps before the patrolling measures start", low=0),
    F(
        "record.timeline",
        "int",
        0,
        "write timeline.csv: average and worst idleness in windows of N team steps (0: off)",
        low=0,
    ),
    F(
        "security.attack_steps",
        "durations",
        [],
        "durations D (team steps) of the intruder measures capture_random and "
        "capture_observer; auto: T/8, T/4, T/2, T and 2T for a map of T targets, rounded "
        "up; [] (the default outside the security study) turns them off",
    ),
    F(
        "engine",
        "choice",
        "auto",
        "how runs are computed: numpy (the reference), numba (compiled), or "
        "auto (numba when installed, for batches of at least 20,000 runs x agents x steps); "
        "every engine gives the same files to the bit",
        choices=("auto", "numpy", "numba"),
    ),
    F(
        "threads",
        "int",
        0,
        "threads of the compiled engine for one batch, each advancing its share of the runs "
        "(0: this process's share of the cores: all of them, or one each for two --jobs on "
        "two cores); every number of threads gives the same files to the bit",
        low=0,
        high=1024,
    ),
    F(
        "memory.limit_gib",
        "float",
        2.0,
        "memory (GiB) a batch of runs may take: a sweep point's runs are computed in "
        "consecutive batches whose estimated size stays under it, with the files of one "
        "batch (`train`, with its checkpoints, keeps one batch)",
        low=0.0,
        low_open=True,
        high=1e6,
    ),
)
#: Keys that choose how a result is computed, never what it is: left out of
#: ``config.yaml`` and of :meth:`Config.digest` (the engine that ran is in ``meta.json``).
EXECUTION_KEYS: tuple[str, ...] = ("engine", "threads", "memory.limit_gib")
FIELDS: dict[str, Field] = {f.key: f for f in SCHEMA}
KEYS: tuple[str, ...] = tuple(FIELDS)


def defaults() -> dict[str, Any]:
    """Flat mapping of every key to its default."""
    return {f.key: copy.deepcopy(f.default) for f in SCHEMA}


#: Every group of keys: each dotted prefix of a key (``learning``, ``learning.q_init``).
GROUPS: frozenset[str] = frozenset(
    k.rsplit(".", n)[0] for k in FIELDS for n in range(1, k.count(".") + 1)
)


def _flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for k, v in tree.items():
        if not isinstance(k, str):
            raise ConfigError(f"{prefix}{short_repr(k)}: keys must be strings")
        key = f"{prefix}{k}"
        is_group = key in GROUPS and key not in ALIASES
        if key == "battery" and isinstance(v, bool):  # shorthand `battery: off`
            flat["battery.enabled"] = v
        elif is_group and key not in FIELDS:
            if not isinstance(v, Mapping):
                raise ConfigError(f"{key}: expected a mapping of sub-keys, got {short_repr(v)}")
            flat.update(_flatten(v, key + "."))
        else:
            flat[key] = v
    return flat


def _unflatten(flat: Mapping[str, Any]) -> dict[str, Any]:
    tree: dict[str, Any] = {}
    for key, v in flat.items():
        node = tree
        parts = key.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = v
    return tree


def _unknown(key: str) -> ConfigError:
    near = [k for k in KEYS if k.split(".")[-1] == key.split(".")[-1] or k.startswith(key)]
    hint = f"; did you mean {', '.join(near[:3])}?" if near else ""
    return ConfigError(f"unknown config key '{key}'{hint} (see `qpatrol config keys`)")


def check_value(key: str, value: Any) -> Any:
    """Validate and normalise one value; raise :class:`ConfigError` naming ``key``."""
    if key not in FIELDS:
        raise _unknown(key)
    return _check(FIELDS[key], key, value)


def _check(f: Field, key: str, value: Any) -> Any:
    """:func:`check_value` of ``value`` for field ``f`` (named ``key`` in errors)."""
    original = value

    def bad(why: str = "") -> ConfigError:
        got = f" ({why})" if why else ""
        return ConfigError(f"{key}: got {short_repr(original)}{got}; allowed: {f.allowed()}")

    if value is None:
        if f.nullable:
            return None
        raise bad()
    if f.kind == "bool":
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("on", "off", "true", "false", "yes", "no"):
            return value.lower() in ("on", "true", "yes")
        raise bad()
    if f.kind == "str":
        if isinstance(value, str) and value:
            return value
        raise bad()
    if f.kind == "choice":
        if isinstance(value, str) and value in f.choices:
            return value
        raise bad()
    if f.kind in ("cells", "durations"):  # a list of states (>= 0) or of steps (>= 1)
        if f.kind == "durations" and value == "auto":
            return value
        low = 0 if f.kind == "cells" else 1
        if isinstance(value, int) and not isinstance(value, bool):
            value = [value]
        if isinstance(value, list) and all(
            isinstance(v, int) and not isinstance(v, bool) and v >= low for v in value
        ):
            return sorted(set(value))
        raise bad()
    if isinstance(value, bool):
        raise bad()
    if f.kind == "int":
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if not isinstance(value, int):
            raise bad()
    else:
        if not isinstance(value, int | float):
            raise bad()
        value = float(value)
        if value != value or value in (float("inf"), float("-inf")):
            raise bad()
    if f.low is not None and (value < f.low or (f.low_open and value == f.low)):
        raise bad("out of range")
    if f.high is not None and value > f.high:
        raise bad("out of range")
    return value


def parse_assignment(text: str) -> tuple[str, Any]:
    """Split ``KEY=VALUE`` and read VALUE as YAML (``0.5``, ``on``, ``[3, 4]``)."""
    if "=" not in text:
        raise ConfigError(f"--set {short_repr(text)}: expected KEY=VALUE")
    key, raw = text.split("=", 1)
    key = key.strip()
    try:
        value = yaml.load(raw, Loader=BoundedLoader) if raw.strip() else None  # noqa: S506
    except yaml.YAMLError:
        value = raw
    if key in ALIASES:
        return key, value
    if key not in FIELDS:
        raise _unknown(key)
    kind = FIELDS[key].kind
    if kind == "str" and value is not None:
        value = raw.strip()
    elif kind in ("int", "float") and isinstance(value, str):
        try:  # YAML 1.1 reads 1e-3 (no dot) as text
            value = float(value)
        except ValueError:
            pass
    return key, value


@dataclass(frozen=True)
class Config:
    """A validated configuration: a flat mapping from every key to its value."""

    values: Mapping[str, Any]

    def __getitem__(self, key: str) -> Any:
        if key in ALIASES:  # an old switch, read off the key it stands for
            target, meaning = ALIASES[key]
            return self.values[target] == meaning[True]
        return self.values[key]

    def replace(self, **changes: Any) -> Config:
        """A copy with keys (dotted names given as ``**{"learning.gamma": 0.5}``) changed;
        an alias (:data:`ALIASES`) changes the key it stands for."""
        return from_flat({**self.values, **_translate(changes, given=changes)})

    def with_overrides(self, assignments: Iterable[str]) -> Config:
        """A copy with ``KEY=VALUE`` strings applied."""
        changes = dict(parse_assignment(a) for a in assignments)
        return self.replace(**changes)

    def tree(self) -> dict[str, Any]:
        """The nested mapping, as written to ``config.yaml``."""
        return _unflatten({k: v for k, v in self.values.items() if k not in EXECUTION_KEYS})

    def to_yaml(self) -> str:
        """The fully resolved config as YAML text (keys in schema order)."""
        return yaml.safe_dump(self.tree(), sort_keys=False, default_flow_style=None)

    def digest(self) -> str:
        """A short hash of the resolved values, used to name run folders."""
        values = {k: v for k, v in self.values.items() if k not in EXECUTION_KEYS}
        blob = json.dumps(values, sort_keys=True, default=str).encode()
        return hashlib.sha256(blob).hexdigest()[:10]


def _translate(flat: Mapping[str, Any], given: Mapping[str, Any]) -> dict[str, Any]:
    """``flat`` with each alias (:data:`ALIASES`) replaced by the key it stands for;
    :class:`ConfigError` when ``given`` (the keys the user gave together) sets both to
    different values."""
    out = dict(flat)
    for alias, (target, meaning) in ALIASES.items():
        if alias not in out:
            continue
        value = out.pop(alias)
        field = Field(alias, "bool", True, "")
        checked = _check(field, alias, value)
        mapped = meaning[checked]
        if target in given and given[target] != mapped:
            raise ConfigError(
                f"{alias}: {short_repr(value)} means {target} {mapped}, but {target} is "
                f"{short_repr(given[target])}; allowed: one of the two keys, or both agreeing"
            )
        out[target] = mapped
    return out


def from_flat(flat: Mapping[str, Any]) -> Config:
    """Validate a flat ``{key: value}`` mapping on top of the defaults (an alias of
    :data:`ALIASES` sets the key it stands for)."""
    values = defaults()
    flat = _translate(flat, given=flat)
    for key, v in flat.items():
        values[key] = check_value(key, v)
    check_together(values)
    return Config(values)


#: Largest magnitude of an initial Q-value (``q_init x multiplier``): far beyond any
#: useful scale, and far enough from float64's limit that updates stay finite.
MAX_INITIAL_Q = 1e100


def check_together(values: Mapping[str, Any]) -> None:
    """Rules that tie keys together; raise :class:`ConfigError` naming the key."""
    if values["record.warmup"] >= values["steps"]:
        raise ConfigError(
            f"record.warmup: got {values['record.warmup']}; allowed: less than steps "
            f"({values['steps']}), or no step would be measured"
        )
    fail = values["failures.robots"]
    if fail and fail >= values["agents"]:
        raise ConfigError(
            f"failures.robots: got {fail} with {values['agents']} agents; allowed: at most "
            f"{values['agents'] - 1} (at least one robot must remain)"
        )
    if fail and not 1 <= values["failures.at"] < values["steps"]:
        raise ConfigError(
            f"failures.at: got {values['failures.at']} with failures.robots {fail}; allowed: "
            f"a team step in 1..{values['steps'] - 1} (less than steps)"
        )
    if values["team.interference_cooldown"] <= values["team.interference_steps"]:
        raise ConfigError(
            f"team.interference_cooldown: got {values['team.interference_cooldown']} with "
            f"team.interference_steps {values['team.interference_steps']}; allowed: more "
            "than interference_steps (a robot moves between two stops)"
        )
    mult = values["learning.multiplier"]
    for d in ("north", "east", "south", "west"):
        q = values[f"learning.q_init.{d}"] * mult
        if not math.isfinite(q) or abs(q) > MAX_INITIAL_Q:
            raise ConfigError(
                f"learning.q_init.{d}: {values[f'learning.q_init.{d}']!r} x learning.multiplier "
                f"{mult!r} = {q!r}; allowed: an initial Q-value of at most {MAX_INITIAL_Q:g} "
                "in absolute value"
            )


def from_mapping(tree: Mapping[str, Any]) -> Config:
    """Validate a nested mapping (as read from YAML)."""
    if not isinstance(tree, Mapping):
        raise ConfigError(f"a config must be a mapping of keys, got {type(tree).__name__}")
    return from_flat(_flatten(tree))


class _DuplicateKey(Exception):
    def __init__(self, key: Any, mark: Any, first: Any):
        super().__init__(key)
        self.key, self.mark, self.first = key, mark, first


class _StrictLoader(BoundedLoader):
    """``yaml.SafeLoader`` that refuses a key given twice in one mapping, and YAML nested
    too deep or too large once its aliases are expanded
    (:class:`qpatrol.util.inputs.BoundedLoader`)."""


def _construct_mapping(loader: _StrictLoader, node: yaml.MappingNode, deep: bool = False) -> Any:
    seen: dict[Any, Any] = {}
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge":
            continue
        key = loader.construct_object(key_node, deep=True)
        try:
            if key in seen:
                raise _DuplicateKey(key, key_node.start_mark, seen[key])
            seen[key] = key_node.start_mark
        except TypeError:  # an unhashable key: the mapping constructor reports it
            pass
    return BoundedLoader.construct_mapping(loader, node, deep=deep)


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def _looks_like_path(value: str) -> bool:
    return "/" in value or os.sep in value or value.endswith(".txt")


def shipped_configs() -> dict[str, Path]:
    """Config name (file stem) -> path, for the configs shipped with qpatrol."""
    d = shipped_dir("configs")
    return {p.stem: p for p in sorted(d.glob("*.yaml"))} if d.is_dir() else {}


def find_config(path: str | Path) -> Path:
    """The config file for ``path``: the file itself if it exists, else a shipped config
    named like it (``paper``, ``paper.yaml`` or ``configs/paper.yaml``)."""
    p = Path(path)
    if p.is_file():
        return p
    kind = not_a_file(p)
    if kind is not None:
        raise ConfigError(f"{p}: is {kind}, not a config file")
    parts = p.parts
    if p.suffix in ("", ".yaml", ".yml") and (
        len(parts) == 1 or (len(parts) == 2 and parts[0] == "configs")
    ):
        shipped = shipped_configs()
        if p.stem in shipped:
            return shipped[p.stem]
    names = ", ".join(shipped_configs()) or "none found"
    raise ConfigError(f"{p}: no such config file (shipped configs: {names})")


#: Configs read in this process, by ``(folder, text)`` (:func:`load_config`): a figure
#: reads every point of a sweep, and several figures the same sweep, and PyYAML's pure-
#: Python parser takes some milliseconds a file.
_READ: dict[tuple[str, str], Config] = {}


def load_config(path: str | Path, overrides: Iterable[str] = ()) -> Config:
    """Read a YAML config, apply ``KEY=VALUE`` overrides, validate.

    ``path`` may also name a shipped config (``paper``, see :func:`find_config`). A
    relative map path in the file (``map: floors/a.txt``) is taken relative to the
    file's folder and stored absolute. Errors in the file name the file; errors in an
    override name ``--set``. The file is read every time; a text read before from the
    same folder is not parsed again (the config depends only on the two).
    """
    p = find_config(path)
    try:
        text = read_text_capped(p, MAX_YAML_BYTES, "a config file")
    except InputError as e:
        raise ConfigError(str(e)) from None
    except (OSError, UnicodeDecodeError) as e:
        why = getattr(e, "strerror", None) or str(e)
        raise ConfigError(f"{p}: cannot read config ({why})") from None
    key = (os.path.abspath(p.parent), text)
    cfg = _READ.get(key)
    if cfg is None:
        cfg = _parse_config(p, text)
        if len(_READ) >= 4096:
            _READ.clear()
        _READ[key] = cfg
    cfg = Config(copy.deepcopy(cfg.values))  # a copy: a caller may not change another's
    overrides = list(overrides)
    if not overrides:
        return cfg
    try:
        return cfg.with_overrides(overrides)
    except ConfigError as e:
        text = str(e)
        raise ConfigError(text if text.startswith("--set") else f"--set: {text}") from None


def _parse_config(p: Path, text: str) -> Config:
    """The validated config of the text of file ``p`` (:func:`load_config`)."""
    try:
        tree = yaml.load(text, Loader=_StrictLoader)  # noqa: S506 (a SafeLoader)
    except _DuplicateKey as e:
        raise ConfigError(
            f"{p}:{e.mark.line + 1}:{e.mark.column + 1}: duplicate key {short_repr(e.key)} "
            f"(first at line {e.first.line + 1}); allowed: each key once"
        ) from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f":{mark.line + 1}:{mark.column + 1}" if mark else ""
        problem = getattr(e, "problem", None) or "invalid YAML"
        raise ConfigError(f"{p}{where}: {problem}") from None
    if tree is None:
        raise ConfigError(
            f"{p}: empty config; allowed: a mapping of config keys (`qpatrol config keys`), "
            "or {} to run every default"
        )
    if isinstance(tree, Mapping) and isinstance(tree.get("map"), str):
        value = tree["map"]
        if _looks_like_path(value) and not Path(value).is_absolute():
            tree = {**tree, "map": os.path.normpath(os.path.abspath(p.parent / value))}
    try:
        return from_mapping(tree)
    except ConfigError as e:
        raise ConfigError(f"{p}: {e}") from None


def keys_table(fmt: Callable[[Field], str] | None = None) -> str:
    """One line per key: name, default, allowed values, help."""
    lines = []
    for f in SCHEMA:
        only = f" (read only by policy {', '.join(f.used_by)}; other strategies ignore it)"
        note = only if f.used_by else ""
        lines.append(f"{f.key:28s} {json.dumps(f.default):>14s}  {f.help}{note} [{f.allowed()}]")
    return "\n".join(lines)
