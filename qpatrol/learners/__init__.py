"""Reference deep learners over :mod:`qpatrol.envs` (optional extra ``rl``: PyTorch).

* :mod:`qpatrol.learners.ppo`: PPO with one port-scoring policy shared by every robot,
  trained on :class:`qpatrol.envs.PatrolVectorEnv`; its weights are ``policy: neural``.

Nothing else in qpatrol imports this package.
"""
