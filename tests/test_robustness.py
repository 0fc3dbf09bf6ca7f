"""Every bad input of issue 7, through the real entry point (``qpatrol.cli.main``).

Each case asserts the exit code, a one-line message naming the problem, no traceback,
and that nothing was written (the folder the command was pointed at is unchanged).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import pytest
import yaml

from qpatrol.config import from_flat
from qpatrol.study.sweep import grid_points, points_for, run_sweep

#: on one worker under pytest-xdist: the module fixtures are built once
pytestmark = pytest.mark.xdist_group("robustness")

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture
def run(cli_run):
    """Run ``qpatrol ARGS...`` in this process, as the console script does."""
    return cli_run


def tree(root: Path) -> set[str]:
    """Every path under ``root`` (files and folders), relative."""
    return {str(p.relative_to(root)) for p in root.rglob("*")}


def assert_one_line_error(res: Any, code: int, words: str) -> None:
    assert res.code == code, (res.code, res.out, res.err)
    lines = res.err.strip().splitlines()
    assert len(lines) == 1, res.err
    assert lines[0].startswith("qpatrol: "), res.err
    assert words in lines[0], res.err
    assert "Traceback" not in res.out + res.err


def tiny(tmp_path: Path, name: str = "tiny.yaml", **extra) -> Path:
    cfg = {"map": "map_b", "agents": 2, "runs": 1, "seed": 3, "steps": 200, "battery": False}
    cfg.update(extra)
    p = tmp_path / name
    p.write_text(yaml.safe_dump(cfg))
    return p


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    """A finished multiplier sweep and a team-size-like grid sweep, tiny."""
    root = tmp_path_factory.mktemp("sweeps")
    base = from_flat(
        {"map": "map_b", "agents": 1, "runs": 1, "steps": 150, "battery.enabled": False}
    )
    mult = root / "mult"
    run_sweep(
        base.replace(**{"record.watch": [34]}), points_for("learning.multiplier", [1, 100]), mult
    )
    team = root / "team"
    run_sweep(base, grid_points({"agents": [1, 2], "team.communication": [True, False]}), team)
    return {"mult": mult, "team": team}


# --------------------------------------------------------------------- work lost or damaged


@pytest.mark.parametrize("command", ["train", "sweep", "reproduce", "maps-png", "plot"])
def test_read_only_output_is_refused_before_any_work(run, tmp_path, readonly, sweeps, command):
    cfg = tiny(tmp_path)
    before = tree(tmp_path)
    args = {
        "train": ["train", cfg, "--set", "steps=40000", "--out", readonly / "run"],
        "sweep": ["sweep", "learning.gamma", "--values", "0.1,0.2", cfg, "--out", readonly / "s"],
        "reproduce": ["reproduce", "--quick", "--out", readonly / "r"],
        "maps-png": ["maps", "show", "map_a", "--png", readonly / "m.png"],
        "plot": ["plot", "figure-2", "--from", sweeps["mult"], "--out", readonly / "f.png"],
    }[command]
    res = run(*args)
    assert_one_line_error(res, 2, "cannot write in")
    assert str(readonly) in res.err
    assert tree(tmp_path) == before
    if readonly != Path("/sys"):
        assert not any(readonly.iterdir())


def test_force_never_replaces_a_file(run, tmp_path):
    f = tmp_path / "notes.txt"
    f.write_text("mine\n")
    res = run("train", tiny(tmp_path), "--out", f, "--force")
    assert_one_line_error(res, 2, "is a file, not a folder")
    assert f.read_text() == "mine\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "tiny.yaml"]


def test_force_never_replaces_a_foreign_folder(run, tmp_path):
    d = tmp_path / "photos"
    d.mkdir()
    (d / "a.jpg").write_text("x")
    res = run("train", tiny(tmp_path), "--out", d, "--force")
    assert_one_line_error(res, 2, "has no manifest.json, so qpatrol did not write it")
    assert [p.name for p in d.iterdir()] == ["a.jpg"]
    res = run("sweep", "learning.gamma", "--values", "0.1", tiny(tmp_path), "--out", d, "--force")
    assert_one_line_error(res, 2, "has no manifest.json, so qpatrol did not write it")
    assert [p.name for p in d.iterdir()] == ["a.jpg"]


def test_force_replaces_a_run_folder(run, tmp_path):
    cfg = tiny(tmp_path, steps=30)
    assert run("train", cfg, "--out", tmp_path / "o", "-q").code == 0
    assert run("train", cfg, "--out", tmp_path / "o", "-q", "--force").code == 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize(
    "make, words",
    [
        (lambda d: ["maps", "show", "map_a", "--png", d / "x.bmpx"], "unknown image format .bmpx"),
        (lambda d: ["reproduce", "--quick", "--jobs", "0", "--out", d / "r"], "--jobs: got 0"),
        (lambda d: ["reproduce", "--quick", "--out", d / "tiny.yaml"], "is a file, not a folder"),
        (lambda d: ["train", d / "tiny.yaml", "--out", d / "tiny.yaml" / "run"], "is a file"),
        (
            lambda d: [
                "sweep",
                "learning.gamma",
                "--values",
                "0.1",
                d / "tiny.yaml",
                "--jobs",
                "-5",
            ],
            "--jobs: got -5",
        ),
        (
            lambda d: ["sweep", "learning.gamma", "--values", "0.1", d / "tiny.yaml", "-j", "1000"],
            "--jobs: got 1000",
        ),
    ],
)
def test_bad_paths_and_options(run, tmp_path, make, words):
    tiny(tmp_path)
    before = tree(tmp_path)
    res = run(*make(tmp_path))
    assert_one_line_error(res, 2, words)
    assert tree(tmp_path) == before


def test_huge_map_line_is_refused_for_a_table_strategy(run, tmp_path):
    m = tmp_path / "line.txt"
    m.write_text("0" + "." * 199_999 + "\n")
    cfg = tiny(tmp_path, map=str(m), agents=2)
    before = tree(tmp_path)
    res = run("train", cfg, "--out", tmp_path / "o", "--set", "policy=gravitational")
    assert_one_line_error(res, 2, "policy: gravitational keeps a cells x cells table")
    assert "200,000 cells" in res.err
    assert tree(tmp_path) == before


def test_too_many_runs_are_refused_by_memory(run, tmp_path):
    res = run("train", tiny(tmp_path), "--set", "map=facility", "--set", "runs=100000")
    assert_one_line_error(res, 2, "memory: runs=100000, steps=200, agents=2 on map facility")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny.yaml"]


def test_memory_check_in_sweeps(tmp_path):
    from qpatrol.config import ConfigError

    base = from_flat({"map": "facility", "agents": 4, "runs": 100000, "steps": 10})
    with pytest.raises(ConfigError, match="sweep point 000-seed=1: memory: runs=100000"):
        run_sweep(base, points_for("seed", [1]), tmp_path / "s")
    assert not (tmp_path / "s").exists()


# --------------------------------------------------------------------- silently wrong


@pytest.mark.parametrize(
    "sets, words",
    [
        (["map=map_a", "record.watch=[999]"], "record.watch: got [999]; allowed: states 0 to 184"),
        (["record.warmup=200"], "record.warmup: got 200; allowed: less than steps (200)"),
        (
            ["learning.q_init.north=1e300", "learning.multiplier=1e12"],
            "learning.q_init.north: 1e+300 x learning.multiplier 1000000000000.0",
        ),
    ],
)
def test_meaningless_values_are_refused(run, tmp_path, sets, words):
    cfg = tiny(tmp_path)
    args = [x for s in sets for x in ("--set", s)]
    res = run("train", cfg, *args, "--out", tmp_path / "o")
    assert_one_line_error(res, 2, words)
    assert not (tmp_path / "o").exists()


def test_non_finite_q_at_the_end_is_not_saved(run, tmp_path, monkeypatch):
    """Initial values are bounded (above); if Q still overflowed (extreme rewards), the run
    is not saved. The overflow is injected: reaching it honestly takes many episodes."""
    import numpy as np

    import qpatrol.run

    real = qpatrol.run.simulate

    def overflowing(*a, **k):
        result = real(*a, **k)
        result.strategy.q[0, 0, 5, 1, 2] = np.inf
        return result

    monkeypatch.setattr(qpatrol.run, "simulate", overflowing)
    res = run("train", tiny(tmp_path, steps=30), "--out", tmp_path / "o", "-q")
    assert_one_line_error(res, 2, "learning: 1 Q-values became inf or NaN during the run")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny.yaml"]


def test_set_errors_name_set_not_the_file(run, tmp_path):
    cfg = tiny(tmp_path)
    res = run("train", cfg, "--set", "learning.gamma=1.5")
    assert_one_line_error(res, 2, "--set: learning.gamma: got 1.5 (out of range)")
    assert "tiny.yaml" not in res.err


@pytest.mark.parametrize(
    "text, words",
    [
        ("", "empty config"),
        ("# only a comment\n", "empty config"),
        (
            "agents: 2\nsteps: 100\nagents: 3\n",
            "tiny.yaml:3:1: duplicate key 'agents' (first at line 1)",
        ),
        ("learning:\n  gamma: 0.2\n  gamma: 0.3\n", "tiny.yaml:3:3: duplicate key 'gamma'"),
    ],
)
def test_empty_and_duplicate_yaml(run, tmp_path, text, words):
    (tmp_path / "tiny.yaml").write_text(text)
    res = run("train", tmp_path / "tiny.yaml", "--out", tmp_path / "o")
    assert_one_line_error(res, 2, words)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny.yaml"]


def test_repeated_grid_key(run, tmp_path):
    cfg = tiny(tmp_path)
    res = run("sweep", "--grid", "agents=1,2", "--grid", "agents=4", cfg, "--out", tmp_path / "s")
    assert_one_line_error(res, 2, "--grid agents: given twice")
    assert not (tmp_path / "s").exists()


def test_plot_checks_what_the_folder_holds(run, tmp_path, sweeps):
    res = run("plot", "gamma", "--from", sweeps["mult"], "--out", tmp_path / "g.png")
    assert_one_line_error(
        res,
        2,
        "gamma needs a sweep over learning.gamma; "
        f"{sweeps['mult']} holds a sweep of 2 points over learning.multiplier (2 finished)",
    )
    res = run("plot", "figure-6", "--from", sweeps["team"], "--out", tmp_path / "f6.png")
    assert_one_line_error(res, 2, "figure-6 needs a run folder or a one-point sweep; ")
    assert "a sweep of 4 points over agents, team.communication" in res.err
    res = run("plot", "team-size", "--from", tmp_path, "--out", tmp_path / "t.png")
    assert_one_line_error(res, 2, "holds no qpatrol experiment")
    assert list(tmp_path.iterdir()) == []


def test_map_path_in_a_config_is_relative_to_the_config(run, tmp_path, monkeypatch):
    sub = tmp_path / "project"
    sub.mkdir()
    (sub / "floor.txt").write_text("0....\n.#.#.\n..o..\n")
    cfg = sub / "c.yaml"
    cfg.write_text("map: floor.txt\nagents: 1\nsteps: 20\nbattery: off\n")
    monkeypatch.chdir(tmp_path)
    res = run("train", "project/c.yaml", "--out", "out", "-q")
    assert res.code == 0, res.err
    saved = yaml.safe_load((tmp_path / "out" / "config.yaml").read_text())
    assert saved["map"] == str(sub / "floor.txt")
    assert (tmp_path / "out" / "map.txt").read_text() == "0....\n.#.#.\n..o..\n"


# --------------------------------------------------------------------- unlike its neighbours


COMMANDS = [
    [],
    ["train"],
    ["sweep"],
    ["plot"],
    ["reproduce"],
    ["maps"],
    ["maps", "list"],
    ["maps", "show"],
    ["maps", "check"],
    ["config"],
    ["config", "keys"],
    ["config", "list"],
    ["config", "show"],
]


@pytest.mark.parametrize("path", COMMANDS, ids=lambda p: " ".join(p) or "qpatrol")
def test_dash_h_everywhere_with_examples_and_plain_flags(run, path):
    res = run(*path, "-h")
    assert res.code == 0, res.err
    assert "Usage: qpatrol" in res.out
    assert "<bool>" not in res.out and "{" not in res.out
    if path and path[0] not in ("maps", "config") or len(path) == 2:
        assert "Examples:" in res.out


def test_version(run):
    from qpatrol import __version__

    for flag in ("--version", "-V"):
        res = run(flag)
        assert res.code == 0 and res.out.strip() == f"qpatrol {__version__}"


def test_usage_errors_are_one_line(run):
    res = run("train", "--no-such-flag")
    assert_one_line_error(res, 2, "No such option")
    assert "--no-such-flag" in res.err and "(see 'qpatrol train -h')" in res.err


def test_internal_error_one_line_and_a_log(run, tmp_path, monkeypatch):
    import qpatrol.run

    def boom(*a, **k):
        raise RuntimeError("something broke\nsecond line")

    monkeypatch.setattr(qpatrol.run, "simulate", boom)
    monkeypatch.setenv("QPATROL_LOG_DIR", str(tmp_path / "logs"))
    res = run("train", tiny(tmp_path), "--out", tmp_path / "o")
    assert_one_line_error(res, 1, "internal error: RuntimeError: something broke; full traceback")
    logs = list((tmp_path / "logs").iterdir())
    assert len(logs) == 1 and str(logs[0]) in res.err
    assert "Traceback" in logs[0].read_text() and "boom" in logs[0].read_text()
    assert not (tmp_path / "o").exists()


def test_ctrl_c_prints_a_message(run, tmp_path, monkeypatch):
    import qpatrol.study.sweep

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(qpatrol.study.sweep, "run_sweep", interrupted)
    res = run("sweep", "learning.gamma", "--values", "0.1", tiny(tmp_path), "-o", tmp_path / "s")
    assert_one_line_error(res, 130, "interrupted; finished points are kept in")
    monkeypatch.setattr(qpatrol.cli, "available_maps", interrupted)
    res = run("maps", "list")
    assert_one_line_error(res, 130, "qpatrol: interrupted")


def test_quiet_prints_only_where_it_wrote(run, tmp_path):
    res = run("train", tiny(tmp_path, steps=30), "--out", tmp_path / "o", "--quiet")
    assert res.code == 0 and res.out == f"wrote {tmp_path / 'o'}\n" and res.err == ""


def test_outputs_are_written_with_mode_0644(tmp_path, sweeps):
    from qpatrol.util import atomic

    old = os.umask(0o022)
    try:
        atomic.write_text(tmp_path / "x.csv", "a\n")
        assert (tmp_path / "x.csv").stat().st_mode & 0o777 == 0o644
    finally:
        os.umask(old)
    for name in ("results.csv", "sweep.json", "meta.json"):
        assert (sweeps["mult"] / name).stat().st_mode & 0o777 == 0o644, name


def test_meta_json_and_map_copy(run, tmp_path):
    res = run("train", tiny(tmp_path, steps=30), "--set", "seed=4", "--out", tmp_path / "o", "-q")
    assert res.code == 0
    meta = json.loads((tmp_path / "o" / "meta.json").read_text())
    assert meta["qpatrol"] and meta["host"]["cores"] >= 1
    assert meta["engine"]["ran"] == "numpy" and meta["engine"]["asked"] == "auto"
    assert meta["overrides"] == ["seed=4"]
    assert meta["command"].startswith("qpatrol train ") and "seed=4" in meta["command"]
    assert meta["started"] <= meta["ended"]
    assert meta["config_file"].endswith("tiny.yaml")
    if (REPO / ".git").exists():
        assert len(meta["git"]["commit"]) == 40 and isinstance(meta["git"]["dirty"], bool)
    shipped = (REPO / "maps" / "map_b.txt").read_text()
    assert (tmp_path / "o" / "map.txt").read_text() == shipped
    assert meta["map"]["name"] == "map_b" and meta["map"]["file"] == "map.txt"


@pytest.mark.parametrize("path", [[], ["maps"], ["config"]], ids=["qpatrol", "maps", "config"])
def test_no_arguments_print_the_help_and_no_error_line(run, path):
    res = run(*path)
    assert "Usage: qpatrol" in res.out + res.err
    assert "error" not in res.out + res.err and "Traceback" not in res.out + res.err
