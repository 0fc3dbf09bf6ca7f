"""`pip install .` outside the checkout gives a working qpatrol: maps, configs and the quick
reproduction come with the package.

The wheel is built from a copy of the sources with this interpreter's setuptools
(``--no-build-isolation``: no network) and installed with pip into a fresh venv, whose
dependencies come from this interpreter's site-packages through a ``.pth`` file. The
installed ``qpatrol`` then runs from a folder outside the checkout; every input of the
quick reproduction is read from the installed package.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

#: on one worker under pytest-xdist: the module fixtures are built once
pytestmark = pytest.mark.xdist_group("install")

REPO = Path(__file__).resolve().parent.parent
SOURCES = ("pyproject.toml", "setup.py", "README.md", "qpatrol", "maps", "configs")


def sh(*args: object, cwd: Path, env: dict[str, str], timeout: float = 300):
    res = subprocess.run(
        [str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )
    assert res.returncode == 0, f"{args}: {res.stdout}\n{res.stderr}"
    return res


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    pytest.importorskip("setuptools", minversion="77")
    root = tmp_path_factory.mktemp("install")
    src = root / "src"
    src.mkdir()
    for name in SOURCES:
        p = REPO / name
        if p.is_dir():
            shutil.copytree(p, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(p, src / name)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    pip = [sys.executable, "-m", "pip"]
    sh(
        *pip,
        "wheel",
        "--no-deps",
        "--no-build-isolation",
        "-w",
        root / "dist",
        src,
        cwd=root,
        env=env,
    )
    (wheel,) = (root / "dist").glob("qpatrol-*.whl")

    target = root / "venv"
    venv.create(target, with_pip=False)
    python = target / "bin" / "python"
    site = Path(
        subprocess.run(
            [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    )
    # the dependencies (numpy, pandas, ...) of the interpreter running the tests
    here = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "zz_test_dependencies.pth").write_text("\n".join(sorted(here)) + "\n")
    sh(*pip, "--python", python, "install", "--no-deps", "--no-index", wheel, cwd=root, env=env)
    elsewhere = root / "elsewhere"
    elsewhere.mkdir()
    return target / "bin" / "qpatrol", python, elsewhere, env


def test_installed_package_runs_outside_the_checkout(installed):
    qpatrol, python, cwd, env = installed
    where = sh(python, "-c", "import qpatrol; print(qpatrol.__file__)", cwd=cwd, env=env)
    assert Path(where.stdout.strip()).is_relative_to(python.parent.parent)
    assert sh(qpatrol, "--version", cwd=cwd, env=env).stdout.startswith("qpatrol ")

    listed = sh(qpatrol, "maps", "list", cwd=cwd, env=env).stdout
    for name in ("map_a", "map_b", "pacman", "facility"):
        assert name in listed
    assert "paper" in sh(qpatrol, "config", "list", cwd=cwd, env=env).stdout

    sh(qpatrol, "train", "paper", "--set", "steps=200", "--out", "run", "-q", cwd=cwd, env=env)
    meta = json.loads((cwd / "run" / "meta.json").read_text())
    assert meta["git"] is None and meta["map"]["name"] == "map_a"
    assert (cwd / "run" / "map.txt").read_text() == (REPO / "maps" / "map_a.txt").read_text()


#: Prints, for every point of every experiment of the quick reproduction, the config's
#: digest and the file it and its map were read from, with the map file's bytes' hash.
QUICK_INPUTS = """
import hashlib, json
from qpatrol.study import reproduce as rp
from qpatrol.maps import resolve_map
out = []
for e in rp.EXPERIMENTS:
    base = rp._repo_file(e.config)
    for p in e.points(True):
        cfg = e.base(True).replace(**p.overrides)
        m = resolve_map(cfg["map"])
        out.append([e.name, p.index, cfg.digest(), str(base.resolve()), str(m.resolve()),
                    hashlib.sha256(m.read_bytes()).hexdigest()])
print(json.dumps(out))
"""


def test_installed_quick_reproduction_reads_the_checkouts_inputs(installed):
    """Every config and map of the quick reproduction comes with the installed package
    and is the checkout's: the same config digest for every point and the same map bytes.
    (The quick reproduction itself runs in-process on the checkout and is compared with
    the committed references byte for byte in test_experiments.py; run installed it cost
    minutes, mostly compiling the whole engine again for the installed copy.)"""
    _, python, cwd, env = installed
    got = json.loads(sh(python, "-c", QUICK_INPUTS, cwd=cwd, env=env).stdout)
    here = subprocess.run(
        [sys.executable, "-c", QUICK_INPUTS], cwd=REPO, capture_output=True, text=True, check=True
    )
    want = json.loads(here.stdout)
    assert len(got) == len(want) > 50  # every point of the nine experiments
    site = python.parent.parent.resolve()
    for g, w in zip(got, want, strict=True):
        assert g[:3] == w[:3] and g[5] == w[5], (g, w)  # experiment, point, digest, map bytes
        assert Path(g[3]).is_relative_to(site) and Path(g[4]).is_relative_to(site), g


def test_pyproject_license_is_an_spdx_string():
    """A table (``{text = "MIT"}``) makes setuptools >= 77 warn that it is deprecated."""
    import tomllib

    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT"
    assert "joblib>=1.4" in project["dependencies"]  # return_as="generator_unordered"


def test_the_model_is_documented_in_the_repository():
    model = (REPO / "docs" / "model.md").read_text()
    for title in ("## Maps", "## One agent", "## A team", "## Movement, collisions and charging"):
        assert title in model
    assert "`policy`" in model
    cited = [REPO / "README.md", *sorted((REPO / "qpatrol").glob("*.py"))]
    assert not [p.name for p in cited if "SPEC.md" in p.read_text()]
    assert "docs/model.md" in (REPO / "README.md").read_text()
