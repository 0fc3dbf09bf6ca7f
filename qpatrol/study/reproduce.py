"""Reproduce the paper: run every experiment, extract each figure's CSV, draw it, report.

``qpatrol reproduce [--quick] [--out DIR]`` calls :func:`reproduce`. Every
experiment is a sweep folder (a single config is a sweep of one point, whose runs
draw from ``SeedSequence(seed, spawn_key=(0, r))`` exactly as ``train`` does), so a
killed reproduction resumes where it stopped. Layout under ``out`` (``results/`` for
the full mode, ``results/quick/`` for the quick one, by default)::

    runs/<mode>/<experiment>/      raw sweep folders (git-ignored scratch)
    figures/<figure>.png|gif|csv   each figure and the CSV it was drawn from
    data/<experiment>-results.csv  each experiment's per-run measures
    REPORT.md                      each paper claim beside our figure and numbers
    meta.json                      what made it (qpatrol.util.provenance)

``results/reference/quick/`` holds the quick run's CSVs, which the test suite
recomputes and compares byte for byte (``--update-references`` rewrites them).
"""

from __future__ import annotations

import csv
import io
import json
import threading
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import pandas as pd

from qpatrol import __version__
from qpatrol.config import Config, ConfigError, find_config, load_config
from qpatrol.measures.records import to_csv_text
from qpatrol.run import outputs
from qpatrol.study.sweep import NAMED_SWEEPS, Point, progress_of, run_sweep, run_sweeps
from qpatrol.util import atomic, manifest, provenance
from qpatrol.world import limits

REPO = Path(__file__).resolve().parents[2]
#: Where the quick references live, relative to the folder qpatrol is run from.
REFERENCES = Path("results") / "reference" / "quick"


@dataclass(frozen=True)
class Experiment:
    """One experiment: a config, optionally swept, with overrides for the quick mode.

    Attributes:
        name: folder name under ``runs/<mode>/``.
        config: config path relative to the repository root.
        sweep: a named sweep (``qpatrol sweep NAME``) or None for the config alone.
        quick: ``KEY=VALUE`` overrides that make ``--quick`` fast.
    """

    name: str
    config: str
    sweep: str | None = None
    quick: tuple[str, ...] = ()

    def base(self, quick: bool) -> Config:
        """The experiment's config, with the quick overrides when asked."""
        return load_config(_repo_file(self.config), list(self.quick) if quick else [])

    def points(self, quick: bool = False) -> list[Point]:
        """The sweep's points, or one point without overrides."""
        return NAMED_SWEEPS[self.sweep].points(quick) if self.sweep else [Point(0, {})]

    def runs(self, quick: bool) -> int:
        """Runs over all points."""
        base = self.base(quick)
        return sum(base.replace(**p.overrides)["runs"] for p in self.points(quick))


EXPERIMENTS: tuple[Experiment, ...] = (
    Experiment("team", "configs/figure6.yaml", None, ("runs=1", "episodes=25")),
    Experiment(
        "team-size",
        "configs/team_size.yaml",
        "team-size",
        ("runs=2", "steps=1500", "record.warmup=500"),
    ),
    Experiment(
        "gamma",
        "configs/gamma.yaml",
        "gamma",
        ("runs=3", "steps=4000", "max_episode_steps=4000"),
    ),
    Experiment(
        "strategies",
        "configs/strategies.yaml",
        "strategies",
        ("runs=2", "steps=1500", "record.warmup=500"),
    ),
    Experiment("policies", "configs/policies.yaml", "policies", ("runs=2",)),
    Experiment("learning", "configs/learning.yaml", "learning", ("record.timeline=1000",)),
    Experiment("field", "configs/field.yaml", "field", ("runs=2",)),
    Experiment("security", "configs/security.yaml", "security", ("runs=2",)),
    Experiment("multiplier", "configs/multiplier.yaml", "multiplier", ("runs=1", "steps=2500")),
    Experiment("figure-3", "configs/figure3.yaml", None, ("runs=1", "steps=3000")),
    Experiment("figure-4", "configs/figure4.yaml", None, ("runs=1", "steps=2500")),
)
BY_NAME = {e.name: e for e in EXPERIMENTS}


def _repo_file(relative: str) -> Path:
    return find_config(relative)


def default_out(quick: bool) -> Path:
    """``results`` (full mode) or ``results/quick``."""
    return Path("results") / "quick" if quick else Path("results")


def experiment_dir(out: Path, name: str, quick: bool) -> Path:
    """Where an experiment's sweep folder lives."""
    return Path(out) / "runs" / ("quick" if quick else "full") / name


def run_experiment(exp: Experiment, out: Path, quick: bool) -> tuple[str, float, list[str]]:
    """Run (or resume) one experiment alone; returns (name, seconds, failed point ids)."""
    start = time.monotonic()
    res = run_sweep(
        exp.base(quick), exp.points(quick), experiment_dir(out, exp.name, quick), jobs=1
    )
    return exp.name, time.monotonic() - start, res.failed


def point_seconds(folder: Path) -> float:
    """Seconds the points of an experiment folder took, summed (from each point's
    ``meta.json`` start and end); 0 for points computed by an older qpatrol."""
    total = 0.0
    for meta in sorted(Path(folder).glob("points/*/meta.json")):
        info = provenance.read_meta(meta.parent) or {}
        try:
            started = datetime.fromisoformat(str(info["started"]))
            ended = datetime.fromisoformat(str(info["ended"]))
        except (KeyError, TypeError, ValueError):
            continue
        total += (ended - started).total_seconds()
    return total


def nested(out: Path) -> list[str]:
    """Folders inside a results folder that qpatrol writes with manifests of their own:
    the experiments' sweep folders (both modes), ``figures``, the quick references
    (``reference/quick``) and a quick results folder inside a full one (``quick``)."""
    out = Path(out)
    found = []
    kinds = {
        **{f"runs/{mode}/{e.name}": "sweep" for mode in ("full", "quick") for e in EXPERIMENTS},
        "figures": "figures",
        "reference/quick": "references",
        "quick": "reproduction",
    }
    for rel, kind in kinds.items():
        d = out / rel
        if d.is_dir() and not d.is_symlink():
            try:
                m = manifest.read(d)
            except manifest.ManifestError:
                continue
            if m is not None and m.kind == kind:
                found.append(rel)
    return found


def check_target(out: Path, force: bool, label: str = "--out") -> None:
    """Check a results folder before any work: new or empty, or one qpatrol wrote that
    holds nothing else. Without ``force`` it must also be of this qpatrol's version, its
    report, data and figures as qpatrol wrote them (the experiments' points are checked
    by their sweeps, :func:`qpatrol.study.sweep.run_sweeps`).

    Raises:
        OutputError: one line naming the file or the difference.
    """
    out = Path(out)
    outputs.check_out_path(out, label)
    if outputs.is_fresh(out):
        outputs.check_writable_dir(out, label, inside=out.exists())
        return
    hint = (
        "reproduce writes only into a new or empty folder or a results folder of its own; "
        f"choose another {label}"
    )
    kinds = ("reproduction",)
    m = outputs.check_replaceable(out, kinds, label, "results folder", nested(out), hint)
    outputs.check_writable_dir(out, label, inside=True)
    if force:
        return
    again = f"pass --force to compute it anew, or choose another {label}"
    if m.qpatrol != __version__:
        raise outputs.OutputError(
            f"{label} {out}: written by qpatrol {m.qpatrol}, this is {__version__}; {again}"
        )
    try:
        bad = [b for b in manifest.changed(out, 100, nested=False) if (out / b).exists()]
        if not bad and (out / "figures").is_dir():
            bad = [f"figures/{f}" for f in manifest.changed(out / "figures", 100)]
            bad = [b for b in bad if (out / b).exists()]
    except manifest.ManifestError as e:
        raise outputs.OutputError(f"{label} {out}: {e}; {again}") from None
    if bad:
        raise outputs.OutputError(
            f"{label} {out}: {bad[0]} changed since qpatrol wrote it; {again}"
        )


def run_all(
    out: Path,
    quick: bool,
    jobs: int = 2,
    log: Callable[[str], None] = print,
    progress: Callable[[float, float], None] | None = None,
    force: bool = False,
) -> tuple[dict[str, float], list[str]]:
    """Run every experiment's points in one pool of ``jobs`` workers, the costliest
    first; returns each experiment's summed point run time in seconds (point times are
    whole seconds, from each point's ``meta.json``), and the names of the experiments
    resumed whole (computed by an earlier run).

    ``progress(runs_done, runs_total)`` is called about twice a second, counting the runs
    of every experiment (those of running points by their share of steps done).
    """
    limits.check_jobs(jobs)
    total = sum(e.runs(quick) for e in EXPERIMENTS)
    stop = threading.Event()

    def runs_done() -> float:
        return sum(progress_of(experiment_dir(out, e.name, quick))[0] for e in EXPERIMENTS)

    def poll() -> None:
        shown = -1.0
        while True:
            done = runs_done()
            if done > shown:
                shown = done
                progress(done, total)
            if stop.wait(0.5):
                return

    watcher = threading.Thread(target=poll, daemon=True) if progress is not None else None
    if watcher is not None:
        watcher.start()
    sweeps = [
        (e.base(quick), e.points(quick), experiment_dir(out, e.name, quick)) for e in EXPERIMENTS
    ]
    try:
        results = run_sweeps(sweeps, jobs=jobs, meta=provenance.collect(), force=force)
    finally:
        stop.set()
        if watcher is not None:
            watcher.join()
    if progress is not None:
        progress(total, total)
    failed: list[str] = []
    seconds: dict[str, float] = {}
    resumed: list[str] = []
    for i, (exp, res) in enumerate(zip(EXPERIMENTS, results, strict=True), start=1):
        failed += [f"{exp.name}/{p}" for p in res.failed]
        secs = point_seconds(res.out)
        seconds[exp.name] = secs
        if not res.done:
            resumed.append(exp.name)
        ran = f"{len(res.done)} points run" + (
            f", {len(res.skipped)} resumed" if res.skipped else ""
        )
        log(
            f"[{i}/{len(EXPERIMENTS)}] {exp.name}: {ran}"
            + (f", {secs:.0f} s" if res.done else "")
            + (f", FAILED {res.failed}" if res.failed else "")
        )
    if failed:
        raise RuntimeError(f"experiment points failed: {', '.join(failed)}")
    return seconds, resumed


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
        sweep_key: for a figure drawn from a sweep, the key it must sweep.
        wants_map: ``draw`` takes the map (``map=``), read from the run folder.
    """

    name: str
    experiment: str
    data: Callable[[Path], pd.DataFrame]
    draw: Callable[..., object]
    per_run: bool = False
    ext: str = ".png"
    sweep_key: str | None = None
    wants_map: bool = False

    def files(self, image: Path) -> list[Path]:
        """The files drawing to ``image`` writes: its CSV, the image (and, for an
        animation, its still ``.png``)."""
        image = Path(image)
        if self.ext == ".gif":
            return [image.with_suffix(".csv"), image.with_suffix(".gif"), image.with_suffix(".png")]
        return [image.with_suffix(".csv"), image if image.suffix else image.with_suffix(".png")]


def _figures() -> dict[str, Figure]:
    from qpatrol.study import figures as fd
    from qpatrol.study import plots

    return {
        f.name: f
        for f in (
            Figure(
                "figure-2",
                "multiplier",
                fd.figure2_data,
                plots.figure_2,
                sweep_key="learning.multiplier",
            ),
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
            Figure("gamma", "gamma", fd.gamma_data, plots.gamma, sweep_key="learning.gamma"),
            Figure(
                "figure-5",
                "team",
                fd.figure5_data,
                plots.figure_5,
                per_run=True,
                ext=".gif",
                wants_map=True,
            ),
            Figure("figure-6", "team", fd.figure6_data, plots.figure_6, per_run=True),
            Figure(
                "team-size", "team-size", fd.team_size_data, plots.team_size, sweep_key="agents"
            ),
            Figure(
                "strategies",
                "strategies",
                fd.strategies_data,
                plots.strategies,
                sweep_key="policy",
            ),
            Figure("policies", "policies", fd.policies_data, plots.policies, sweep_key="policy"),
            Figure("learning", "learning", fd.learning_data, plots.learning, sweep_key="policy"),
            Figure("field", "field", fd.field_data, plots.field, sweep_key="policy"),
            Figure(
                "field-models",
                "field",
                fd.field_models_data,
                plots.field_models,
                sweep_key="policy",
            ),  # fmt: skip
            Figure("security", "security", fd.security_data, plots.security, sweep_key="policy"),
            Figure(
                "security-failures",
                "security",
                fd.security_failures_data,
                plots.security_failures,
                sweep_key="policy",
            ),
            Figure(
                "security-recovery",
                "security",
                fd.security_recovery_data,
                plots.security_recovery,
                sweep_key="policy",
            ),
            # the neural policy's study: `qpatrol sweep neural`, not part of reproduce
            Figure("neural", "neural", fd.neural_data, plots.neural, sweep_key="policy"),
        )
    }


FIGURE_NAMES = (
    "figure-2",
    "figure-3",
    "figure-4",
    "gamma",
    "figure-5",
    "figure-6",
    "team-size",
    "strategies",
    "policies",
    "learning",
    "field",
    "field-models",
    "security",
    "security-failures",
    "security-recovery",
)


def figure(name: str) -> Figure:
    """The :class:`Figure` called ``name``; a ConfigError lists the known ones."""
    figs = _figures()
    if name not in figs:
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


def _swept_keys(spec: dict[str, Any]) -> list[str]:
    keys: list[str] = []
    for pt in spec.get("points", []):
        keys += [k for k in (pt.get("overrides") or {}) if k not in keys]
    return keys


def describe_folder(folder: Path) -> str:
    """What an experiment folder holds, in a few words (for error messages)."""
    d = Path(folder)
    if (d / "sweep.json").is_file():
        try:
            spec = json.loads((d / "sweep.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return "an unreadable sweep.json"
        points = spec.get("points") or []
        done = sum((d / "points" / str(p.get("id"))).is_dir() for p in points)
        keys = _swept_keys(spec)
        over = f" over {', '.join(keys)}" if keys else ""
        return f"a sweep of {len(points)} point{'s' * (len(points) != 1)}{over} ({done} finished)"
    if (d / "config.yaml").is_file():
        try:
            cfg = load_config(d / "config.yaml")
        except ConfigError:
            return "a run folder with an unreadable config.yaml"
        return f"a run folder ({cfg['agents']} agents on {cfg['map']}, {cfg['runs']} runs)"
    return "no qpatrol experiment (neither sweep.json nor config.yaml)"


def check_source(fig: Figure, folder: Path) -> None:
    """Raise :class:`ConfigError` (one line naming what was found) unless ``folder`` holds
    what ``fig`` is drawn from: a finished sweep over its key, or a run folder (or a
    one-point sweep) for a per-run figure."""
    d = Path(folder)
    found = describe_folder(d)
    sweep = (d / "sweep.json").is_file()
    if fig.per_run:
        if sweep:
            spec = json.loads((d / "sweep.json").read_text(encoding="utf-8"))
            if len(spec.get("points") or []) != 1:
                raise ConfigError(
                    f"{fig.name} needs a run folder or a one-point sweep; {d} holds {found}"
                )
        elif not (d / "config.yaml").is_file():
            raise ConfigError(f"{fig.name} needs a run folder; {d} holds {found}")
        return
    if not sweep:
        raise ConfigError(f"{fig.name} needs a sweep over {fig.sweep_key}; {d} holds {found}")
    spec = json.loads((d / "sweep.json").read_text(encoding="utf-8"))
    if fig.sweep_key and fig.sweep_key not in _swept_keys(spec):
        raise ConfigError(f"{fig.name} needs a sweep over {fig.sweep_key}; {d} holds {found}")
    if not any((d / "points" / str(p.get("id"))).is_dir() for p in spec.get("points") or []):
        raise ConfigError(f"{fig.name}: {d} holds {found}; run the sweep first")


def make_figure(
    name: str,
    folder: Path,
    image: Path,
    draw: bool = True,
    check: Callable[[list[Path], str], None] | None = None,
) -> list[Path]:
    """Tabulate ``folder`` into ``image``'s CSV (same stem, ``.csv``), then draw it
    (unless ``draw`` is off). Returns the files written. ``check(files, csv_text)`` is
    called before anything is written, with the files drawing will write
    (:meth:`Figure.files`) and the CSV's text; it raises to write nothing."""
    from qpatrol.study.figures import folder_map

    fig = figure(name)
    source = source_folder(fig, folder)
    table = fig.data(source)
    text = to_csv_text(table)
    if check is not None:
        check(fig.files(Path(image)) if draw else [Path(image).with_suffix(".csv")], text)
    csv = Path(image).with_suffix(".csv")
    atomic.write_text(csv, text)
    if not draw:
        return [csv]
    if fig.wants_map:
        drawn = fig.draw(csv, Path(image), map=folder_map(source))
    else:
        drawn = fig.draw(csv, Path(image))
    files = list(drawn) if isinstance(drawn, tuple | list) else [Path(drawn)]
    return [csv, *files]


#: Figures that take longest to make, made first when figures are made in parallel
#: (the animated GIF of Fig. 5, and the reference tour of the gamma figure).
SLOW_FIGURES = ("figure-5", "gamma")


def make_figures(
    out: Path, quick: bool, figs: Path, draw: bool, jobs: int
) -> list[tuple[str, list[Path]]]:
    """Every figure of :data:`FIGURE_NAMES` from the experiments in ``out``, into
    ``figs``: ``(name, files written)`` in that order. With ``jobs`` > 1 the figures
    are made by that many worker processes, the slowest first (each writes its own
    files, atomically)."""
    tasks = []
    for name in FIGURE_NAMES:
        fig = figure(name)
        folder = experiment_dir(out, fig.experiment, quick)
        tasks.append((name, folder, figs / f"{name}{fig.ext}"))
    from joblib import Parallel, delayed, effective_n_jobs

    n = min(effective_n_jobs(jobs), len(tasks))
    if n <= 1 or not draw:
        return [(name, make_figure(name, folder, img, draw=draw)) for name, folder, img in tasks]
    order = sorted(tasks, key=lambda t: t[0] not in SLOW_FIGURES)
    with warnings.catch_warnings():
        # The sweeps' workers are reused; loky replaces one whose memory grew (numba's
        # compiled code, cached walks) between two tasks and warns, though no task is
        # lost: every figure returns the files it wrote.
        warnings.filterwarnings("ignore", "A worker stopped while some jobs", UserWarning)
        made = Parallel(n_jobs=n, backend="loky")(
            delayed(make_figure)(name, folder, img, draw) for name, folder, img in order
        )
    by_name = {t[0]: files for t, files in zip(order, made, strict=True)}
    return [(name, by_name[name]) for name, _, _ in tasks]


def without_point_ids(results_csv: Path) -> str:
    """A sweep's ``results.csv`` as the committed ``data/<experiment>-results.csv``: every
    cell as written, but the ``point_id`` column (the point's folder name, which repeats
    its swept keys: a quarter of the field study's 5 MB)."""
    rows = list(csv.reader(io.StringIO(results_csv.read_text(encoding="utf-8"), newline="")))
    drop = rows[0].index("point_id") if rows and "point_id" in rows[0] else -1
    buf = io.StringIO(newline="")
    writer = csv.writer(buf, lineterminator="\n")
    for row in rows:
        writer.writerow(row[:drop] + row[drop + 1 :] if drop >= 0 else row)
    return buf.getvalue()


def reproduce(
    out: Path | None = None,
    quick: bool = False,
    jobs: int = 2,
    draw: bool = True,
    update_references: bool = False,
    log: Callable[[str], None] = print,
    progress: Callable[[float, float], None] | None = None,
    references: Path | None = None,
    force: bool = False,
) -> Path:
    """Run every experiment, tabulate and draw every figure, write REPORT.md.

    Writes ``out/figures``, ``out/data``, ``out/REPORT.md`` and ``out/meta.json``
    (``out`` defaults to ``results`` in full mode, ``results/quick`` in quick mode). In
    quick mode the report marks every verdict as indicative, and ``update_references``
    copies its CSVs to ``references`` (default ``results/reference/quick``), which the
    test suite compares byte for byte with a fresh quick run. Returns the report's path
    (or ``out`` when ``draw`` is off).

    ``out`` must be new or empty, or a results folder qpatrol wrote holding nothing else
    (:func:`check_target`); its ``manifest.json`` lists what it wrote. Finished points
    are reused only when they are what this qpatrol would write now; otherwise, and when
    ``out`` is of another version or a file of it changed, a ConfigError names the
    difference and ``force`` starts over (removing only what the manifest lists).
    """
    out = Path(out) if out is not None else default_out(quick)
    if update_references and not quick:
        raise ValueError("update_references applies to the quick mode")
    ref = Path(references) if references is not None else REFERENCES
    check_target(out, force)
    if update_references:
        check_references(ref)
    started = provenance.now()
    start = time.monotonic()
    if force and not outputs.is_fresh(out):
        manifest.remove(out)  # what the manifest lists; nested folders of its own stay
    out.mkdir(parents=True, exist_ok=True)
    if manifest.read(out) is None:  # a manifest from the start: a killed run is resumable
        manifest.write(out, "reproduction", [], [], None)
    seconds, resumed = run_all(out, quick, jobs, log, progress, force)
    home = out
    figs, data = home / "figures", home / "data"
    written = []
    for exp in EXPERIMENTS:
        src = experiment_dir(out, exp.name, quick) / "results.csv"
        atomic.write_text(data / f"{exp.name}-results.csv", without_point_ids(src))
        written.append(f"data/{exp.name}-results.csv")
    fresh_figs = outputs.is_fresh(figs)
    made_figs: list[str] = []
    for name, made in make_figures(out, quick, figs, draw, jobs):
        made_figs += [Path(p).name for p in made]
        if draw:
            log(f"figure {name}: {', '.join(str(p) for p in made)}")
    outputs.record_files(figs, made_figs, fresh=fresh_figs or force)
    if update_references:
        _write_references(home, ref)
        log(f"updated the quick references in {ref}")
    meta = provenance.collect(started=started, mode="quick" if quick else "full", jobs=jobs)
    atomic.write_text(home / provenance.META_FILE, provenance.meta_text(meta))
    path = home
    if draw:
        from qpatrol.study import report

        path = report.write(
            home, "quick" if quick else "full", seconds, time.monotonic() - start, resumed
        )
        written.append(path.name)
        log(f"wrote {path}")
    mode = "quick" if quick else "full"
    folders = ["figures", *(f"runs/{mode}/{e.name}" for e in EXPERIMENTS)]
    manifest.add(out, "reproduction", written, folders, provenance=[provenance.META_FILE])
    return path


def check_references(ref: Path) -> None:
    """Check the references folder ``--update-references`` rewrites: new or empty, or a
    references folder qpatrol wrote holding nothing else."""
    outputs.check_out_path(ref, "--update-references")
    if not outputs.is_fresh(ref):
        outputs.check_replaceable(ref, ("references",), "--update-references", "references folder")
    outputs.check_writable_dir(ref, "--update-references", inside=ref.exists())


def _write_references(home: Path, ref: Path) -> None:
    """Copy the quick run's figure and data CSVs to ``ref``, replacing only what qpatrol
    wrote there, and give it its manifest."""
    check_references(ref)
    if not outputs.is_fresh(ref):
        manifest.remove(ref)
    for sub in ("figures", "data"):
        copy_tree_files(home / sub, ref / sub)
    manifest.seal(ref, "references")


def compare_with_references(
    out: Path, references: Path, new_columns: Sequence[str] = ()
) -> list[str]:
    """Names of the CSVs of a quick run written to ``out`` that differ from the references.

    A CSV equals its reference byte for byte; or, if it has some of ``new_columns`` that
    the reference lacks (measures added since the references were made), every other
    column of it must be the reference's, cell for cell as text, in the same rows."""
    diffs = []
    for ref in sorted(references.glob("*/*.csv")):
        new = out / ref.parent.name / ref.name
        if not new.exists():
            diffs.append(f"{ref.parent.name}/{ref.name}")
            continue
        old_text, new_text = ref.read_bytes(), new.read_bytes()
        if old_text != new_text and not (
            new_columns and _same_but_new_columns(old_text, new_text, set(new_columns))
        ):
            diffs.append(f"{ref.parent.name}/{ref.name}")
    return diffs


def _same_but_new_columns(old: bytes, new: bytes, allowed: set[str]) -> bool:
    """True if CSV ``new`` is CSV ``old`` with columns of ``allowed`` added: the same rows,
    every column of ``old`` present with the same text in every cell."""
    old_rows = list(csv.reader(io.StringIO(old.decode("utf-8"))))
    new_rows = list(csv.reader(io.StringIO(new.decode("utf-8"))))
    if not old_rows or len(old_rows) != len(new_rows):
        return False
    old_head, new_head = old_rows[0], new_rows[0]
    if not set(old_head) <= set(new_head) or set(new_head) - set(old_head) - allowed:
        return False
    at = [new_head.index(c) for c in old_head]
    return all(
        [row[i] for i in at] == want for want, row in zip(old_rows[1:], new_rows[1:], strict=True)
    )


__all__ = ["EXPERIMENTS", "FIGURE_NAMES", "Experiment", "reproduce", "run_all"]
