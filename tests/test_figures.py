"""Figure tables from tiny experiment folders, and every plot writes its image."""

import itertools
import json
import math

import numpy as np
import pandas as pd
import pytest

from qpatrol.config import from_flat
from qpatrol.maps import DIR_LETTERS, get_map
from qpatrol.measures.records import to_csv_text
from qpatrol.run import simulate, write_run
from qpatrol.study import figures, plots

#: on one worker under pytest-xdist: the module fixtures are built once
pytestmark = pytest.mark.xdist_group("figures")

# 17 free cells; cell 3 is a T-junction (West, East, South); H at cell 13
TINY = """; name: tiny
#########
#0.....1#
#.##.##.#
#...H...#
#########
"""
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def tiny_map(tmp_path_factory):
    path = tmp_path_factory.mktemp("maps") / "tiny.txt"
    path.write_text(TINY)
    return str(path)


def base(tiny_map, **kw):
    flat = {
        "map": tiny_map,
        "agents": 1,
        "runs": 2,
        "seed": 7,
        "steps": 400,
        "battery.enabled": False,
    }
    flat.update(kw)
    return flat


def make_sweep(out, flat, grid):
    """A sweep folder as qpatrol's sweep writes it: sweep.json, points/<id>/, results.csv."""
    cfg0 = from_flat(flat)
    keys = list(grid)
    points, rows = [], []
    for i, values in enumerate(itertools.product(*grid.values())):
        ov = dict(zip(keys, values, strict=True))
        pid = f"{i:03d}-" + ",".join(f"{k}={v}" for k, v in ov.items())
        points.append({"index": i, "id": pid, "overrides": ov})
        res = simulate(cfg0.replace(**ov), point=i)
        write_run(res, out / "points" / pid)
        rows += [{"point": i, "point_id": pid, **ov, **s} for s in res.summary]
    (out / "sweep.json").write_text(json.dumps({"base": cfg0.tree(), "points": points}))
    df = pd.DataFrame(rows)
    front = ["point", "point_id", *keys, "run"]
    df = df[front + [c for c in df.columns if c not in front]]
    (out / "results.csv").write_text(to_csv_text(df))
    return out


@pytest.fixture(scope="module")
def folders(tmp_path_factory, tiny_map):
    root = tmp_path_factory.mktemp("experiments")
    f = {}
    f["fig2"] = make_sweep(
        root / "fig2",
        base(tiny_map, steps=1500, runs=1, **{"record.watch": [3]}),
        {"learning.multiplier": [1, 100]},
    )
    f["gamma"] = make_sweep(
        root / "gamma",
        base(tiny_map, runs=4, steps=2000, episodes=1, max_episode_steps=500),
        {"learning.gamma": [0.1, 0.9]},
    )
    f["team"] = make_sweep(
        root / "team",
        base(tiny_map, steps=300),
        {"agents": [1, 2], "team.communication": [True, False]},
    )
    run = simulate(from_flat(base(tiny_map, agents=2, steps=600, **{"record.watch": [3]})))
    f["run"] = write_run(run, root / "run")
    return f


def test_t_quantile_and_mean_ci():
    assert figures.t_quantile(0.975, 1) == pytest.approx(12.7062047, abs=1e-6)
    assert figures.t_quantile(0.975, 9) == pytest.approx(2.2621572, abs=1e-6)
    assert figures.t_quantile(0.025, 30) == pytest.approx(-2.0422725, abs=1e-6)
    ci = figures.mean_ci([1.0, 2.0, 3.0, None, float("nan")])
    assert ci["n"] == 3 and ci["mean"] == 2.0
    assert ci["hi"] - 2.0 == pytest.approx(4.30265273 / math.sqrt(3), rel=1e-7)
    one = figures.mean_ci([5.0])
    assert one["n"] == 1 and math.isnan(one["lo"])


def test_choose_heading():
    east, south = DIR_LETTERS.index("E"), DIR_LETTERS.index("S")
    assert figures.choose_heading([{1: 100, 2: 300}], 100) == east
    assert figures.choose_heading([{1: 99, 2: 300}], 100) == south
    # common fallback over several series: the heading whose fewest updates is largest
    assert figures.choose_heading([{1: 50, 2: 300, 3: 60}, {1: 120, 2: 10, 3: 70}], 100) == 3


def test_figure2_data(folders):
    df = figures.figure2_data(folders["fig2"], cell=3, n_updates=20)
    assert list(df.columns[:7]) == [
        "multiplier",
        "update",
        "step",
        "heading",
        "action",
        "reward",
        "q_west",
    ]
    assert {"q_east", "run", "cell"} <= set(df.columns)
    assert sorted(df["multiplier"].unique()) == [1.0, 100.0]
    assert df["heading"].nunique() == 1 and (df["run"] == 0).all() and (df["cell"] == 3).all()
    for _, d in df.groupby("multiplier"):
        assert len(d) == 20  # the tiny map passes cell 3 often enough
        assert d["update"].tolist() == list(range(1, 21))
        assert d["step"].is_monotonic_increasing
    first = df[(df["multiplier"] == 100) & (df["update"] == 1)].iloc[0]
    # the first update of the row: whichever of W/E was not taken still holds 2 x 100
    if first["action"] != "W":
        assert first["q_west"] == 200.0
    if first["action"] != "E":
        assert first["q_east"] == 200.0
    fixed = figures.figure2_data(folders["fig2"], cell=3, n_updates=5, heading="S")
    assert (fixed["heading"] == "S").all() and len(fixed) <= 10


def test_figure34_data(folders):
    df = figures.figure34_data(folders["run"], cell=3, n_updates=30)
    assert {"update", "step", "action", "reward", "bootstrap", "q_west", "q_east"} <= set(
        df.columns
    )
    assert 0 < len(df) <= 30
    assert df["heading"].nunique() == 1
    assert (df["reward"] > 0).all() and (df["bootstrap"] > 0).all()
    # only the action taken changes: the other of W/E carries over from the row before
    prev = df.shift(1)
    not_w = (df["action"] != "W") & (df["update"] > 1)
    not_e = (df["action"] != "E") & (df["update"] > 1)
    assert (df.loc[not_w, "q_west"] == prev.loc[not_w, "q_west"]).all()
    assert (df.loc[not_e, "q_east"] == prev.loc[not_e, "q_east"]).all()
    with pytest.raises(ValueError):
        figures.figure34_data(folders["run"], cell=5)


def test_gamma_data(folders):
    df = figures.gamma_data(folders["gamma"])
    assert df["gamma"].tolist() == [0.1, 0.9]
    for col in (
        "steps_mean",
        "steps_lo",
        "steps_hi",
        "distinct_states_mean",
        "n",
        "runs",
        "lower_bound",
        "tour",
        "truncated",
        "unfinished",
    ):
        assert col in df.columns
    assert (df["lower_bound"] <= df["tour"]).all()
    assert (df["n"] + df["truncated"] + df["unfinished"] == df["runs"]).all()
    ok = df[df["n"] >= 2]
    assert (ok["steps_lo"] <= ok["steps_mean"]).all() and (ok["steps_mean"] <= ok["steps_hi"]).all()
    # no complete first episode can beat the shortest walk
    assert (df["steps_min"].dropna() >= df.loc[df["steps_min"].notna(), "lower_bound"]).all()
    assert df["dots"].iloc[0] == 16 and df["cells"].iloc[0] == 17


def test_team_size_data(folders):
    df = figures.team_size_data(folders["team"])
    assert len(df) == 4
    assert set(zip(df["agents"], df["communication"], strict=True)) == {
        (1, True),
        (1, False),
        (2, True),
        (2, False),
    }
    for m in ("mean_steps_per_episode", "division_of_labour", "avg_idleness"):
        for s in ("mean", "lo", "hi", "n"):
            assert f"{m}_{s}" in df.columns
    solo = df[df["agents"] == 1]
    assert np.allclose(solo["division_of_labour_mean"], 1.0)
    assert (df["division_of_labour_mean"] >= 0.5 - 1e-9).all()


def test_figure6_data(folders, tiny_map):
    df = figures.figure6_data(folders["run"], agent=0, run=0)
    m = get_map(tiny_map)
    assert len(df) == m.n_cells
    assert (df["visits_all"] >= df["visits_agent"]).all()
    for _, row in df.iterrows():
        assert m.neighbors[row["cell"], DIR_LETTERS.index(row["action"])] >= 0  # never a wall
    assert df["heading_share"].dropna().between(0.25 - 1e-9, 1).all()
    assert (df["agents"] == 2).all()


@pytest.mark.parametrize("battery", [False, True])
def test_trajectory_matches_simulate(tiny_map, battery):
    flat = base(tiny_map, agents=3, runs=2, steps=250, **{"battery.enabled": battery})
    if battery:
        flat.update({"battery.capacity": 40, "battery.charge_steps": 5})
    cfg = from_flat(flat)
    for point in (0, 2):
        result = simulate(cfg, point=point)
        for run in (0, 1):
            tr = figures.trajectory(cfg, 250, run=run, point=point)
            last = tr[tr["step"] == tr["step"].max()].sort_values("agent")
            assert tr["step"].max() == 250
            assert last["cell"].tolist() == result.state.pos[run].tolist()
    tr = figures.trajectory(cfg, 20, skip=100)
    assert tr["step"].min() == 100 and tr["step"].max() == 120
    assert len(tr) == 21 * 3
    m = get_map(tiny_map)
    assert (m.coords[tr["cell"], 0] == tr["row"]).all()
    if battery:
        full = figures.trajectory(cfg, 250)
        assert (full["mode"] != "patrol").any()  # homing/charging shows up


def test_figure5_data_matches_trajectory(tmp_path, tiny_map):
    from qpatrol.config import FIELDS

    if "record.trajectory" not in FIELDS:
        pytest.skip("the core does not record trajectory.csv")
    cfg = from_flat(base(tiny_map, agents=2, runs=2, steps=120, **{"record.trajectory": 30}))
    run_dir = write_run(simulate(cfg), tmp_path / "run")
    for run in (0, 1):
        recorded = figures.figure5_data(run_dir, run=run)
        assert recorded["step"].min() == 91 and recorded["step"].max() == 120
        ours = figures.trajectory(cfg, 30, run=run, skip=90)
        ours = ours[ours["step"] > 90].reset_index(drop=True)
        cols = ["step", "agent", "cell", "row", "col"]
        pd.testing.assert_frame_equal(recorded[cols], ours[cols], check_dtype=False)


def test_plots_write_images(folders, tmp_path, tiny_map):
    def csv(name, df):
        p = tmp_path / f"{name}.csv"
        p.write_text(to_csv_text(df))
        return p

    out = {}
    out["f2"] = plots.figure_2(
        csv("f2", figures.figure2_data(folders["fig2"], cell=3, n_updates=20)), tmp_path / "f2"
    )
    f34 = csv("f34", figures.figure34_data(folders["run"], cell=3))
    out["f3"] = plots.figure_3(f34, tmp_path / "f3.png")
    out["f4"] = plots.figure_4(f34, tmp_path / "f4.png")
    out["gamma"] = plots.gamma(csv("g", figures.gamma_data(folders["gamma"])), tmp_path / "g.png")
    out["team"] = plots.team_size(
        csv("t", figures.team_size_data(folders["team"])), tmp_path / "t.png"
    )
    out["f6"] = plots.figure_6(csv("f6", figures.figure6_data(folders["run"])), tmp_path / "f6.png")
    for key, p in out.items():
        assert p.suffix == ".png", key
        assert p.read_bytes()[:8] == PNG, key
    svg = plots.figure_6(tmp_path / "f6.csv", tmp_path / "f6.svg")
    assert b"<svg" in svg.read_bytes()[:500]

    cfg = from_flat(base(tiny_map, agents=2, steps=50))
    tr = csv("f5", figures.trajectory(cfg, 12))
    gif, still = plots.figure_5(tr, tmp_path / "f5.gif", frames=10, trail=4)
    assert gif.read_bytes()[:6] in (b"GIF89a", b"GIF87a")
    assert still.read_bytes()[:8] == PNG


RING12 = "; name: ring12\n....\n.##.\n.##.\n....\n"


@pytest.fixture(scope="module")
def study(tmp_path_factory, tiny_map):
    """A policies-like sweep over two maps, a learner and two classic strategies, K = 1, 2;
    and a learning-like sweep with record.timeline."""
    root = tmp_path_factory.mktemp("study")
    ring = root / "ring12.txt"
    ring.write_text(RING12)
    flat = base(tiny_map, steps=300, **{"record.warmup": 100})
    pol = make_sweep(
        root / "policies",
        flat,
        {
            "map": [tiny_map, str(ring)],
            "policy": ["qlearning", "conscientious", "cyclic"],
            "agents": [1, 2],
        },
    )
    learn = make_sweep(
        root / "learning",
        base(str(ring), steps=120, **{"record.timeline": 12}),
        {"policy": ["qlearning", "cyclic"]},
    )
    return pol, learn


def test_policies_data(study):
    df = figures.policies_data(study[0])
    assert len(df) == 2 * 3 * 2
    assert list(dict.fromkeys(df["map"])) == ["tiny", "ring12"]  # sweep order
    ring = df[df["map"] == "ring12"]
    # the closed walk through the 12-ring is the ring itself: L = 12, L/K = 12/K
    assert (ring["walk_length"] == 12).all()
    assert (
        sorted(zip(ring["agents"], ring["bound_per_robot"], strict=True))
        == [(1, 12.0)] * 3 + [(2, 6.0)] * 3
    )
    # a cyclic robot on the ring: every cell every 12 steps, whatever happened before
    cyc = ring[(ring["policy"] == "cyclic") & (ring["agents"] == 1)].iloc[0]
    assert cyc["mean_interval_mean"] == 12 and cyc["avg_idleness_mean"] == 5.5
    assert (df["warmup"] == 100).all() and (df["window"] == 200).all()
    assert df.set_index("policy")["learns"].to_dict() == {
        "qlearning": True,
        "conscientious": False,
        "cyclic": False,
    }


def test_learning_data(study):
    df = figures.learning_data(study[1])
    assert set(df["policy"]) == {"qlearning", "cyclic"}
    cyc = df[df["policy"] == "cyclic"].sort_values("window")
    assert list(cyc["last_step"]) == list(range(12, 121, 12))
    late = cyc[cyc["window"] >= 2]
    assert (late["avg_idleness_mean"] == 5.5).all() and (late["worst_idleness_mean"] == 11).all()
    assert (df["runs"] == 2).all()


def test_study_plots_write_images(study, tmp_path):
    for name, data, draw in (
        ("policies", figures.policies_data, plots.policies),
        ("learning", figures.learning_data, plots.learning),
    ):
        folder = study[0] if name == "policies" else study[1]
        csv = tmp_path / f"{name}.csv"
        csv.write_text(to_csv_text(data(folder)))
        assert draw(csv, tmp_path / f"{name}.png").read_bytes()[:8] == PNG


def test_settle_steps_counts_only_windows_that_start_after_the_failure():
    """A window that starts at the failure step holds steps before it: not counted."""
    from qpatrol.study.figures import settle_steps

    first = np.array([1, 11, 21, 31, 41])
    last = np.array([10, 20, 30, 40, 50])
    worst = np.array([5.0, 8.0, 50.0, 8.0, 8.0])
    # after step 11: windows 21-30 (50), 31-40 (8), 41-50 (8); level 8, reached by step 40
    assert settle_steps(first, last, worst, 11) == 40 - 11
    # after step 10: the window 11-20 is the first within the band of the level 8
    assert settle_steps(first, last, worst, 10) == 20 - 10
    assert settle_steps(first, last, worst, 41) is None
