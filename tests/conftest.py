"""Shared fixtures: tiny maps written to temporary files.

The suite runs in parallel (pytest-xdist, ``-n auto`` in pyproject.toml): every test
writes only under its own ``tmp_path``, and the workers share numba's on-disk cache,
whose writes :mod:`qpatrol.engines.cachelock` makes safe between processes.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from hypothesis import settings

from qpatrol.engines import cachelock

cachelock.install()  # before any compiled function is first called in this process

# hypothesis: the same examples on every run and machine (derandomize), no example
# database written into the checkout, no time limit per example (a loaded machine)
settings.register_profile("qpatrol", derandomize=True, database=None, deadline=None)
settings.load_profile("qpatrol")


def pytest_configure(config: pytest.Config) -> None:
    """Before the workers of a parallel run start (in the controller only): compile the
    compiled engine's loops into numba's cache in two processes at once, each taking the
    next loop the other has not taken, the longest first (``tests/warm_loops.py``), so
    that no worker sits idle waiting for another's compile. On a warm cache each
    process only loads them (a few seconds)."""
    parallel = getattr(config.option, "numprocesses", None)
    if hasattr(config, "workerinput") or not parallel or not importlib.util.find_spec("numba"):
        return
    import warm_loops

    script = Path(__file__).with_name("warm_loops.py")
    with tempfile.TemporaryDirectory(prefix="qpatrol-warm-") as claims:
        procs = [
            subprocess.Popen([sys.executable, str(script), "--claim", claims])
            for _ in range(warm_loops.PROCESSES)
        ]
        for proc in procs:
            proc.wait()


#: The longest tests and groups of tests (``xdist_group``), the longest first: a parallel
#: run hands tests out in collection order as the workers ask, so these go first and the
#: short ones fill in around them (no worker left alone with a long test at the end).
#: ``file::name`` prefixes of test ids; the others keep their order.
LONGEST_FIRST = (
    "test_modelcheck.py::test_no_task_starves_with_battery_and_goals",
    "test_modelcheck.py::test_no_task_starves_with_battery",
    "test_experiments.py::test_quick_reproduction_matches_the_committed_references",
    "test_figures.py::",
    "test_checkpoint.py::",
    "test_modelcheck.py::test_no_task_starves_with_goals_exchanged_head_on",
    "test_modelcheck.py::test_no_task_starves_with_three_robots_and_two_stations",
    "test_install.py::",
    "test_sweep.py::test_killed_sweep_resumes_to_identical_results",
    "test_modelcheck.py::test_no_task_starves_without_battery",
    "test_strategies.py::test_every_strategy_runs_on_every_shipped_map",
    "test_progress.py::test_without_the_age_insisting_robots_starve",
    "test_failures.py::test_every_strategy_survives_two_failures_on_every_map",
    "test_spacing.py::test_the_bound_fails_without_the_rules",
)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The tests of :data:`LONGEST_FIRST` first, in its order (a stable sort)."""

    def rank(item: pytest.Item) -> int:
        name = item.nodeid.rpartition("/")[2]
        return next(
            (i for i, prefix in enumerate(LONGEST_FIRST) if name.startswith(prefix)),
            len(LONGEST_FIRST),
        )

    items.sort(key=rank)


RING = """\
; name: ring
; description: a 3x3 ring of eight cells around one wall
0..
.#.
...
"""

ROOMS = """\
; name: rooms
#########
#0..#..1#
#.#...#.#
#...H...#
#.#.#.#.#
#2.o#o.3#
#########
"""


@pytest.fixture
def ring_map(tmp_path: Path) -> Path:
    p = tmp_path / "ring.txt"
    p.write_text(RING)
    return p


@pytest.fixture
def rooms_map(tmp_path: Path) -> Path:
    p = tmp_path / "rooms.txt"
    p.write_text(ROOMS)
    return p


@pytest.fixture
def loop_specs(monkeypatch) -> list[int]:
    """The compiled loop (``numba_core.SPEC_*``) each ``numba_core.Loop`` built during
    the test runs, in order."""
    pytest.importorskip("numba")
    from qpatrol.engines import numba_core

    specs: list[int] = []
    init = numba_core.Loop.__init__

    def spy(self, *args, **kwargs):
        init(self, *args, **kwargs)
        specs.append(self.spec)

    monkeypatch.setattr(numba_core.Loop, "__init__", spy)
    return specs


def stopped_and_resumed(cfg, folder: Path, at: int):
    """``simulate(cfg)`` stopped at step ``at`` by a checkpointer ticked after every
    step (on the compiled engine: one step per call), then resumed from its checkpoint
    in ``folder``: the resumed run's result."""
    from qpatrol.run import checkpoint as ck
    from qpatrol.run import simulate

    class StopAt(ck.Checkpointer):
        every_step = True

        def tick(self, position, payload):
            if position == at:
                self.request_stop()
            super().tick(position, payload)

    with pytest.raises(ck.Interrupted):
        simulate(cfg, checkpoint=StopAt(folder, every=0))
    resumed = ck.Checkpointer(folder, every=0)
    assert resumed.load().position == at
    return simulate(cfg, checkpoint=resumed)


@pytest.fixture
def stop_and_resume():
    """:func:`stopped_and_resumed`, for tests in any file."""
    return stopped_and_resumed


@pytest.fixture(autouse=True)
def compiled_loops_cached(monkeypatch):
    """Every compiled loop counts as in numba's cache (``engine: auto`` then takes the
    compiled engine as the tests expect, whether or not this machine compiled the loop
    before), and no background process compiles one; tests of the cold start
    (tests/test_engine_choice.py) undo this with their own patches."""
    from qpatrol.engines import coldstart

    monkeypatch.setattr(coldstart, "cached", lambda loop, disp=None, folder=None: True)
    monkeypatch.setattr(coldstart, "warm_in_background", lambda cfg, loop, folder=None: False)


def _writable(d: Path) -> bool:
    try:
        fd, tmp = tempfile.mkstemp(dir=d)
    except OSError:
        return False
    os.close(fd)
    os.unlink(tmp)
    return True


@pytest.fixture
def readonly(tmp_path: Path):
    """A folder nobody can write into: mode 0555, made immutable when we are root."""
    d = tmp_path / "ro"
    d.mkdir()
    d.chmod(0o555)
    immutable = False
    if _writable(d) and shutil.which("chattr"):
        immutable = subprocess.run(["chattr", "+i", str(d)], capture_output=True).returncode == 0
    try:
        if _writable(d):
            if Path("/sys").is_dir() and not _writable(Path("/sys")):
                yield Path("/sys")  # root without chattr: a real read-only place
                return
            pytest.skip("cannot make a read-only folder here")
        yield d
    finally:
        if immutable:
            subprocess.run(["chattr", "-i", str(d)], capture_output=True)
        d.chmod(0o755)


@dataclass
class CliResult:
    """What ``qpatrol ARGS...`` did: exit code, stdout, stderr."""

    code: int
    out: str
    err: str


@pytest.fixture
def cli_run(capsys) -> Any:
    """Run ``qpatrol ARGS...`` in this process, as the console script does."""
    from qpatrol import cli

    def call(*args: object) -> CliResult:
        capsys.readouterr()
        try:
            cli.main([str(a) for a in args])
            code = 0
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
        out, err = capsys.readouterr()
        return CliResult(code, out, err)

    return call
