"""qpatrol: learned multi-robot patrolling with tabular Q-learning on grid mazes.

Data flows one way: config -> map -> simulator + learners -> records -> CSV -> plots.
Start with :func:`qpatrol.config.load_config` and :func:`qpatrol.run.simulate`.
"""

__version__ = "0.1.0"
