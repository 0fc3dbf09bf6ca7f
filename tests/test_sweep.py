"""Sweeps: ids and validation, determinism over jobs and backends, resume, kill, faults."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from qpatrol.config import ConfigError, from_mapping
from qpatrol.study.sweep import (
    NAMED_SWEEPS,
    Point,
    grid_points,
    load_results,
    parse_values,
    points_for,
    run_sweep,
)

TINY = """\
; name: tiny
#######
#0...1#
#.#.#.#
#.....#
#######
"""
GAMMAS = [0.1, 0.5, 0.9]


@pytest.fixture
def tiny_map(tmp_path: Path) -> Path:
    p = tmp_path / "tiny.txt"
    p.write_text(TINY)
    return p


def base_tree(tiny_map: Path, **extra) -> dict:
    tree = {"map": str(tiny_map), "agents": 2, "runs": 2, "seed": 7, "steps": 300, "battery": False}
    tree.update(extra)
    return tree


@pytest.fixture
def base(tiny_map: Path):
    return from_mapping(base_tree(tiny_map))


def tree_snapshot(root: Path) -> dict[str, tuple[int, bytes | None]]:
    """Every path under root with its mtime and (for files) its bytes."""
    snap = {}
    for p in sorted(root.rglob("*")):
        snap[str(p.relative_to(root))] = (
            p.stat().st_mtime_ns,
            p.read_bytes() if p.is_file() else None,
        )
    return snap


def tmp_leftovers(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.name.endswith(".tmp")]


# --------------------------------------------------------------------- 7. ids, validation


def test_points_for_ids_and_values():
    pts = points_for("learning.gamma", [0.1, 0.2, 0.3, 0.4])
    assert [p.index for p in pts] == [0, 1, 2, 3]
    assert pts[3].id == "003-learning.gamma=0.4"
    assert pts[3].overrides == {"learning.gamma": 0.4}
    # values are normalised by the schema: an int multiplier is a float, ids stay short
    m = points_for("learning.multiplier", [1, 1000])
    assert m[1].overrides == {"learning.multiplier": 1000.0}
    assert m[1].id == "001-learning.multiplier=1000"
    # a path is made filesystem-safe
    assert points_for("map", ["maps/a b.txt"])[0].id == "000-map=maps_a_b.txt"
    assert len(set(pts)) == 4  # hashable


def test_grid_points_first_key_slowest():
    pts = grid_points({"agents": [1, 2, 4], "team.communication": ["on", False]})
    assert [p.id for p in pts[:3]] == [
        "000-agents=1,team.communication=true",
        "001-agents=1,team.communication=false",
        "002-agents=2,team.communication=true",
    ]
    assert pts[5].id == "005-agents=4,team.communication=false"
    assert pts[5].overrides == {"agents": 4, "team.communication": False}
    assert Point(1234, {"seed": 3}).id == "1234-seed=3"


@pytest.mark.parametrize(
    "grid, key",
    [
        ({"learning.gamma": [0.1, 1.5]}, "learning.gamma"),
        ({"agents": [2], "team.communication": ["maybe"]}, "team.communication"),
        ({"learning.gama": [0.1]}, "learning.gama"),
        ({"learning.gamma": []}, "learning.gamma"),
    ],
)
def test_bad_values_raise_naming_the_key(grid, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")) as e:
        grid_points(grid)
    assert "\n" not in str(e.value)


def test_parse_values():
    assert parse_values("learning.gamma", "0.1, 0.5,0.9") == [0.1, 0.5, 0.9]
    assert parse_values("learning.epsilon", "1e-3,0") == [0.001, 0.0]
    assert parse_values("team.communication", "on,off") == [True, False]
    assert parse_values("agents", "1,2,4") == [1, 2, 4]
    assert parse_values("map", "map_a,maps/x.txt") == ["map_a", "maps/x.txt"]
    with pytest.raises(ConfigError, match="learning.gamma"):
        parse_values("learning.gamma", "0.1,1.5")
    with pytest.raises(ConfigError, match="agents"):
        parse_values("agents", "1,,2")


def test_named_sweeps():
    g = NAMED_SWEEPS["gamma"]
    assert g.config == "configs/gamma.yaml" and g.param == "learning.gamma"
    assert g.values == [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9]
    assert NAMED_SWEEPS["multiplier"].values == [1, 10, 100, 1000]
    ts = NAMED_SWEEPS["team-size"]
    assert ts.config == "configs/team_size.yaml"
    assert len(ts.points()) == 8 and ts.points()[0].overrides == {
        "agents": 1,
        "team.communication": True,
    }


# --------------------------------------------------------------------- 1. jobs=1 == jobs=2


def test_results_identical_for_jobs_1_and_2(base, tmp_path):
    pts = points_for("learning.gamma", GAMMAS)
    calls = []
    r1 = run_sweep(base, pts, tmp_path / "j1", jobs=1, progress=lambda d, t: calls.append((d, t)))
    r2 = run_sweep(base, pts, tmp_path / "j2", jobs=2)
    assert r1.done == r2.done == [p.id for p in pts] and not r1.failed and not r1.skipped
    a = (tmp_path / "j1" / "results.csv").read_bytes()
    assert a == (tmp_path / "j2" / "results.csv").read_bytes()
    assert calls[0] == (0, 6) and calls[-1] == (6, 6)
    assert [d for d, _ in calls] == sorted(d for d, _ in calls)

    df = load_results(tmp_path / "j1")
    assert list(df.columns[:4]) == ["point", "point_id", "learning.gamma", "run"]
    assert list(df.columns[4:7]) == ["steps", "episodes_completed", "episodes_truncated"]
    assert df[["point", "run"]].values.tolist() == [[0, 0], [0, 1], [1, 0], [1, 1], [2, 0], [2, 1]]
    assert df["learning.gamma"].tolist() == [0.1, 0.1, 0.5, 0.5, 0.9, 0.9]
    assert (df["steps"] == 300).all()
    spec = json.loads((tmp_path / "j1" / "sweep.json").read_text())
    assert spec["base"]["learning"]["gamma"] == 0.1
    assert [p["id"] for p in spec["points"]] == [p.id for p in pts]
    # a point's runs are the same as a plain `simulate(cfg, point=p)`
    from qpatrol.run import simulate

    res = simulate(base.replace(**pts[1].overrides), point=1)
    stored = json.loads((tmp_path / "j1" / "points" / pts[1].id / "summary.json").read_text())
    assert json.loads(json.dumps(res.summary)) == stored["runs"]


# --------------------------------------------------------------------- 2. resume


def test_resume_recomputes_only_missing_point(base, tmp_path):
    import shutil

    pts = points_for("learning.gamma", GAMMAS)
    out = tmp_path / "s"
    run_sweep(base, pts, out, jobs=1)
    first = (out / "results.csv").read_bytes()
    shutil.rmtree(out / "points" / pts[1].id)
    stray = out / "points" / f".{pts[1].id}.abc123.tmp"
    stray.mkdir()
    (stray / "config.yaml").write_text("half")
    (out / ".results.csv.xyz.tmp").write_text("half")
    calls = []
    r = run_sweep(base, pts, out, jobs=2, progress=lambda d, t: calls.append((d, t)))
    assert r.done == [pts[1].id]
    assert r.skipped == [pts[0].id, pts[2].id]
    assert (out / "results.csv").read_bytes() == first
    assert calls[0] == (4, 6) and calls[-1] == (6, 6)
    assert not tmp_leftovers(out)
    # nothing to do: everything skipped, same bytes
    r = run_sweep(base, pts, out)
    assert r.done == [] and len(r.skipped) == 3
    assert (out / "results.csv").read_bytes() == first


# --------------------------------------------------------------------- 3. kill and resume


KILL_SCRIPT = """
import sys
from qpatrol.config import load_config
from qpatrol.study.sweep import points_for, run_sweep
base = load_config(sys.argv[1])
run_sweep(base, points_for("learning.gamma", [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8]),
          sys.argv[2], jobs=2)
"""


def test_killed_sweep_resumes_to_identical_results(tiny_map, tmp_path):
    tree = base_tree(tiny_map, steps=4000)
    cfg_path = tmp_path / "kill.yaml"
    cfg_path.write_text(yaml.safe_dump(tree))
    base = from_mapping(tree)
    pts = points_for("learning.gamma", [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8])
    out = tmp_path / "killed"
    proc = subprocess.Popen(
        [sys.executable, "-c", KILL_SCRIPT, str(cfg_path), str(out)],
        start_new_session=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    deadline = time.monotonic() + 60
    try:
        while time.monotonic() < deadline:
            pdir = out / "points"
            if pdir.is_dir() and any(
                p.is_dir() and not p.name.startswith(".") for p in pdir.iterdir()
            ):
                break
            assert proc.poll() is None, proc.communicate()[1].decode()
            time.sleep(0.01)
        else:
            pytest.fail("no point finished within 60 s")
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
    assert not (out / "results.csv").exists()
    finished = [p for p in (out / "points").iterdir() if not p.name.startswith(".")]
    assert 1 <= len(finished) < len(pts)  # killed mid-way: the test is not vacuous

    r = run_sweep(base, pts, out, jobs=2)
    assert set(r.skipped) == {p.name for p in finished}
    assert len(r.done) + len(r.skipped) == len(pts) and not r.failed
    assert not tmp_leftovers(out)

    ref = run_sweep(base, pts, tmp_path / "ref", jobs=2)
    assert len(ref.done) == len(pts)
    assert (out / "results.csv").read_bytes() == (tmp_path / "ref" / "results.csv").read_bytes()


# --------------------------------------------------------------------- 4. failures


def test_point_with_missing_map_fails_alone(base, tiny_map, tmp_path):
    missing = str(tmp_path / "nope.txt")
    pts = points_for("map", [str(tiny_map), missing, str(tiny_map)])
    out = tmp_path / "f"
    r = run_sweep(base, pts, out, jobs=2)
    assert r.failed == [pts[1].id] and r.done == [pts[0].id, pts[2].id] and not r.ok
    assert "MapError" in r.errors[pts[1].id]
    info = json.loads((out / "points" / f"{pts[1].id}.failed.json").read_text())
    assert info["error"] == "MapError" and "nope.txt" in info["message"]
    assert "Traceback" in info["traceback"]
    assert not (out / "points" / pts[1].id).exists()
    df = load_results(out)
    assert df["point"].tolist() == [0, 0, 2, 2]


def test_failed_point_is_retried_and_record_removed(base, tmp_path, monkeypatch):
    import qpatrol.run

    real = qpatrol.run.simulate

    def flaky(cfg, *args, **kwargs):
        if cfg["learning.gamma"] == 0.5:
            raise RuntimeError("boom at gamma 0.5")
        return real(cfg, *args, **kwargs)

    pts = points_for("learning.gamma", GAMMAS)
    out = tmp_path / "retry"
    monkeypatch.setattr(qpatrol.run, "simulate", flaky)
    # one point per batch (a failing shared batch: test_batch_points.py)
    r = run_sweep(base, pts, out, jobs=1, batch_points=False)
    assert r.failed == [pts[1].id] and r.done == [pts[0].id, pts[2].id]
    failed = out / "points" / f"{pts[1].id}.failed.json"
    info = json.loads(failed.read_text())
    assert info["error"] == "RuntimeError" and info["message"] == "boom at gamma 0.5"
    assert "flaky" in info["traceback"]
    assert load_results(out)["point"].tolist() == [0, 0, 2, 2]

    monkeypatch.setattr(qpatrol.run, "simulate", real)
    r = run_sweep(base, pts, out, jobs=1)
    assert r.done == [pts[1].id] and r.skipped == [pts[0].id, pts[2].id] and r.ok
    assert not failed.exists()
    run_sweep(base, pts, tmp_path / "clean", jobs=1)
    assert (out / "results.csv").read_bytes() == (tmp_path / "clean" / "results.csv").read_bytes()


# --------------------------------------------------------------------- 5. a different sweep


def test_different_sweep_on_same_folder_is_refused(base, tmp_path):
    out = tmp_path / "s"
    pts = points_for("learning.gamma", GAMMAS)
    run_sweep(base, pts, out)
    before = tree_snapshot(out)
    with pytest.raises(ConfigError, match="different sweep") as e:
        run_sweep(base, points_for("learning.gamma", [0.1, 0.5, 0.7]), out)
    assert "\n" not in str(e.value) and "force" in str(e.value)
    with pytest.raises(ConfigError, match="steps"):
        run_sweep(base.replace(steps=200), pts, out)
    with pytest.raises(ConfigError, match="points"):
        run_sweep(base, pts[:2], out)
    assert tree_snapshot(out) == before

    new = points_for("learning.gamma", [0.2, 0.3])
    r = run_sweep(base, new, out, force=True)
    assert r.done == [p.id for p in new] and not r.skipped
    assert sorted(p.name for p in (out / "points").iterdir()) == [p.id for p in new]
    assert load_results(out)["learning.gamma"].tolist() == [0.2, 0.2, 0.3, 0.3]


def test_second_sweep_on_a_busy_folder_is_refused(base, tmp_path):
    fcntl = pytest.importorskip("fcntl")
    pts = points_for("learning.gamma", GAMMAS[:1])
    out = tmp_path / "busy"
    run_sweep(base, pts, out)
    with open(out / ".sweep.lock", "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        with pytest.raises(ConfigError, match="another sweep"):
            run_sweep(base, pts, out)


def test_bad_options_and_overrides(base, tmp_path):
    out = tmp_path / "x"
    pts = points_for("learning.gamma", GAMMAS)
    with pytest.raises(ConfigError, match="backend"):
        run_sweep(base, pts, out, backend="spark")
    with pytest.raises(ConfigError, match="jobs"):
        run_sweep(base, pts, out, jobs=0)
    with pytest.raises(ConfigError, match="learning.gamma"):
        run_sweep(base, [Point(0, {"learning.gamma": 2.0})], out)
    with pytest.raises(ConfigError, match="twice"):
        run_sweep(base, [Point(0, {"seed": 1}), Point(0, {"seed": 2})], out)
    assert not out.exists()


# --------------------------------------------------------------------- 6. dask


def test_dask_local_cluster_matches_joblib(base, tmp_path):
    distributed = pytest.importorskip("distributed")
    pts = points_for("learning.gamma", GAMMAS)
    run_sweep(base, pts, tmp_path / "joblib", jobs=2)
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        r = run_sweep(
            base, pts, tmp_path / "dask", backend="dask", scheduler=cluster.scheduler_address
        )
    assert r.done == [p.id for p in pts]
    expected = (tmp_path / "joblib" / "results.csv").read_bytes()
    assert (tmp_path / "dask" / "results.csv").read_bytes() == expected


def test_dask_own_local_cluster(base, tmp_path):
    pytest.importorskip("distributed")
    pts = points_for("learning.gamma", GAMMAS[:2])
    run_sweep(base, pts, tmp_path / "joblib", jobs=1)
    r = run_sweep(base, pts, tmp_path / "dask", jobs=2, backend="dask")
    assert r.done == [p.id for p in pts]
    expected = (tmp_path / "joblib" / "results.csv").read_bytes()
    assert (tmp_path / "dask" / "results.csv").read_bytes() == expected


def test_edited_map_is_not_resumed(tmp_path: Path):
    from qpatrol.config import from_flat
    from qpatrol.study.sweep import points_for, run_sweep

    m = tmp_path / "m.txt"
    m.write_text("0....\n.#.#.\n.....\n")
    base = from_flat({"map": str(m), "agents": 1, "steps": 30, "battery.enabled": False})
    pts = points_for("learning.gamma", [0.1, 0.2])
    run_sweep(base, pts, tmp_path / "s")
    m.write_text("0....\n.#.#.\n....o\n")
    with pytest.raises(ConfigError, match="has changed since the sweep started"):
        run_sweep(base, pts, tmp_path / "s")


def test_policies_and_learning_sweeps():
    """Every map x strategy x team size; each point measures the same window, learners
    after a longer warm-up; the quick set is a subset with the same rule."""
    from qpatrol.strategies import NAMES, learns
    from qpatrol.study import sweep as sw

    for quick in (False, True):
        pts = NAMED_SWEEPS["policies"].points(quick)
        ov = [p.overrides for p in pts]
        maps = {o["map"] for o in ov}
        teams = {o["agents"] for o in ov}
        assert len(pts) == len(maps) * len(NAMES) * len(teams)
        assert {o["policy"] for o in ov} == set(NAMES)
        windows = {o["steps"] - o["record.warmup"] for o in ov}
        assert len(windows) == 1
        for o in ov:
            longer = o["record.warmup"] > min(x["record.warmup"] for x in ov)
            assert longer == learns(o["policy"])
    full = [p.overrides for p in NAMED_SWEEPS["policies"].points()]
    assert (
        {o["map"] for o in full} == set(sw.POLICY_MAPS) == {"map_a", "map_b", "pacman", "facility"}
    )
    assert {o["agents"] for o in full} == {1, 2, 4, 8}
    assert full[0]["steps"] - full[0]["record.warmup"] == sw.POLICY_WINDOW
    learning = [p.overrides for p in NAMED_SWEEPS["learning"].points()]
    assert {o["policy"] for o in learning} == set(NAMES) - {"random"}
    for o in learning:
        assert o["steps"] == sw.learning_steps(o["policy"])
        assert (o["steps"] > sw.LEARNING_OTHERS_STEPS) == learns(o["policy"])
    assert sw.learning_steps("qlearning") == 200_000 and sw.policy_warmup("qlearning") == 100_000


def test_a_swept_key_named_like_a_measure_keeps_its_value(base, tmp_path):
    """Sweeping ``steps`` (as the policies study does): the swept column holds the
    config's steps and the runs' own ``steps`` is written as ``steps_run``; an episode
    quota makes them differ."""
    pts = points_for("steps", [300, 400])
    run_sweep(base.replace(episodes=1, max_episode_steps=100), pts, tmp_path / "s")
    df = load_results(tmp_path / "s")
    assert list(df.columns).count("steps") == 1 and "steps_run" in df.columns
    assert sorted(set(df["steps"])) == [300, 400]
    assert (df["steps_run"] < df["steps"]).all()
