"""Reproduce the paper: run every experiment, extract each figure's CSV, draw it, report.

``qpatrol reproduce [--quick] [--out results/]`` calls :func:`reproduce`. Every
experiment is a sweep folder (a single config is a sweep of one point, whose runs
draw from ``SeedSequence(seed, spawn_key=(0, r))`` exactly as ``train`` does), so a
killed reproduction resumes where it stopped. Layout under ``out``::

    runs/<mode>/<experiment>/      raw sweep folders (git-ignored scratch)
    figures/<figure>.png|gif|csv   each figure and the CSV it was drawn from (full run)
    reference/quick/*.csv          the quick run's figure CSVs and sweep results, which
                                   the test suite recomputes and compares byte for byte
    REPORT.md                      each paper claim beside our figure and numbers
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from qpatrol import atomic
from qpatrol.config import Config, load_config
from qpatrol.records import to_csv_text
from qpatrol.sweep import NAMED_SWEEPS, Point, run_sweep

REPO = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Experiment:
    """One experiment: a config, optionally swept, with overrides for the quick mode.

    Attributes:
        name: folder name under ``runs/<mode>/``.
        config: config path relative to the repository root.
        sweep: a named sweep (``qpatrol sweep NAME``) or None for the config alone.
        quick: ``KEY=VALUE`` overrides that make ``--quick`` fast.
        cost: rough relative run time, to start the longest first.
    """

    name: str
    config: str
    sweep: str | None = None
    quick: tuple[str, ...] = ()
    cost: float = 1.0

    def base(self, quick: bool) -> Config:
        """The experiment's config, with the quick overrides when asked."""
        return load_config(_repo_file(self.config), list(self.quick) if quick else [])

    def points(self) -> list[Point]:
        """The sweep's points, or one point without overrides."""
        return NAMED_SWEEPS[self.sweep].points() if self.sweep else [Point(0, {})]


EXPERIMENTS: tuple[Experiment, ...] = (
    Experiment("team", "configs/figure6.yaml", None, ("runs=1", "episodes=25"), cost=10),
    Experiment(
        "team-size",
        "configs/team_size.yaml",
        "team-size",
        ("runs=2", "steps=1500", "record.warmup=500"),
        cost=3,
    ),
    Experiment(
        "gamma",
        "configs/gamma.yaml",
        "gamma",
        ("runs=3", "steps=4000", "max_episode_steps=4000"),
        cost=2,
    ),
    Experiment("multiplier", "configs/multiplier.yaml", "multiplier", ("runs=1", "steps=2500")),
    Experiment("figure-3", "configs/figure3.yaml", None, ("runs=1", "steps=3000")),
    Experiment("figure-4", "configs/figure4.yaml", None, ("runs=1", "steps=2500")),
)
BY_NAME = {e.name: e for e in EXPERIMENTS}


def _repo_file(relative: str) -> Path:
    here = Path(relative)
    return here if here.exists() else REPO / relative


def experiment_dir(out: Path, name: str, quick: bool) -> Path:
    """Where an experiment's sweep folder lives."""
    return Path(out) / "runs" / ("quick" if quick else "full") / name


def run_experiment(exp: Experiment, out: Path, quick: bool) -> tuple[str, float, list[str]]:
    """Run (or resume) one experiment; returns (name, seconds, failed point ids)."""
    start = time.monotonic()
    res = run_sweep(exp.base(quick), exp.points(), experiment_dir(out, exp.name, quick), jobs=1)
    return exp.name, time.monotonic() - start, res.failed


def run_all(
    out: Path, quick: bool, jobs: int = 2, log: Callable[[str], None] = print
) -> dict[str, float]:
    """Run every experiment, the costliest first, ``jobs`` at a time; seconds per experiment."""
    from joblib import Parallel, delayed

    todo = sorted(EXPERIMENTS, key=lambda e: -e.cost)
    seconds: dict[str, float] = {}
    failed: list[str] = []
    tasks = (delayed(run_experiment)(e, out, quick) for e in todo)
    runner = Parallel(n_jobs=min(jobs, len(todo)), return_as="generator_unordered")
    for i, (name, secs, bad) in enumerate(runner(tasks), start=1):
        seconds[name] = secs
        failed += [f"{name}/{p}" for p in bad]
        log(f"[{i}/{len(todo)}] {name}: {secs:.1f} s" + (f", FAILED {bad}" if bad else ""))
    if failed:
        raise RuntimeError(f"experiment points failed: {', '.join(failed)}")
    return seconds


def write_csv(df: pd.DataFrame, path: Path) -> Path:
    """A figure CSV, atomically, in the fixed float format."""
    atomic.write_text(path, to_csv_text(df))
    return path


def copy_tree_files(src: Path, dst: Path, pattern: str = "*.csv") -> None:
    """Copy matching files of ``src`` to ``dst`` (atomically per file)."""
    for f in sorted(src.glob(pattern)):
        atomic.write_bytes(dst / f.name, f.read_bytes())


@dataclass(frozen=True)
class Figure:
    """A figure: the experiment it comes from, how to tabulate it, how to draw it.

    Attributes:
        name: ``qpatrol plot NAME``.
        experiment: the :class:`Experiment` whose folder it reads.
        data: folder -> the figure's table (a sweep folder, or a run folder when
            ``per_run``).
        draw: (csv path, image path) -> drawn files.
        per_run: ``data`` wants the run folder of the experiment's single point.
        ext: default image extension.
    """

    name: str
    experiment: str
    data: Callable[[Path], pd.DataFrame]
    draw: Callable[[Path, Path], object]
    per_run: bool = False
    ext: str = ".png"


def _figures() -> dict[str, Figure]:
    from qpatrol import figures as fd
    from qpatrol import plots

    return {
        f.name: f
        for f in (
            Figure("figure-2", "multiplier", fd.figure2_data, plots.figure_2),
            Figure(
                "figure-3",
                "figure-3",
                lambda d: fd.figure34_data(d, 13),
                plots.figure_3,
                per_run=True,
            ),
            Figure(
                "figure-4",
                "figure-4",
                lambda d: fd.figure34_data(d, 34),
                plots.figure_4,
                per_run=True,
            ),
            Figure("gamma", "gamma", fd.gamma_data, plots.gamma),
            Figure("figure-5", "team", fd.figure5_data, plots.figure_5, per_run=True, ext=".gif"),
            Figure("figure-6", "team", fd.figure6_data, plots.figure_6, per_run=True),
            Figure("team-size", "team-size", fd.team_size_data, plots.team_size),
        )
    }


FIGURE_NAMES = ("figure-2", "figure-3", "figure-4", "gamma", "figure-5", "figure-6", "team-size")


def figure(name: str) -> Figure:
    """The :class:`Figure` called ``name``; a ConfigError lists the known ones."""
    figs = _figures()
    if name not in figs:
        from qpatrol.config import ConfigError

        raise ConfigError(f"unknown figure {name!r}; known: {', '.join(FIGURE_NAMES)}")
    return figs[name]


def source_folder(fig: Figure, folder: Path) -> Path:
    """The folder ``fig.data`` reads: a run folder inside a one-point sweep if needed."""
    folder = Path(folder)
    if fig.per_run and (folder / "sweep.json").exists():
        points = sorted(p for p in (folder / "points").iterdir() if p.is_dir())
        if not points:
            raise FileNotFoundError(f"{folder}: no finished point to plot")
        return points[0]
    return folder


def make_figure(name: str, folder: Path, image: Path, draw: bool = True) -> list[Path]:
    """Tabulate ``folder`` into ``image``'s CSV (same stem, ``.csv``), then draw it
    (unless ``draw`` is off). Returns the files written."""
    fig = figure(name)
    table = fig.data(source_folder(fig, folder))
    csv = write_csv(table, Path(image).with_suffix(".csv"))
    if not draw:
        return [csv]
    drawn = fig.draw(csv, Path(image))
    files = list(drawn) if isinstance(drawn, tuple | list) else [Path(drawn)]
    return [csv, *files]


def reproduce(
    out: Path = Path("results"),
    quick: bool = False,
    jobs: int = 2,
    draw: bool = True,
    update_references: bool = False,
    log: Callable[[str], None] = print,
) -> Path:
    """Run every experiment, tabulate and draw every figure, write REPORT.md.

    Full mode writes ``out/figures``, ``out/data`` and ``out/REPORT.md`` (the committed
    reference results). Quick mode writes the same under ``out/quick/`` and, with
    ``update_references``, copies its CSVs to ``out/reference/quick/``, which the test
    suite compares byte for byte with a fresh quick run. Returns the report's path (or
    the quick folder when ``draw`` is off).
    """
    out = Path(out)
    start = time.monotonic()
    seconds = run_all(out, quick, jobs, log)
    home = out / "quick" if quick else out
    figs, data = home / "figures", home / "data"
    for exp in EXPERIMENTS:
        src = experiment_dir(out, exp.name, quick) / "results.csv"
        atomic.write_bytes(data / f"{exp.name}-results.csv", src.read_bytes())
    for name in FIGURE_NAMES:
        fig = figure(name)
        folder = experiment_dir(out, fig.experiment, quick)
        made = make_figure(name, folder, figs / f"{name}{fig.ext}", draw=draw)
        if draw:
            log(f"figure {name}: {', '.join(str(p) for p in made)}")
    if update_references:
        if not quick:
            raise ValueError("update_references applies to the quick mode")
        ref = out / "reference" / "quick"
        for sub in ("figures", "data"):
            shutil.rmtree(ref / sub, ignore_errors=True)
            copy_tree_files(home / sub, ref / sub)
        log(f"updated the quick references in {ref}")
    if not draw:
        return home
    from qpatrol import report

    path = report.write(home, "quick" if quick else "full", seconds, time.monotonic() - start)
    log(f"wrote {path}")
    return path


def compare_with_references(out: Path, references: Path) -> list[str]:
    """Names of the CSVs of a quick run (``out/quick``) that differ from the references."""
    diffs = []
    for ref in sorted(references.glob("*/*.csv")):
        new = out / "quick" / ref.parent.name / ref.name
        if not new.exists() or new.read_bytes() != ref.read_bytes():
            diffs.append(f"{ref.parent.name}/{ref.name}")
    return diffs


__all__ = ["EXPERIMENTS", "FIGURE_NAMES", "Experiment", "reproduce", "run_all"]
