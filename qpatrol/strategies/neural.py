"""``neural``: a trained patrol policy, evaluated as a strategy (numpy, no torch needed).

The policy is the one :mod:`qpatrol.learners.ppo` trains on
:class:`qpatrol.envs.PatrolVectorEnv`: a small network shared by every robot that
scores each port of the robot's vertex from that port's features
(:func:`qpatrol.strategies.features.ports`, the same function the environment's
observations come from; a ``graph-sage`` policy also from a graph network's embedding
of the port's far target, over :func:`~qpatrol.strategies.features.nodes`) and takes a
port by the scores' softmax, over the moves a
strategy may choose (its open moves, :func:`base.prefer_open`). Drawing from the
probabilities uses the run's tie-break uniform ``u[..., 1]`` (the inverse of the
cumulative distribution, ports in order), so a run is reproducible and the same on
every batch; ``neural.greedy`` takes the most probable port instead (ties by the same
uniform).

Weights (``neural.weights``, an ``.npz``, or the name of one shipped in
:data:`WEIGHTS_DIR`; null: :data:`SHIPPED`): ``format`` =
``qpatrol-neural/1``, ``features`` (the port features' names, checked against
:data:`qpatrol.strategies.features.PORT`), and the actor's layers ``actor_w0``
``[H, P]``, ``actor_b0`` ``[H]``, ``actor_w1`` ``[H, H]``, ``actor_b1``, ``actor_w2``
``[1, H]``, ``actor_b2`` ``[1]`` (tanh between layers); anything else in the file
(the critic, the training's facts) is not read. The compiled engine does not run it:
``engine: numba`` or ``auto`` falls back to numpy and says so in ``meta.json``.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from qpatrol.config import ConfigError
from qpatrol.strategies import base, features

if TYPE_CHECKING:
    from qpatrol.config import Config
    from qpatrol.maps import Map
    from qpatrol.world import Observation, Params

FORMAT = "qpatrol-neural/1"
#: The policy shipped with qpatrol: trained by ``python -m qpatrol.learners.ppo`` on
#: ps_cumberland with 6 robots (the file's ``command`` entry says how).
WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
SHIPPED = WEIGHTS_DIR / "ps_cumberland_6_seed0.npz"
LAYERS = ("actor_w0", "actor_b0", "actor_w1", "actor_b1", "actor_w2", "actor_b2")


#: The layers of a ``graph-sage`` policy: two mean-aggregation layers over the graph
#: features (``gnn_self*``, ``gnn_nb*`` ``[H, F]`` then ``[H, H]``, ``gnn_b*``; ReLU),
#: then a head over each port's far target's embedding and the port's features
#: (``head_w0`` ``[H, H + P]``, ``head_b0``, tanh, ``head_w1`` ``[1, H]``, ``head_b1``).
GRAPH_LAYERS = (
    "gnn_self0", "gnn_nb0", "gnn_b0", "gnn_self1", "gnn_nb1", "gnn_b1",
    "head_w0", "head_b0", "head_w1", "head_b1",
)  # fmt: skip
KINDS = {"ports-mlp": LAYERS, "graph-sage": GRAPH_LAYERS}


class PortPolicy:
    """The actor of a weights file: ``logits(x, ...)`` float64 ``[..., D]`` from port
    features ``x`` ``[..., P, D]`` (and, for a ``graph-sage`` policy, the graph
    features ``nodes`` ``[..., N, F]``, the mean-aggregation matrix ``[N, N]`` and each
    port's far target ``[..., D]``)."""

    def __init__(self, path: str | Path):
        path = Path(path)
        if not path.is_file() and path.name == str(path) and (WEIGHTS_DIR / path).is_file():
            path = WEIGHTS_DIR / path  # a shipped policy, by its name
        if not path.is_file():
            raise ConfigError(
                f"neural.weights: {path} is not a file; allowed: an .npz written by "
                "`python -m qpatrol.learners.ppo`, or null for the shipped policy"
            )
        data = path.read_bytes()
        self.sha256 = hashlib.sha256(data).hexdigest()
        self.path = path
        with np.load(path, allow_pickle=False) as z:
            fmt = str(z["format"]) if "format" in z else ""
            names = tuple(str(x) for x in z["features"]) if "features" in z else ()
            self.kind = str(z["kind"]) if "kind" in z else "ports-mlp"
            layers = KINDS.get(self.kind, LAYERS)
            if fmt != FORMAT or names != features.PORT or any(k not in z for k in layers):
                raise ConfigError(
                    f"neural.weights: {path} is no {FORMAT} file of port features "
                    f"{', '.join(features.PORT)} with layers {', '.join(layers)}"
                )
            self.layers = [np.asarray(z[k], dtype=np.float64) for k in layers]
            self.facts = {k: str(z[k]) for k in ("map", "agents", "seed", "steps") if k in z}

    @property
    def graph(self) -> bool:
        """The policy reads the graph features too."""
        return self.kind == "graph-sage"

    def logits(self, x, nodes=None, adjacency=None, port_nodes=None) -> np.ndarray:
        ports = np.swapaxes(x, -1, -2).astype(np.float64)  # [..., D, P]
        if not self.graph:
            w0, b0, w1, b1, w2, b2 = self.layers
            h = np.tanh(ports @ w0.T + b0)
            h = np.tanh(h @ w1.T + b1)
            return (h @ w2.T + b2)[..., 0]
        s0, n0, b0, s1, n1, b1, hw0, hb0, hw1, hb1 = self.layers
        h = nodes.astype(np.float64)
        h = np.maximum(h @ s0.T + (adjacency @ h) @ n0.T + b0, 0.0)
        h = np.maximum(h @ s1.T + (adjacency @ h) @ n1.T + b1, 0.0)
        at = np.take_along_axis(h, port_nodes[..., None], axis=-2)  # [..., D, H]
        z = np.tanh(np.concatenate([at, ports], axis=-1) @ hw0.T + hb0)
        return (z @ hw1.T + hb1)[..., 0]


class Strategy(base.Strategy):
    """Each choosing robot takes a port by the trained policy's probabilities."""

    name = "neural"

    def __init__(self, cfg: Config, m: Map, p: Params, start_cells: np.ndarray):
        super().__init__(cfg, m, p, start_cells)
        self.policy = PortPolicy(cfg["neural.weights"] or SHIPPED)
        self.feature_tables = features.Tables(m, p)
        self.adjacency = self.feature_tables.adjacency() if self.policy.graph else None
        self.greedy = bool(cfg["neural.greedy"])

    def act(self, obs: Observation, u: np.ndarray) -> np.ndarray:
        tab = self.feature_tables
        x = features.ports(obs, tab)
        mask = base.prefer_open(obs) & obs.choosing[..., None]
        if self.policy.graph:
            nodes = features.nodes(obs, tab)
            logits = self.policy.logits(x, nodes, self.adjacency, tab.port_nodes(obs.state.pos))
        else:
            logits = self.policy.logits(x)
        if self.greedy:
            return base.choose_min(-logits, mask, u[..., 1])
        return sample(logits, mask, u[..., 1])

    def describe(self) -> dict[str, object]:
        return {
            "weights": self.policy.path.name,
            "network": self.policy.kind,
            "weights_sha256": self.policy.sha256,
            "greedy": self.greedy,
            **{f"trained_{k}": v for k, v in self.policy.facts.items()},
        }


def sample(logits: np.ndarray, mask: np.ndarray, u: np.ndarray) -> np.ndarray:
    """int ``[R, K]``: a port drawn from the softmax of ``logits`` ``[R, K, D]`` over
    ``mask`` by the uniform ``u`` ``[R, K]`` (the first port whose cumulative
    probability exceeds ``u``); -1 where the mask allows none."""
    z = np.where(mask, logits, -np.inf)
    top = z.max(axis=-1, keepdims=True)
    e = np.where(mask, np.exp(z - np.where(np.isfinite(top), top, 0.0)), 0.0)
    cdf = np.cumsum(e, axis=-1)
    total = cdf[..., -1:]
    # the first port past u x total: an allowed one, as only they add to the sum
    pick = (cdf > u[..., None] * total).argmax(axis=-1)
    return np.where(mask.any(axis=-1), pick, -1)
