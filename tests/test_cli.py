"""Every CLI entry point at a tiny budget, bad input, and byte-identical reruns."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from qpatrol.cli import app
from qpatrol.maps import DIRECTIONS
from qpatrol.util.csvio import read_csv

runner = CliRunner()


def tiny_config(tmp_path: Path, **extra) -> Path:
    cfg = {
        "map": "map_b",
        "agents": 4,
        "runs": 2,
        "seed": 5,
        "steps": 400,
        "battery": {"capacity": 120, "charge_steps": 5},
        "record": {"transitions": True, "watch": [34]},
    }
    cfg.update(extra)
    p = tmp_path / "tiny.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def test_train_writes_every_file(tmp_path: Path):
    out = tmp_path / "run"
    res = invoke("train", tiny_config(tmp_path), "--out", out, "--set", "runs=3")
    assert res.exit_code == 0, res.output
    files = {p.name for p in out.iterdir()}
    assert files == {
        "config.yaml",
        "episodes.csv",
        "summary.json",
        "q_table.npz",
        "visits.npz",
        "transitions.csv",
        "watch.csv",
        "meta.json",
        "map.txt",
        "manifest.json",
    }
    with np.load(out / "q_table.npz") as z:
        assert z["q"].dtype == np.float64 and z["n"].dtype == np.int64
        assert z["q"].shape == z["n"].shape == (3, 4, 124, 4, 4)
    ep = pd.read_csv(out / "episodes.csv")
    assert list(ep.columns[:7]) == [
        "run",
        "episode",
        "start_step",
        "steps",
        "dots_eaten",
        "distinct_cells",
        "complete",
    ]
    tr = pd.read_csv(out / "transitions.csv")
    assert list(tr.columns) == [
        "run",
        "step",
        "agent",
        "cell",
        "heading",
        "action",
        "reward",
        "next_cell",
        "next_heading",
        "alpha",
        "q_before",
        "q_after",
    ]
    assert yaml.safe_load((out / "config.yaml").read_text())["runs"] == 3
    assert not list(tmp_path.glob(".*tmp"))


def test_every_transition_follows_the_update_rule_exactly(tmp_path: Path):
    """Replay transitions.csv from the initial table: each row is one exact Q-learning step."""
    out = tmp_path / "run"
    assert invoke("train", tiny_config(tmp_path), "--out", out).exit_code == 0
    cfg = yaml.safe_load((out / "config.yaml").read_text())
    lr = cfg["learning"]
    q_init = np.array([lr["q_init"][d] for d in DIRECTIONS]) * lr["multiplier"]
    from qpatrol.maps import get_map

    legal = get_map("map_b").neighbors >= 0
    tr = read_csv(out / "transitions.csv")  # exact on pandas 2 too
    q = np.broadcast_to(q_init, (2, 4, 124, 4, 4)).copy()
    n = np.zeros(q.shape, dtype=np.int64)
    with np.load(out / "q_table.npz") as z:
        q_final, n_final = z["q"], z["n"]
    for row in tr.itertuples(index=False):
        i = (row.run, row.agent, row.cell, row.heading, row.action)
        assert row.q_before == q[i]
        n[i] += 1
        assert row.alpha == 1.0 / n[i]
        nxt = q[row.run, row.agent, row.next_cell, row.next_heading]
        target = row.reward + lr["gamma"] * nxt[legal[row.next_cell]].max()
        expected = row.q_before + row.alpha * (target - row.q_before)
        assert row.q_after == expected
        q[i] = row.q_after
    assert np.array_equal(q, q_final) and np.array_equal(n, n_final)
    assert len(tr) > 1000


def test_same_config_and_seed_give_byte_identical_files(tmp_path: Path):
    cfg = tiny_config(tmp_path)
    for name in ("a", "b"):
        assert invoke("train", cfg, "--out", tmp_path / name).exit_code == 0
    for f in (tmp_path / "a").iterdir():
        if f.name == "meta.json":  # the one file with times in it: equal but for them
            a, b = (json.loads((tmp_path / d / f.name).read_text()) for d in ("a", "b"))
            for meta in (a, b):
                del meta["started"], meta["ended"], meta["command"]
            assert a == b
            continue
        assert f.read_bytes() == (tmp_path / "b" / f.name).read_bytes(), f.name
    assert invoke("train", cfg, "--out", tmp_path / "c", "--set", "seed=6").exit_code == 0
    assert (tmp_path / "c" / "q_table.npz").read_bytes() != (
        tmp_path / "a" / "q_table.npz"
    ).read_bytes()


@pytest.mark.parametrize(
    "make, words",
    [
        (lambda d: ["--set", f"map={_broken_map(d)}"], "broken.txt:2:4: unknown character"),
        (lambda d: ["--set", "learning.gama=0.1"], "unknown config key 'learning.gama'"),
        (lambda d: ["--set", "learning.gamma=1.5"], "learning.gamma: got 1.5 (out of range)"),
        (lambda d: ["--set", "agents=0"], "agents: got 0 (out of range)"),
        (
            lambda d: [
                "--set",
                "agents=60",
                "--set",
                "map=" + _small_map(d),
                "--set",
                "record.watch=[]",
            ],
            "agents: 60 robots on map",
        ),
        (lambda d: ["--set", "map=nowhere/x.txt"], "no such map file"),
        (
            lambda d: [
                *("--set", "agents=2", "--set", "record.watch=[]"),
                *("--set", "map=" + _line_map(d, "H......")),
            ],
            "agents: 2 robots with battery.enabled on map line, a one-wide line without a "
            "station 1 cell or more from both ends",
        ),
    ],
)
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path: Path, make, words):
    cfg = tiny_config(tmp_path)
    out = tmp_path / "out"
    res = invoke("train", cfg, "--out", out, *make(tmp_path))
    assert res.exit_code == 2
    assert words in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
    assert "Traceback" not in res.output
    assert not out.exists()


def test_missing_config_file_and_existing_output(tmp_path: Path):
    res = invoke("train", tmp_path / "nope.yaml")
    assert res.exit_code == 2 and "no such config file" in res.stderr
    cfg = tiny_config(tmp_path, steps=50)
    assert invoke("train", cfg, "--out", tmp_path / "o").exit_code == 0
    res = invoke("train", cfg, "--out", tmp_path / "o")
    assert res.exit_code == 2 and "already exists" in res.stderr
    assert invoke("train", cfg, "--out", tmp_path / "o", "--force").exit_code == 0


def test_subprocess_error_has_no_traceback(tmp_path: Path):
    import subprocess
    import sys

    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "qpatrol.cli",
            "train",
            str(tiny_config(tmp_path)),
            "--set",
            "agents=0",
        ],
        capture_output=True,
        text=True,
    )
    assert res.returncode == 2
    assert res.stderr.strip().startswith("qpatrol: error: ")
    assert len(res.stderr.strip().splitlines()) == 1


def test_maps_commands(tmp_path: Path):
    res = invoke("maps", "list")
    assert res.exit_code == 0 and "map_a" in res.output and "facility" in res.output
    res = invoke("maps", "show", "map_b")
    assert res.exit_code == 0 and " 34 " in res.output
    png = tmp_path / "b.png"
    assert invoke("maps", "show", "map_b", "--png", png).exit_code == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    res = invoke("maps", "check", _broken_map(tmp_path))
    assert res.exit_code == 2 and "broken.txt:2:4" in res.stderr
    assert invoke("maps", "check", _small_map(tmp_path)).exit_code == 0


def test_config_commands(tmp_path: Path):
    res = invoke("config", "keys")
    assert res.exit_code == 0 and "learning.gamma" in res.output
    res = invoke("config", "show", tiny_config(tmp_path), "--set", "learning.gamma=0.3")
    assert res.exit_code == 0 and "gamma: 0.3" in res.output


def _broken_map(d: Path) -> str:
    p = d / "broken.txt"
    p.write_text("#####\n#0.x#\n#####\n")
    return str(p)


def _line_map(d: Path, row: str) -> str:
    p = d / "line.txt"
    p.write_text(row + "\n")
    return str(p)


@pytest.mark.parametrize("row, agents", [("...H...", 2), ("H......", 1)])
def test_a_battery_team_on_a_line_with_room_to_reach_a_station_is_accepted(
    tmp_path: Path, row, agents
):
    """The line rule refuses only what it must: a station in the middle serves two robots,
    one at an end serves one."""
    cfg = tiny_config(tmp_path, steps=50, record={})
    res = invoke(
        "train", cfg, "--out", tmp_path / "o", "-q", "--set", f"agents={agents}",
        "--set", "map=" + _line_map(tmp_path, row),
    )  # fmt: skip
    assert res.exit_code == 0, res.output


def _small_map(d: Path) -> str:
    p = d / "small.txt"
    p.write_text("0....\n.#.#.\n..H..\n")
    return str(p)


def test_oversized_transition_log_is_refused(tmp_path: Path):
    res = invoke("train", tiny_config(tmp_path), "--set", "steps=10000000", "--out", tmp_path / "o")
    assert res.exit_code == 2 and "record.transitions: up to" in res.stderr
    assert not (tmp_path / "o").exists()


def _engine_of(tmp_path: Path, name: str, *sets: str) -> dict:
    cfg = tiny_config(tmp_path, battery={"enabled": False}, record={})
    args = [a for s in sets for a in ("--set", s)]
    res = invoke("train", cfg, "--out", tmp_path / name, "-q", *args)
    assert res.exit_code == 0, res.output
    return json.loads((tmp_path / name / "meta.json").read_text())["engine"]


def test_meta_json_names_the_engine_that_ran_and_why(tmp_path: Path, monkeypatch):
    """``meta.json``'s ``engine``: the engine asked for, the one that ran, its loop, and
    why they differ, on both engines and each fallback."""
    pytest.importorskip("numba")
    from qpatrol import engines

    big = "steps=4000"  # 32,000 agent-steps: auto takes numba
    assert _engine_of(tmp_path, "numba", "engine=numba") == {
        "asked": "numba",
        "ran": "numba",
        "loop": "qlearning-team",
        "note": "",
    }
    assert _engine_of(tmp_path, "auto", "engine=auto", big, "agents=1", "runs=8") == {
        "asked": "auto",
        "ran": "numba",
        "loop": "qlearning-solo",
        "note": "",
    }
    recorded = _engine_of(tmp_path, "rec", "engine=numba", "record.watch=[34]")
    assert recorded["loop"] == "qlearning"
    battery = _engine_of(tmp_path, "battery", "engine=numba", "battery.enabled=on")
    assert battery["loop"] == "any"
    assert _engine_of(tmp_path, "numpy", "engine=numpy") == {
        "asked": "numpy",
        "ran": "numpy",
        "loop": "general",
        "note": "",
    }
    general = _engine_of(tmp_path, "general", "engine=numpy", "policy=random")
    assert general["loop"] == "general"
    small = _engine_of(tmp_path, "small", "engine=auto", "steps=100")
    assert (small["asked"], small["ran"]) == ("auto", "numpy")
    assert small["note"].startswith("auto: a small batch")
    monkeypatch.setattr(engines, "EVAP_POWERS_MAX", 50)  # evap's table would not fit
    evap = _engine_of(tmp_path, "evap", "engine=numba", "policy=evap", "steps=200")
    assert (evap["asked"], evap["ran"], evap["loop"]) == ("numba", "numpy", "general")
    assert evap["note"].startswith("fallback from numba: evap with evaporation")
    monkeypatch.setattr(engines, "numba_installed", lambda: False)
    missing = _engine_of(tmp_path, "missing", "engine=auto", big)
    assert (missing["ran"], missing["note"]) == ("numpy", "numba not installed")
