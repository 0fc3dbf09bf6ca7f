"""PPO with one policy shared by every robot, on the batched patrol env (CleanRL style).

One file, readable top to bottom: the arguments, the network, the rollout on
:class:`qpatrol.envs.PatrolVectorEnv` (compiled world, ``B`` runs x ``K`` robots), the
advantages, the update, and the weights written for ``policy: neural``
(:mod:`qpatrol.strategies.neural`). Needs PyTorch: ``pip install 'qpatrol[rl]'``.

The problem, as the environment poses it:

* **Observation**: each robot's port features (:func:`qpatrol.strategies.features.ports`,
  ``[P, D]``: per port of its vertex the far target's idleness, the way's length, who
  else is bound there or nearer, ...).
* **Action**: a port of the vertex it stands on, among its action mask; a robot decides
  only at vertices (on a waypoint the world carries it along the edge, its action is
  ignored and the step is no decision: it is left out of the policy's loss).
* **Reward**: on reaching a target (a vertex), the target's idleness on the robot's map
  before the visit, in hundreds of team steps: the world's reward with only its
  idleness term, ``reward.incremental_value=1`` and ``reward.idle_horizon=1e6``,
  rescaled; 0 on waypoints. Visiting the stalest targets first is what lowers the
  average idleness.
* **Policy** (the actor): an MLP ``P -> H -> H -> 1`` scores every port from that
  port's features alone (the same weights for every port and every robot), and the
  robot takes a port by the softmax of the scores over its mask: any number of ports,
  any graph. **Critic**: the same per-port embedding, pooled (mean and max over the
  legal ports), then ``2H -> H -> 1``.
* **PPO**: generalized advantage estimation over team steps (``gamma`` per step),
  clipped ratio, value loss, entropy bonus, Adam; advantages normalised over the
  decisions of a batch.

Run (the shipped policy; ``--minutes`` bounds the wall time)::

    python -m qpatrol.learners.ppo --map ps_cumberland --agents 6 --seed 0 \\
        --minutes 12 --out qpatrol/strategies/weights/ps_cumberland_6_seed0.npz

It prints one line per finished batch of episodes and writes ``--curve`` (CSV:
team steps trained, agent-steps, seconds, the batch's mean average idleness) beside
the weights. ``--minutes`` makes the updates done depend on the machine's speed; the
same weights again (same torch, one thread): ``--updates U`` with the file's
``updates`` (for the shipped files, its ``steps`` / (``--runs`` x ``--rollout``)).
"""

from __future__ import annotations

import argparse
import csv
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

from qpatrol.envs import PatrolVectorEnv
from qpatrol.strategies import features
from qpatrol.strategies.neural import FORMAT


def parse(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--map", default="ps_cumberland")
    ap.add_argument("--agents", type=int, default=6)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="config overrides of the training env (default: the field study's "
                    "world: interference, battery off)")  # fmt: skip
    ap.add_argument("--runs", type=int, default=128, help="runs stepped together (B)")
    ap.add_argument("--episode", type=int, default=1000, help="team steps of a run")
    ap.add_argument("--rollout", type=int, default=64, help="team steps per update")
    ap.add_argument("--minutes", type=float, default=12.0, help="wall time bound")
    ap.add_argument("--updates", type=int, default=0, help="stop after this many (0: time)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--net", choices=("mlp", "graph"), default="mlp",
                    help="the actor: an MLP over each port's features, or a graph network "
                    "over the graph features as well")  # fmt: skip
    ap.add_argument("--hidden", type=int, default=64)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--gamma", type=float, default=0.98)
    ap.add_argument("--lam", type=float, default=0.95)
    ap.add_argument("--epochs", type=int, default=4)
    ap.add_argument("--minibatches", type=int, default=4)
    ap.add_argument("--clip", type=float, default=0.2)
    ap.add_argument("--ent", type=float, default=0.01)
    ap.add_argument("--vf", type=float, default=0.5)
    ap.add_argument("--reward-scale", type=float, default=0.01, help="reward per step of idleness")
    ap.add_argument("--threads", type=int, default=1, help="torch and env threads")
    ap.add_argument("--out", default="neural.npz")
    ap.add_argument("--curve", default="", help="CSV of the curve (default: beside --out)")
    ap.add_argument("--quiet", action="store_true")
    return ap.parse_args(argv)


class Agent(nn.Module):
    """The actor scores ports from their features; the critic pools them."""

    def __init__(self, n_feat: int, hidden: int):
        super().__init__()
        self.actor = nn.Sequential(
            nn.Linear(n_feat, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh(),
            nn.Linear(hidden, 1),
        )  # fmt: skip
        self.embed = nn.Sequential(nn.Linear(n_feat, hidden), nn.Tanh())
        self.value = nn.Sequential(nn.Linear(2 * hidden, hidden), nn.Tanh(), nn.Linear(hidden, 1))
        nn.init.orthogonal_(self.actor[-1].weight, 0.01)

    def forward(self, x: torch.Tensor, mask: torch.Tensor):
        """``x`` ``[N, P, D]``, ``mask`` bool ``[N, D]`` -> (logits ``[N, D]``, value ``[N]``)."""
        ports = x.transpose(1, 2)  # [N, D, P]
        logits = self.actor(ports)[..., 0]
        legal = ports[..., 0:1]  # feature 0: the port has a move
        e = self.embed(ports) * legal
        mean = e.sum(1) / legal.sum(1).clamp(min=1.0)
        top = (e - 1e9 * (1 - legal)).max(1).values.clamp(min=-1.0)
        value = self.value(torch.cat([mean, top], dim=-1))[..., 0]
        logits = torch.where(mask, logits, torch.full_like(logits, -1e9))
        return logits, value


class GraphAgent(nn.Module):
    """The actor scores each port from a graph network's embedding of the port's far
    target (two mean-aggregation layers over the graph features, GraphSAGE's) and the
    port's features; the critic pools the embeddings of every target."""

    def __init__(self, n_feat: int, n_node: int, hidden: int, adjacency: np.ndarray):
        super().__init__()
        self.register_buffer("adj", torch.as_tensor(adjacency, dtype=torch.float32))
        self.s0, self.n0 = nn.Linear(n_node, hidden), nn.Linear(n_node, hidden, bias=False)
        self.s1, self.n1 = nn.Linear(hidden, hidden), nn.Linear(hidden, hidden, bias=False)
        self.head = nn.Sequential(
            nn.Linear(hidden + n_feat, hidden), nn.Tanh(), nn.Linear(hidden, 1)
        )
        self.value = nn.Sequential(nn.Linear(2 * hidden, hidden), nn.Tanh(), nn.Linear(hidden, 1))
        nn.init.orthogonal_(self.head[-1].weight, 0.01)

    def forward(self, x, mask, nodes, port_nodes):
        """``x`` ``[N, P, D]``, ``mask`` ``[N, D]``, ``nodes`` ``[N, V, F]``,
        ``port_nodes`` ``[N, D]`` -> (logits ``[N, D]``, value ``[N]``)."""
        h = torch.relu(self.s0(nodes) + self.n0(self.adj @ nodes))
        h = torch.relu(self.s1(h) + self.n1(self.adj @ h))
        at = h.gather(1, port_nodes[..., None].expand(-1, -1, h.shape[-1]))
        logits = self.head(torch.cat([at, x.transpose(1, 2)], dim=-1))[..., 0]
        value = self.value(torch.cat([h.mean(1), h.max(1).values], dim=-1))[..., 0]
        logits = torch.where(mask, logits, torch.full_like(logits, -1e9))
        return logits, value


def save(
    agent: nn.Module, path: Path, args: argparse.Namespace, steps: int, updates: int = 0
) -> None:
    """The weights as ``policy: neural`` reads them (:mod:`qpatrol.strategies.neural`)."""
    arrays = {
        "format": np.array(FORMAT),
        "features": np.array(features.PORT),
        "map": np.array(args.map),
        "agents": np.array(str(args.agents)),
        "seed": np.array(str(args.seed)),
        "steps": np.array(str(steps)),
        "updates": np.array(str(updates)),
        "command": np.array("python -m qpatrol.learners.ppo " + shlex.join(sys.argv[1:])),
    }

    def np32(p: torch.Tensor) -> np.ndarray:
        return p.detach().numpy().astype(np.float32)

    if isinstance(agent, GraphAgent):
        arrays["kind"] = np.array("graph-sage")
        for i, (s, nb) in enumerate(((agent.s0, agent.n0), (agent.s1, agent.n1))):
            arrays[f"gnn_self{i}"], arrays[f"gnn_b{i}"] = np32(s.weight), np32(s.bias)
            arrays[f"gnn_nb{i}"] = np32(nb.weight)
        for i, layer in enumerate(m for m in agent.head if isinstance(m, nn.Linear)):
            arrays[f"head_w{i}"], arrays[f"head_b{i}"] = np32(layer.weight), np32(layer.bias)
    else:
        arrays["kind"] = np.array("ports-mlp")
        for i, layer in enumerate(m for m in agent.actor if isinstance(m, nn.Linear)):
            arrays[f"actor_w{i}"], arrays[f"actor_b{i}"] = np32(layer.weight), np32(layer.bias)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        np.savez_compressed(f, **arrays)


def train(args: argparse.Namespace) -> list[dict[str, float]]:
    """Train until ``--minutes`` (or ``--updates``) pass; write the weights and the
    curve. Returns the curve's rows."""
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    began = time.perf_counter()
    world = ["reward.dot_value=0", "reward.big_dot_value=0", "reward.lambda=0"]
    world += ["reward.incremental_value=1", "reward.idle_horizon=1000000"]
    warmup = min(200, args.episode // 5)  # the first steps' idleness is the start's
    field = ["team.interaction=interference", "battery.enabled=off", f"record.warmup={warmup}"]
    field += ["security.attack_steps=[]"]
    env = PatrolVectorEnv(
        None, [*field, *world, *args.set], map=args.map, agents=args.agents,
        num_envs=args.runs, max_steps=args.episode, engine="numba", threads=args.threads,
    )  # fmt: skip
    b, k = env.num_envs, env.n_agents
    n, p, d = b * k, len(features.PORT), env.batch.n_ports
    target = env.batch.params.target
    tab = env.tables
    f_n, v_n = len(features.NODE), tab.targets.size
    graph = args.net == "graph"
    if graph:
        agent = GraphAgent(p, f_n, args.hidden, tab.adjacency())
    else:
        agent = Agent(p, args.hidden)

    def graph_inputs() -> tuple:
        """The graph network's inputs of this step: node features, ports' far targets."""
        if not graph:
            return ()
        nodes = torch.from_numpy(env.graph()[0].reshape(n, v_n, f_n).copy())
        return nodes, torch.from_numpy(tab.port_nodes(env.batch.state.pos).reshape(n, d))

    opt = torch.optim.Adam(agent.parameters(), lr=args.lr, eps=1e-5)
    s_n = args.rollout
    obs_b = torch.zeros((s_n, n, p, d))
    mask_b = torch.zeros((s_n, n, d), dtype=torch.bool)
    act_b = torch.zeros((s_n, n), dtype=torch.long)
    logp_b = torch.zeros((s_n, n))
    rew_b = torch.zeros((s_n, n))
    done_b = torch.zeros((s_n, n))
    val_b = torch.zeros((s_n, n))
    dec_b = torch.zeros((s_n, n), dtype=torch.bool)
    nodes_b = torch.zeros((s_n, n, v_n, f_n) if graph else (s_n, n, 0))
    pn_b = torch.zeros((s_n, n, d) if graph else (s_n, n, 0), dtype=torch.long)
    obs, infos = env.reset(seed=args.seed)
    scale = args.reward_scale * 1_000_000  # the world pays idle / 1e6
    curve: list[dict[str, float]] = []
    team_steps = 0
    update = 0
    while True:
        update += 1
        for s in range(s_n):
            x = torch.from_numpy(obs.reshape(n, p, d).copy())
            m = torch.from_numpy(infos["action_mask"].reshape(n, d).astype(bool))
            decide = m.any(-1)
            g = graph_inputs()
            if graph:
                nodes_b[s], pn_b[s] = g
            with torch.no_grad():
                logits, v = agent(x, m | ~decide[:, None], *g)
                dist = torch.distributions.Categorical(logits=logits)
                a = dist.sample()
            obs_b[s], mask_b[s], act_b[s], val_b[s], dec_b[s] = (
                x,
                m | ~decide[:, None],
                a,
                v,
                decide,
            )
            logp_b[s] = dist.log_prob(a)
            obs, rew, term, trunc, infos = env.step(a.numpy().reshape(b, k))
            team_steps += 1
            arrived = infos["moved"] & target[env.batch.state.pos]
            if "final_metrics" in infos:  # the batch was reset: its last step's arrivals
                arrived = infos["moved"] & target[env.last_result.state.pos]
            rew_b[s] = torch.from_numpy((rew * arrived * scale).reshape(n).astype(np.float32))
            done_b[s] = torch.from_numpy((term | trunc).reshape(n).astype(np.float32))
            if "final_metrics" in infos:
                fm = infos["final_metrics"]
                row = {
                    "update": update,
                    "team_steps": team_steps * b,
                    "agent_steps": team_steps * n,
                    "seconds": round(time.perf_counter() - began, 2),
                    "avg_idleness": float(np.mean(fm["avg_idleness"])),
                    "worst_idleness": float(np.mean(fm["worst_idleness"])),
                }
                curve.append(row)
                if not args.quiet:
                    print(
                        f"update {update}  team steps {row['team_steps']:,}  "
                        f"{row['seconds']:.0f} s  average idleness {row['avg_idleness']:.2f}  "
                        f"worst {row['worst_idleness']:.1f}",
                        flush=True,
                    )
        # --- advantages (GAE over team steps; a done step cuts the trace) ---------------
        with torch.no_grad():
            x = torch.from_numpy(obs.reshape(n, p, d).copy())
            m = torch.from_numpy(infos["action_mask"].reshape(n, d).astype(bool))
            _, nxt = agent(x, m | ~m.any(-1, keepdim=True), *graph_inputs())
            adv = torch.zeros_like(rew_b)
            last = torch.zeros(n)
            for s in reversed(range(s_n)):
                v_next = nxt if s == s_n - 1 else val_b[s + 1]
                live = 1.0 - done_b[s]
                delta = rew_b[s] + args.gamma * v_next * live - val_b[s]
                last = delta + args.gamma * args.lam * live * last
                adv[s] = last
            ret = adv + val_b
        # --- the update: decisions train the actor, every step the critic ---------------
        flat = lambda t: t.reshape(s_n * n, *t.shape[2:])  # noqa: E731
        batch = (obs_b, mask_b, act_b, logp_b, adv, ret, dec_b, nodes_b, pn_b)
        fo, fm_, fa, flp, fadv, fret, fdec, fnodes, fpn = map(flat, batch)
        idx = np.arange(s_n * n)
        size = len(idx) // args.minibatches
        dec_adv = fadv[fdec]
        mu, sd = dec_adv.mean(), dec_adv.std() + 1e-8
        for _ in range(args.epochs):
            np.random.default_rng(update).shuffle(idx)
            for i in range(args.minibatches):
                mb = torch.from_numpy(idx[i * size : (i + 1) * size])
                g = (fnodes[mb], fpn[mb]) if graph else ()
                logits, v = agent(fo[mb], fm_[mb], *g)
                dist = torch.distributions.Categorical(logits=logits)
                ratio = (dist.log_prob(fa[mb]) - flp[mb]).exp()
                a_n = (fadv[mb] - mu) / sd
                dec = fdec[mb].float()
                pg = torch.max(-a_n * ratio, -a_n * ratio.clamp(1 - args.clip, 1 + args.clip))
                pg = (pg * dec).sum() / dec.sum().clamp(min=1.0)
                ent = (dist.entropy() * dec).sum() / dec.sum().clamp(min=1.0)
                vloss = 0.5 * ((v - fret[mb]) ** 2).mean()
                loss = pg - args.ent * ent + args.vf * vloss
                opt.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), 0.5)
                opt.step()
        elapsed = time.perf_counter() - began
        if (args.updates and update >= args.updates) or elapsed > 60 * args.minutes:
            break
    out = Path(args.out)
    save(agent, out, args, team_steps * b, update)
    path = Path(args.curve) if args.curve else out.with_suffix(".curve.csv")
    if curve:
        with open(path, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(curve[0]))
            w.writeheader()
            w.writerows(curve)
    return curve


def main(argv: list[str] | None = None) -> None:
    train(parse(argv))


if __name__ == "__main__":
    main()
