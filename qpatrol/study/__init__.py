"""Experiments over many runs: sweeps, the paper's figures (data and plots), the report
and ``reproduce``."""
