"""The experiment commands (`sweep`, `plot`, `reproduce`) at tiny budgets, and the CI check
that the quick reproduction still gives the committed reference numbers."""

import importlib.util
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from qpatrol import engines
from qpatrol.cli import app
from qpatrol.measures import FIELD_MEASURES
from qpatrol.study import reproduce as rp

runner = CliRunner()
REPO = Path(__file__).resolve().parent.parent
REFERENCES = REPO / "results" / "reference" / "quick"


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def test_sweep_named_param_and_grid(tmp_path: Path):
    out = tmp_path / "mult"
    res = invoke("sweep", "multiplier", "--runs", "1", "--set", "steps=300", "--out", out)
    assert res.exit_code == 0, res.output
    df = pd.read_csv(out / "results.csv")
    assert df["learning.multiplier"].tolist() == [1, 10, 100, 1000]
    # rerun: nothing to do
    res = invoke("sweep", "multiplier", "--runs", "1", "--set", "steps=300", "--out", out)
    assert "0 points run, 4 already done" in res.output
    # one key from the command line
    cfg = REPO / "configs" / "figure4.yaml"
    res = invoke(
        "sweep",
        "learning.gamma",
        "--values",
        "0.2,0.4",
        cfg,
        "--set",
        "steps=200",
        "--runs",
        "2",
        "--out",
        tmp_path / "g",
        "--jobs",
        "2",
    )
    assert res.exit_code == 0, res.output
    assert pd.read_csv(tmp_path / "g" / "results.csv")["run"].tolist() == [0, 1, 0, 1]
    res = invoke(
        "sweep",
        "--grid",
        "agents=1,2",
        "--grid",
        "team.communication=on,off",
        cfg,
        "--set",
        "steps=100",
        "--runs",
        "1",
        "--out",
        tmp_path / "grid",
    )
    assert res.exit_code == 0, res.output
    grid = pd.read_csv(tmp_path / "grid" / "results.csv")
    assert grid[["agents", "team.communication"]].values.tolist() == [
        [1, True],
        [1, False],
        [2, True],
        [2, False],
    ]


@pytest.mark.parametrize(
    "args, words",
    [
        (
            ["learning.gamma", "--values", "0.1,1.5", "configs/figure4.yaml"],
            "learning.gamma: got 1.5",
        ),
        (["nonsense"], "give a named sweep"),
        (["--grid", "agents", "configs/figure4.yaml"], "expected KEY=V1,V2"),
        (["multiplier", "--set", "lerning.gamma=0.1"], "unknown config key"),
    ],
)
def test_sweep_bad_input(tmp_path: Path, args, words, monkeypatch):
    monkeypatch.chdir(REPO)
    res = invoke("sweep", *args, "--out", tmp_path / "s")
    assert res.exit_code == 2, res.output
    assert words in res.stderr and "Traceback" not in res.output
    assert not (tmp_path / "s").exists()


def test_sweep_failed_point_exits_nonzero(tmp_path: Path):
    cfg = REPO / "configs" / "figure4.yaml"
    res = invoke(
        "sweep",
        "map",
        "--values",
        f"map_b,{tmp_path / 'missing.txt'}",
        cfg,
        "--set",
        "steps=50",
        "--runs",
        "1",
        "--out",
        tmp_path / "s",
    )
    assert res.exit_code == 1
    assert "failed" in res.stderr and "missing.txt" in res.stderr
    assert len(pd.read_csv(tmp_path / "s" / "results.csv")) == 1


def test_plot_from_a_sweep(tmp_path: Path):
    out = tmp_path / "mult"
    assert (
        invoke("sweep", "multiplier", "--runs", "1", "--set", "steps=2000", "--out", out).exit_code
        == 0
    )
    png = tmp_path / "f2.png"
    res = invoke("plot", "figure-2", "--from", out, "--out", png)
    assert res.exit_code == 0, res.output
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert set(pd.read_csv(png.with_suffix(".csv"))["multiplier"]) == {1, 10, 100, 1000}
    svg = tmp_path / "f2.svg"
    assert invoke("plot", "figure-2", "--from", out, "--out", svg).exit_code == 0
    assert b"<svg" in svg.read_bytes()[:500]
    res = invoke("plot", "figure-9", "--from", out)
    assert res.exit_code == 2 and "unknown figure" in res.stderr
    res = invoke("plot", "gamma", "--from", tmp_path / "nowhere")
    assert res.exit_code == 2 and "no such folder" in res.stderr


def test_reproduce_flags():
    res = invoke("reproduce", "--update-references")
    assert res.exit_code == 2 and "needs --quick" in res.stderr


def test_quick_reproduction_matches_the_committed_references(tmp_path: Path, monkeypatch):
    """A change that moves any number of the quick run fails here until the references are
    regenerated on purpose: `qpatrol reproduce --quick --update-references`.

    Every batch runs on the compiled engine where it can (``engine: auto`` would run
    the quick mode's small batches on numpy, and its loops uncompiled yet too): the
    engines agree to the bit, and this way the run takes 12 s of CPU, not 80."""
    assert list(REFERENCES.glob("*/*.csv")), "no committed references"
    if importlib.util.find_spec("numba") is not None:
        from qpatrol.engines import coldstart

        monkeypatch.setattr(engines, "AUTO_NUMPY_SECONDS", 0.0)
        monkeypatch.setattr(coldstart, "cold_note", lambda *args, **kwargs: None)
    rp.reproduce(tmp_path, quick=True, jobs=1, draw=False, log=lambda s: None)
    fresh = {f"{p.parent.name}/{p.name}" for p in tmp_path.glob("*/*.csv")}
    committed = {f"{p.parent.name}/{p.name}" for p in REFERENCES.glob("*/*.csv")}
    assert fresh == committed
    # the committed columns byte for byte (as text, cell by cell); the field's measures,
    # added after the references were made, must be in every results.csv
    assert rp.compare_with_references(tmp_path, REFERENCES, FIELD_MEASURES) == []
    for path in tmp_path.glob("data/*-results.csv"):
        assert set(FIELD_MEASURES) <= set(pd.read_csv(path, nrows=0).columns), path.name


def test_reference_comparison_allows_only_the_named_new_columns(tmp_path: Path):
    """compare_with_references: a CSV equal byte for byte, or with named new columns and
    every old cell unchanged, passes; a changed cell, a missing column, a column not
    named, or a row more fails."""
    ref, out = tmp_path / "ref" / "data", tmp_path / "out" / "data"
    ref.mkdir(parents=True)
    out.mkdir(parents=True)
    (ref / "a.csv").write_text("run,x,y\n0,1.5,a\n1,2,b\n")
    cases = {
        "run,x,y\n0,1.5,a\n1,2,b\n": True,
        "run,x,y,qmi\n0,1.5,a,3.0\n1,2,b,\n": True,
        "run,qmi,x,y\n0,3.0,1.5,a\n1,,2,b\n": True,
        "run,x,y,qmi\n0,1.50,a,3.0\n1,2,b,\n": False,  # the text of a cell changed
        "run,x,qmi\n0,1.5,3.0\n1,2,\n": False,  # y is missing
        "run,x,y,other\n0,1.5,a,3.0\n1,2,b,\n": False,  # not a named column
        "run,x,y,qmi\n0,1.5,a,3.0\n1,2,b,\n2,2,b,\n": False,  # a row more
    }
    for text, same in cases.items():
        (out / "a.csv").write_text(text)
        diffs = rp.compare_with_references(tmp_path / "out", tmp_path / "ref", ["qmi"])
        assert (diffs == []) == same, text
    (out / "a.csv").write_text("run,x,y,qmi\n0,1.5,a,3.0\n1,2,b,\n")
    assert rp.compare_with_references(tmp_path / "out", tmp_path / "ref") == ["data/a.csv"]
