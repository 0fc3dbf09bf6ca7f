"""Nothing lost: ``--force`` removes only what qpatrol wrote, results never mix.

Every folder qpatrol writes lists its files in ``manifest.json``
(:mod:`qpatrol.util.manifest`). These tests drive the real entry point and check that a
user's files are never removed or replaced, that a finished point is reused only when it
is what this qpatrol would write, and that the manifest's checks catch every kind of
stray entry.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from qpatrol import __version__, cli
from qpatrol.run import outputs
from qpatrol.study import reproduce as rp
from qpatrol.util import manifest

pytestmark = pytest.mark.xdist_group("manifests")


def run(*args: object) -> tuple[int, str]:
    """``qpatrol ARGS...`` in this process: (exit code, stderr) via capsys-free capture."""
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            cli.main([str(a) for a in args])
            code = 0
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    return code, err.getvalue()


def one_line(code: int, err: str, words: str) -> None:
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("qpatrol: error: "), err
    assert words in lines[0], err


def tiny(tmp_path: Path, **extra) -> Path:
    cfg = {"map": "map_b", "agents": 2, "runs": 1, "seed": 3, "steps": 60, "battery": False}
    cfg.update(extra)
    p = tmp_path / "tiny.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


def snapshot(root: Path) -> dict[str, bytes | None]:
    """Every path under ``root`` with a file's bytes (None for a folder)."""
    return {
        str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
        for p in sorted(root.rglob("*"))
    }


def sweep_args(cfg: Path, out: Path, values: str = "0.2,0.3", *more: str) -> list[object]:
    return ["sweep", "learning.gamma", "--values", values, cfg, "--out", out, "-q", *more]


# ------------------------------------------------------------------ --force and users' files


@pytest.mark.parametrize("planted", [["meta.json"], ["config.yaml", "summary.json"]])
def test_force_keeps_a_folder_that_only_looks_like_a_run(tmp_path, planted):
    h = tmp_path / "h"
    (h / ".ssh").mkdir(parents=True)
    (h / "Doc").mkdir()
    (h / ".ssh" / "id_rsa").write_text("k\n")
    (h / "data").mkdir()
    (h / "data" / "model.bin").write_bytes(b"\0\1")
    for name in planted:
        (h / name).write_text("{}\n")
    before = snapshot(h)
    one_line(*run("train", tiny(tmp_path), "--out", h, "--force"), "qpatrol did not write it")
    assert snapshot(h) == before


def test_force_replaces_a_run_folder_only_when_it_holds_nothing_else(tmp_path):
    cfg, out = tiny(tmp_path), tmp_path / "r"
    assert run("train", cfg, "--out", out, "-q")[0] == 0
    m = manifest.read(out)
    assert m is not None and m.kind == "run" and m.qpatrol == __version__
    assert set(m.files) | set(m.provenance) == {p.name for p in out.iterdir()} - {"manifest.json"}
    assert m.provenance == ["meta.json"]
    for where in ("mine.txt", "sub/notes.txt", ".hidden"):
        (out / where).parent.mkdir(exist_ok=True)
        (out / where).write_text("mine\n")
        before = snapshot(tmp_path)
        one_line(*run("train", cfg, "--out", out, "-q", "--force"), f"holds {where.split('/')[0]}")
        assert snapshot(tmp_path) == before
        (out / where).unlink()
        if where.startswith("sub/"):
            (out / "sub").rmdir()
    assert run("train", cfg, "--out", out, "-q", "--force")[0] == 0
    assert manifest.strays(out) == [] and manifest.changed(out) == []
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_force_refuses_a_folder_without_manifest_and_a_link(tmp_path):
    cfg, out = tiny(tmp_path), tmp_path / "r"
    assert run("train", cfg, "--out", out, "-q")[0] == 0
    (out / "manifest.json").unlink()  # as a qpatrol that kept none would have left it
    one_line(*run("train", cfg, "--out", out, "--force"), "has no manifest.json")
    assert (out / "summary.json").is_file()
    link = tmp_path / "link"
    link.symlink_to(out)
    one_line(*run("train", cfg, "--out", link, "--force"), "a symbolic link")
    assert (out / "summary.json").is_file()


def test_a_user_file_appearing_during_the_run_is_kept(tmp_path, monkeypatch):
    """The folder is checked again when the run is written; removal goes by the list."""
    cfg, out = tiny(tmp_path), tmp_path / "r"
    assert run("train", cfg, "--out", out, "-q")[0] == 0
    import qpatrol.run as run_mod

    real = run_mod.simulate

    def simulate_then_add(*a, **k):
        result = real(*a, **k)
        (out / "late.txt").write_text("mine\n")
        return result

    monkeypatch.setattr(run_mod, "simulate", simulate_then_add)
    one_line(*run("train", cfg, "--out", out, "-q", "--force"), "holds late.txt")
    assert (out / "late.txt").read_text() == "mine\n" and (out / "summary.json").is_file()


def test_remove_never_deletes_an_unlisted_file(tmp_path):
    d = tmp_path / "d"
    (d / "sub").mkdir(parents=True)
    (d / "a.txt").write_text("a")
    (d / "sub" / "b.txt").write_text("b")
    manifest.write(d, "run", ["a.txt", "sub/b.txt"])
    (d / "sub" / "user.txt").write_text("mine")
    assert manifest.strays(d) == ["sub/user.txt"]
    manifest.remove(d)  # as if the user's file came after the check
    assert snapshot(tmp_path) == {"d": None, "d/sub": None, "d/sub/user.txt": b"mine"}


@pytest.mark.parametrize(
    "make, stray",
    [
        (lambda d: (d / "x").write_text("x"), "x"),
        (lambda d: (d / "e").mkdir(), "e"),
        (lambda d: (d / "p" / "inner").mkdir(), "p/inner"),
        (lambda d: (d / "p" / "q" / "y").write_text("y"), "p/q/y"),
        (lambda d: (d / "l").symlink_to(d / "a"), "l"),
        (lambda d: ((d / "a").unlink(), (d / "a").mkdir()), "a"),
        (lambda d: (d / "p" / "q" / "manifest.json").unlink(), "p/q"),
    ],
)
def test_strays_finds_every_kind_of_foreign_entry(tmp_path, make, stray):
    d = tmp_path / "d"
    (d / "p" / "q").mkdir(parents=True)
    (d / "a").write_text("a")
    (d / "p" / "b").write_text("b")
    (d / "p" / "q" / "c").write_text("c")
    manifest.write(d / "p" / "q", "run", ["c"])
    manifest.write(d, "sweep", ["a", "p/b"], ["p/q"])
    assert manifest.strays(d) == []
    make(d)
    assert manifest.strays(d) == [stray]


def test_a_damaged_manifest_is_refused(tmp_path):
    cfg, out = tiny(tmp_path), tmp_path / "r"
    assert run("train", cfg, "--out", out, "-q")[0] == 0
    doc = json.loads((out / "manifest.json").read_text())
    doc["files"]["../outside"] = {"size": 1, "sha256": "0"}
    (out / "manifest.json").write_text(json.dumps(doc))
    one_line(*run("train", cfg, "--out", out, "--force"), "not a qpatrol manifest")
    (out / "manifest.json").write_text("{nope")
    one_line(*run("train", cfg, "--out", out, "--force"), "unreadable")
    assert (out / "summary.json").is_file()


@pytest.mark.parametrize("out", ["/", "."])
def test_out_that_can_never_be_a_qpatrol_folder(tmp_path, out):
    for args in (
        ["train", tiny(tmp_path), "--out", out],
        sweep_args(tiny(tmp_path), Path(out)),
        ["reproduce", "--quick", "--out", out],
    ):
        one_line(*run(*args), "give a folder of its own")


def test_out_that_is_a_device(tmp_path):
    one_line(
        *run("train", tiny(tmp_path), "--out", "/dev/null"), "is a character device, not a folder"
    )


# --------------------------------------------------------------------------------- sweeps


def test_sweep_never_overwrites_a_users_files(tmp_path):
    proj = tmp_path / "proj"
    proj.mkdir()
    (proj / "results.csv").write_text("mine\n")
    (proj / "meta.json").write_text("{}\n")
    before = snapshot(tmp_path)
    for force in ([], ["--force"]):
        one_line(*run(*sweep_args(tiny(tmp_path), proj, "0.2,0.3", *force)), "did not write it")
        assert snapshot(tmp_path) == {**before, "tiny.yaml": snapshot(tmp_path)["tiny.yaml"]}


def test_sweep_force_keeps_a_user_file_among_the_points(tmp_path):
    cfg, out = tiny(tmp_path), tmp_path / "s"
    assert run(*sweep_args(cfg, out))[0] == 0
    (out / "points" / "notes.txt").write_text("mine\n")
    before = snapshot(out)
    one_line(*run(*sweep_args(cfg, out, "0.2,0.3", "--force")), "holds points/notes.txt")
    assert snapshot(out) == before
    (out / "points" / "notes.txt").unlink()
    assert run(*sweep_args(cfg, out, "0.2,0.3", "--force"))[0] == 0


def test_a_sweep_reuses_only_points_this_qpatrol_would_write(tmp_path):
    cfg, out = tiny(tmp_path), tmp_path / "s"
    assert run(*sweep_args(cfg, out))[0] == 0
    point = sorted((out / "points").iterdir())[0]
    summary = json.loads((point / "summary.json").read_text())
    summary["runs"][0]["avg_idleness"] = 12345
    (point / "summary.json").write_text(json.dumps(summary))
    before = snapshot(out)
    one_line(*run(*sweep_args(cfg, out)), f"{point.name}: summary.json changed")
    assert snapshot(out) == before
    assert run(*sweep_args(cfg, out, "0.2,0.3", "--force"))[0] == 0
    assert "12345" not in (out / "results.csv").read_text()
    # a point another version wrote (its manifest says so)
    doc = json.loads((point / "manifest.json").read_text())
    doc["qpatrol"] = "0.0.9"
    (point / "manifest.json").write_text(json.dumps(doc))
    one_line(*run(*sweep_args(cfg, out)), "written by qpatrol 0.0.9")
    # a point whose config is not the point's config now
    doc["qpatrol"] = __version__
    doc["config"] = "0" * 64
    (point / "manifest.json").write_text(json.dumps(doc))
    one_line(*run(*sweep_args(cfg, out)), "its config.yaml is not the point's config now")


def test_a_point_finished_before_a_kill_is_adopted(tmp_path):
    cfg, out = tiny(tmp_path), tmp_path / "s"
    assert run(*sweep_args(cfg, out))[0] == 0
    doc = json.loads((out / "manifest.json").read_text())
    first = doc["folders"].pop(0)  # the sweep was killed before it listed this point
    (out / "manifest.json").write_text(json.dumps(doc))
    code, err = run(*sweep_args(cfg, out))
    assert code == 0, err
    assert first in manifest.read(out).folders
    assert run(*sweep_args(cfg, out, "0.2,0.3", "--force"))[0] == 0


def test_sweep_refuses_a_repeated_value(tmp_path):
    one_line(*run(*sweep_args(tiny(tmp_path), tmp_path / "s", "0.1,0.10")), "given twice")
    assert not (tmp_path / "s").exists()


def test_runs_zero_names_the_option(tmp_path):
    one_line(*run(*sweep_args(tiny(tmp_path), tmp_path / "s"), "--runs", "0"), "--runs 0:")


# ----------------------------------------------------------------------------- plot


@pytest.fixture(scope="module")
def mult(tmp_path_factory):
    out = tmp_path_factory.mktemp("mult") / "mult"
    code, err = run("sweep", "multiplier", "--runs", "1", "--set", "steps=300", "--out", out, "-q")
    assert code == 0, err
    return out


def test_plot_replaces_no_file_it_did_not_write(tmp_path, mult):
    plt_dir = tmp_path / "plt"
    plt_dir.mkdir()
    (plt_dir / "fig.csv").write_text("mine\n")
    one_line(*run("plot", "figure-2", "--from", mult, "--out", plt_dir / "fig.png"), "fig.csv")
    assert (plt_dir / "fig.csv").read_text() == "mine\n"
    assert not (plt_dir / "fig.png").exists()
    assert run("plot", "figure-2", "--from", mult, "--out", plt_dir / "fig.png", "--force")[0] == 0
    assert (plt_dir / "fig.png").is_file() and "mine" not in (plt_dir / "fig.csv").read_text()
    assert not (plt_dir / "manifest.json").exists()  # not qpatrol's folder: no manifest there


def test_plot_redraws_its_own_figure(tmp_path, mult):
    target = tmp_path / "new" / "fig.png"
    for _ in range(2):
        code, err = run("plot", "figure-2", "--from", mult, "--out", target)
        assert code == 0, err
    m = manifest.read(target.parent)
    assert m is not None and set(m.files) == {"fig.png", "fig.csv"}
    target.write_bytes(b"edited")  # changed after qpatrol wrote it
    one_line(*run("plot", "figure-2", "--from", mult, "--out", target), "was changed after")
    assert target.read_bytes() == b"edited"


# ------------------------------------------------------------------------------- reproduce


def fake_results(out: Path, version: str = __version__) -> None:
    """A results folder as ``reproduce`` leaves it, small: a report, data, figures."""
    (out / "data").mkdir(parents=True)
    (out / "figures").mkdir()
    (out / "REPORT.md").write_text("# report\n")
    (out / "data" / "gamma-results.csv").write_text("a\n1\n")
    (out / "figures" / "gamma.csv").write_text("b\n2\n")
    manifest.seal(out / "figures", "figures")
    m = manifest.write(out, "reproduction", ["REPORT.md", "data/gamma-results.csv"], ["figures"])
    if version != __version__:
        doc = json.loads((out / "manifest.json").read_text())
        doc["qpatrol"] = version
        (out / "manifest.json").write_text(json.dumps(doc))
    del m


@pytest.mark.parametrize(
    "damage, words",
    [
        (lambda d: fake_results(d, "0.0.9"), "written by qpatrol 0.0.9"),
        (lambda d: (fake_results(d), (d / "REPORT.md").write_text("mine")), "REPORT.md changed"),
        (
            lambda d: (fake_results(d), (d / "figures" / "gamma.csv").write_text("x")),
            "figures/gamma.csv changed",
        ),
        (lambda d: (fake_results(d), (d / "notes.txt").write_text("x")), "holds notes.txt"),
        (lambda d: (d.mkdir(), (d / "REPORT.md").write_text("mine")), "has no manifest.json"),
    ],
)
def test_reproduce_refuses_results_it_would_mix_with(tmp_path, damage, words):
    out = tmp_path / "res"
    damage(out)
    before = snapshot(tmp_path)
    one_line(*run("reproduce", "--quick", "--out", out), words)
    assert snapshot(tmp_path) == before


def test_reproduce_accepts_its_own_results_and_nested_folders(tmp_path):
    out = tmp_path / "res"
    fake_results(out)
    rp.check_target(out, force=False)
    (out / "reference" / "quick" / "data").mkdir(parents=True)
    (out / "reference" / "quick" / "data" / "x.csv").write_text("1\n")
    with pytest.raises(outputs.OutputError, match="holds reference"):
        rp.check_target(out, force=True)
    manifest.seal(out / "reference" / "quick", "references")
    rp.check_target(out, force=True)
    (out / "REPORT.md").unlink()  # a file gone is written again, not a difference
    rp.check_target(out, force=False)


def test_reproduce_force_removes_only_listed_files(tmp_path):
    out = tmp_path / "res"
    fake_results(out)
    (out / "reference" / "quick").mkdir(parents=True)
    (out / "reference" / "quick" / "x.csv").write_text("1\n")
    manifest.seal(out / "reference" / "quick", "references")
    rp.check_target(out, force=True)
    manifest.remove(out)
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == [
        "reference",
        "reference/quick",
        "reference/quick/manifest.json",
        "reference/quick/x.csv",
    ]


def test_manifest_hashes_are_the_files(tmp_path):
    d = tmp_path / "d"
    d.mkdir()
    (d / "f").write_bytes(os.urandom(3_000_000))
    m = manifest.seal(d, "run")
    import hashlib

    assert m.files["f"] == {
        "size": 3_000_000,
        "sha256": hashlib.sha256((d / "f").read_bytes()).hexdigest(),
    }
    data = bytearray((d / "f").read_bytes())
    data[1_234_567] ^= 1
    (d / "f").write_bytes(bytes(data))
    assert manifest.changed(d) == ["f"]


def test_force_keeps_a_users_file_in_the_checkpoint_folder(tmp_path):
    cfg, out = tiny(tmp_path), tmp_path / "r"
    cp = tmp_path / "r.checkpoint"
    cp.mkdir()
    (cp / "info.json").write_text("{}\n")
    (cp / "thesis.tex").write_text("mine\n")
    before = snapshot(tmp_path)
    one_line(*run("train", cfg, "--out", out, "--force"), "which is not a checkpoint file")
    assert snapshot(tmp_path) == before
    (cp / "thesis.tex").unlink()
    assert run("train", cfg, "--out", out, "-q", "--force")[0] == 0
    assert not cp.exists() and (out / "manifest.json").is_file()


#: The entries of the folder :func:`test_a_manifest_lists_what_is_there` builds: a file, a
#: folder, links to each and a broken link, at the top and one level down, and a file
#: that stands where a folder would be.
TREE = {
    "f": "file", "d": "dir", "lf": "link:f", "ld": "link:d", "lx": "link:missing",
    "d/f": "file", "d/e": "dir", "d/lf": "link:../f", "d/lx": "link:nothing", "d/e/g": "file",
}  # fmt: skip
NAMES = [*TREE, "missing", "d/missing", "f/x", "missing/x", "ld/f", "lf/x", "d/e/g/x", "ld/e"]


@settings(max_examples=60, deadline=None)
@given(rels=st.lists(st.sampled_from(NAMES), unique=True))
def test_a_manifest_lists_what_is_there(tmp_path_factory, rels):
    """The manifest lists a file (or folder) exactly when ``Path.is_file`` (``is_dir``)
    says it is one: a listing per parent folder answers as a ``stat`` per path would,
    links followed, missing and misplaced parents included."""
    folder = tmp_path_factory.mktemp("tree")
    for rel, kind in TREE.items():
        path = folder / rel
        if kind == "file":
            path.write_text(rel)
        elif kind == "dir":
            path.mkdir()
        else:
            path.symlink_to(kind.split(":", 1)[1])
    files, dirs = manifest._present(folder, rels)
    assert files == {r for r in rels if (folder / r).is_file()}
    assert dirs == {r for r in rels if (folder / r).is_dir()}
    m = manifest.write(folder, "run", rels, rels)
    assert set(m.files) == files and set(m.folders) == dirs
