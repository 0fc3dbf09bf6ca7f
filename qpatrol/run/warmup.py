"""The background compile of :mod:`qpatrol.engines.coldstart`: a process that runs one run
of a config for a few steps on the compiled engine, so that numba's cache holds its loop
for the next run (``python -m qpatrol.run.warmup SPEC.json``)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from qpatrol.config import Config, from_flat
from qpatrol.engines import coldstart
from qpatrol.run import simulate


def warm(cfg: Config, loop: str) -> bool:
    """Compile ``loop`` into numba's cache, in this process, unless another process is
    compiling it: one run of ``cfg`` for a few steps on the compiled engine (which takes
    the loop's lock and records it, :class:`qpatrol.engines.coldstart.Compiling`).
    Returns whether it ran."""
    if coldstart._compiling_for(loop) > 0.0 or coldstart.cached(loop):
        return False
    simulate(cfg.replace(runs=1, steps=min(cfg["steps"], 8), engine="numba", threads=1))
    return True


def main(argv: list[str] | None = None) -> int:
    """``python -m qpatrol.run.warmup SPEC.json``: :func:`warm` the loop of the
    config in SPEC (written by :func:`qpatrol.engines.coldstart.warm_in_background`;
    removed here)."""
    argv = sys.argv[1:] if argv is None else argv
    spec_path = Path(argv[0])
    try:
        spec = json.loads(spec_path.read_text())
    finally:
        spec_path.unlink(missing_ok=True)
    try:
        os.nice(10)
    except OSError:
        pass
    warm(from_flat(spec["config"]), spec["loop"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
