"""``qpatrol`` command line: a thin layer over the Python API.

Bad input (config, map, file, option) ends with one line on stderr and exit code 2,
before any work starts and with nothing written. An interrupted command says so and
exits 130. Anything unexpected ends with one line naming the file that holds the full
traceback, and exit code 1: no command prints a traceback.
"""

from __future__ import annotations

import importlib
import inspect
import json
import os
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Annotated, Any

import typer
from typer.core import TyperCommand, TyperGroup

from qpatrol import __version__
from qpatrol import config as config_mod
from qpatrol.config import ConfigError
from qpatrol.maps import MapError, available_maps, load_map, parse_map, render_states, resolve_map
from qpatrol.maps.graph import graph_summary
from qpatrol.run import outputs
from qpatrol.util import provenance
from qpatrol.util.progress import Bar

HELP = {"help_option_names": ["-h", "--help"]}
#: click's exceptions, wherever this typer takes click from (newer typers vendor it).
_click_exc = importlib.import_module(typer.BadParameter.__module__)


def _usage_pieces(cmd: Any, ctx: Any) -> list[str]:
    """Usage line pieces: ``[OPTIONS] CONFIG`` (arguments by their metavar, optional
    ones in brackets), instead of typer's ``{config}``."""
    pieces = [cmd.options_metavar] if cmd.options_metavar else []
    for param in cmd.get_params(ctx):
        if getattr(param, "param_type_name", "") == "argument":
            if param.metavar:
                pieces.append(param.metavar)
                continue
            name = (param.name or "arg").upper() + ("..." if param.nargs != 1 else "")
            pieces.append(name if param.required else f"[{name}]")
        else:
            pieces.extend(param.get_usage_pieces(ctx))
    return pieces


def _quiet_help_option(opt: Any) -> Any:
    if opt is not None and getattr(opt, "metavar", None) is None:
        opt.metavar = ""  # a flag: no <bool> in the help
    return opt


class _Command(TyperCommand):
    def collect_usage_pieces(self, ctx: Any) -> list[str]:
        return _usage_pieces(self, ctx)

    def get_help_option(self, ctx: Any) -> Any:
        return _quiet_help_option(super().get_help_option(ctx))


class _Group(TyperGroup):
    def collect_usage_pieces(self, ctx: Any) -> list[str]:
        return [*_usage_pieces(self, ctx), self.subcommand_metavar or "COMMAND [ARGS]..."]

    def get_help_option(self, ctx: Any) -> Any:
        return _quiet_help_option(super().get_help_option(ctx))


def _typer(help: str) -> typer.Typer:
    return typer.Typer(
        help=help,
        no_args_is_help=True,
        add_completion=False,
        pretty_exceptions_enable=False,
        context_settings=HELP,
        cls=_Group,
    )


app = _typer("Learned multi-robot patrolling: Q-learning teams on Pac-Man-like mazes.")
maps_app = _typer("List, show, check and import maps.")
config_app = _typer("Config keys, shipped configs and resolved configs.")
app.add_typer(maps_app, name="maps")
app.add_typer(config_app, name="config")


def _examples(*lines: str) -> str:
    return "Examples:\n\n" + "\n\n".join(f"  {x}" for x in lines)


def command(name: str | None = None, examples: tuple[str, ...] = ()) -> Any:
    """``@app.command`` with -h, our usage line and an examples epilog."""
    return {"name": name, "cls": _Command, "epilog": _examples(*examples) if examples else None}


SetOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--set",
        "-s",
        metavar="KEY=VALUE",
        help="Override a config key, e.g. --set learning.gamma=0.5 (repeatable).",
    ),
]
QuietOpt = Annotated[
    bool, typer.Option("--quiet", "-q", metavar="", help="No progress and no summary.")
]


_said: list[str] = []  # the one-line messages `fail` printed in this invocation


def fail(message: str, code: int = 2) -> None:
    """Print one line to stderr and exit."""
    _said.append(message)
    typer.echo(f"qpatrol: error: {message}", err=True)
    raise typer.Exit(code)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"qpatrol {__version__}")
        raise typer.Exit(0)


@app.callback()
def _root(
    version: Annotated[
        bool,
        typer.Option(
            "--version",
            "-V",
            metavar="",
            callback=_version,
            is_eager=True,
            help="Print qpatrol's version and exit.",
        ),
    ] = False,
) -> None:
    """Learned multi-robot patrolling: Q-learning teams on Pac-Man-like mazes.

    Every command takes -h for its options and examples. The model is described in
    docs/model.md.
    """


# --------------------------------------------------------------------------- train


@app.command(
    **command(
        examples=(
            "qpatrol train paper                      (a shipped config: qpatrol config list)",
            "qpatrol train configs/paper.yaml --set runs=8 --set learning.gamma=0.5 "
            "--out results/runs/g05",
            "qpatrol train configs/paper.yaml --out results/runs/g05 --resume   "
            "(after Ctrl-C or a kill)",
        )
    )
)
def train(
    config: Annotated[
        Path, typer.Argument(metavar="CONFIG", help="YAML experiment config (file or name).")
    ],
    set_: SetOpt = None,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out",
            "-o",
            metavar="DIR",
            help="Output folder (default: results/runs/<config>-<hash>).",
        ),
    ] = None,
    force: Annotated[
        bool,
        typer.Option(
            "--force", metavar="", help="Replace an existing run folder (and its checkpoint)."
        ),
    ] = False,
    resume: Annotated[
        bool,
        typer.Option(
            "--resume",
            metavar="",
            help="Continue an interrupted run from its checkpoint (<out>.checkpoint/); give "
            "the same CONFIG and --set.",
        ),
    ] = False,
    checkpoint_every: Annotated[
        float,
        typer.Option(
            "--checkpoint-every",
            metavar="SECONDS",
            envvar="QPATROL_CHECKPOINT_EVERY",
            help="Seconds between checkpoints (0: only on Ctrl-C or SIGTERM).",
        ),
    ] = 60.0,
    quiet: QuietOpt = False,
) -> None:
    """Train a team on CONFIG and write a run folder.

    The folder holds config.yaml, episodes.csv, summary.json, q_table.npz, visits.npz,
    meta.json, map.txt and the records the config asks for. A checkpoint is saved every
    --checkpoint-every seconds and on Ctrl-C or SIGTERM; --resume continues from it and
    gives the same files as an uninterrupted run.
    """
    from qpatrol import run as run_mod
    from qpatrol.run import checkpoint as ck

    started = provenance.now()
    overrides = list(set_ or [])
    if resume and force:
        fail("--resume continues a run and --force starts it over; give one of them")
    if checkpoint_every < 0 or checkpoint_every != checkpoint_every:
        fail(f"--checkpoint-every: got {checkpoint_every}; allowed: a number of seconds >= 0")
    try:
        cfg = config_mod.load_config(config, overrides)
        target = out or run_mod.default_out_dir(cfg, config)
        outputs.check_out_path(target)
        cp_dir = ck.location(target)
        if resume:
            if target.exists():
                fail(f"{target} already exists: that run finished, there is nothing to resume")
            outputs.check_writable_dir(target)
        else:
            outputs.check_run_target(target, force)
            if (cp_dir.exists() or cp_dir.is_symlink()) and not force:
                fail(
                    f"{cp_dir} holds an interrupted run; pass --resume to continue it or "
                    "--force to start over"
                )
            stray = ck.foreign(cp_dir) if cp_dir.exists() or cp_dir.is_symlink() else None
            if stray is not None:
                fail(
                    f"{cp_dir}: holds {stray}, which is not a checkpoint file; --force removes "
                    "only qpatrol's checkpoint files; move it away or choose another --out"
                )
        prepared = run_mod.prepare(cfg)
        cp = run_mod.train_checkpointer(
            cfg,
            prepared[0],
            cp_dir,
            every=checkpoint_every,
            info={"command": provenance.command(), "steps": cfg["steps"], "started": started},
        )
        if resume:
            snap = cp.load()
            started = str(snap.info.get("started") or started)  # only for meta.json
            cp.info["started"] = started
    except (ConfigError, MapError, ck.CheckpointError) as e:
        fail(str(e))
    if force and cp_dir.exists():
        ck.remove_folder(cp_dir)
    meta = provenance.collect(
        overrides, config_file=config_mod.find_config(config), started=started
    )
    if resume:
        meta["resumed"] = {"from_step": snap.position, "checkpoint_saved": snap.saved}
    bar = Bar(f"train {config.name}", quiet=quiet)
    try:
        result = run_mod.train(
            cfg, target, cp, prepared=prepared, progress=bar, meta=meta, replace=force
        )
    except ck.Interrupted as e:
        bar.close()
        again = provenance.command()
        again += "" if "--resume" in again.split() else " --resume"
        fail(
            f"interrupted at team step {e.position:,} of {cfg['steps']:,}; checkpoint saved in "
            f"{e.folder}; continue with: {again}",
            code=128 + int(e.signum),
        )
    except ConfigError as e:
        bar.close()
        fail(str(e))
    bar.close()
    if not quiet:
        _print_summary(result.summary)
    typer.echo(f"wrote {target}")


# --------------------------------------------------------------------------- sweep


@app.command(
    **command(
        examples=(
            "qpatrol sweep gamma                      (a named sweep: gamma, multiplier, "
            "team-size, strategies, policies, learning, field, security, neural)",
            "qpatrol sweep learning.gamma --values 0.1,0.5,0.9 configs/paper.yaml --runs 16",
            "qpatrol sweep --grid agents=1,2,4 --grid team.communication=on,off "
            "configs/team_size.yaml --jobs 2",
            "qpatrol sweep multiplier --backend dask --scheduler tcp://host:8786",
        )
    )
)
def sweep(
    args: Annotated[
        list[str] | None,
        typer.Argument(
            metavar="[NAME|PARAM] [CONFIG]",
            help="A named sweep (gamma, multiplier, team-size, strategies, policies, learning, "
            "field, security, neural) with an optional "
            "CONFIG, or a config key PARAM with --values and a CONFIG, or just CONFIG with --grid.",
        ),
    ] = None,
    values: Annotated[
        str | None,
        typer.Option("--values", "-v", metavar="V1,V2", help="Comma-separated values of PARAM."),
    ] = None,
    grid: Annotated[
        list[str] | None,
        typer.Option(
            "--grid", "-g", metavar="KEY=V1,V2", help="A grid axis (repeatable, one per key)."
        ),
    ] = None,
    runs: Annotated[
        int | None, typer.Option("--runs", metavar="N", help="Runs per point (sets `runs`).")
    ] = None,
    jobs: Annotated[
        int,
        typer.Option("--jobs", "-j", metavar="N", help="Parallel workers (-1: all cores)."),
    ] = 1,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out", "-o", metavar="DIR", help="Sweep folder (default: results/sweeps/NAME)."
        ),
    ] = None,
    set_: SetOpt = None,
    backend: Annotated[
        str, typer.Option("--backend", metavar="NAME", help="joblib or dask.")
    ] = "joblib",
    scheduler: Annotated[
        str | None,
        typer.Option(
            "--scheduler", metavar="ADDRESS", help="Dask scheduler address (with --backend dask)."
        ),
    ] = None,
    force: Annotated[
        bool, typer.Option("--force", metavar="", help="Discard an existing sweep in --out.")
    ] = False,
    no_batch_points: Annotated[
        bool,
        typer.Option(
            "--no-batch-points",
            metavar="",
            help="Run each point's runs as batches of their own (default: points that "
            "differ only in per-run values, e.g. gamma or the seed, share batches; the "
            "files are the same).",
        ),
    ] = False,
    quiet: QuietOpt = False,
) -> None:
    """Run a config at many parameter values, each point's runs in batches, in parallel.

    Resumable: rerunning the same command skips finished points. Writes
    OUT/points/<id>/ (the files `train` writes), OUT/results.csv and OUT/meta.json.
    """
    from qpatrol.study import sweep as sw
    from qpatrol.world import limits

    args = list(args or [])
    overrides = list(set_ or []) + ([f"runs={runs}"] if runs is not None else [])
    try:
        limits.check_jobs(jobs, "--jobs")
        if runs is not None:
            try:
                config_mod.check_value("runs", runs)
            except ConfigError as e:
                fail(f"--runs {runs}: {str(e).split(': ', 1)[-1]}")
        if not grid and args and args[0] in sw.NAMED_SWEEPS and values is None:
            named = sw.NAMED_SWEEPS[args[0]]
            name = args[0]
            config = Path(args[1]) if len(args) > 1 else Path(named.config)
            points = named.points()
            if len(args) > 2:
                fail(f"sweep {name}: too many arguments {args[2:]}")
        elif grid:
            if len(args) != 1:
                fail("sweep --grid: give exactly one CONFIG")
            config, name = Path(args[0]), "grid"
            axes: dict[str, Any] = {}
            for g in grid:
                if "=" not in g:
                    fail(f"--grid {g!r}: expected KEY=V1,V2,...")
                key, text = g.split("=", 1)
                key = key.strip()
                if key in axes:
                    fail(
                        f"--grid {key}: given twice; allowed: each key once, with all its "
                        f"values (--grid {key}=V1,V2,...)"
                    )
                axes[key] = sw.parse_values(key, text)
            points = sw.grid_points(axes)
        else:
            if len(args) != 2 or values is None:
                known = ", ".join(sw.NAMED_SWEEPS)
                fail(
                    f"sweep: give a named sweep ({known}), or PARAM --values V1,V2 CONFIG, "
                    "or --grid KEY=V1,V2 CONFIG"
                )
            name, config = args[0], Path(args[1])
            points = sw.points_for(name, sw.parse_values(name, values))
        base = config_mod.load_config(config, overrides)
        target = out or Path("results") / "sweeps" / name
        meta = provenance.collect(overrides, config_file=config_mod.find_config(config))
        bar = Bar(f"sweep {name}", unit="runs", quiet=quiet)
        try:
            result = sw.run_sweep(
                base,
                points,
                target,
                jobs=jobs,
                backend=backend,
                scheduler=scheduler,
                progress=bar,
                force=force,
                meta=meta,
                batch_points=not no_batch_points,
            )
        except KeyboardInterrupt:
            bar.close()
            fail(
                f"interrupted; finished points are kept in {target}; rerun the same command "
                "to resume",
                code=130,
            )
        bar.close()
    except (ConfigError, MapError) as e:
        fail(str(e))
    typer.echo(
        f"{len(result.done)} points run, {len(result.skipped)} already done, "
        f"{len(result.failed)} failed; results in {result.results}"
    )
    if result.failed:
        for pid in result.failed:
            typer.echo(f"qpatrol: error: point {pid} failed: {result.errors[pid]}", err=True)
        raise typer.Exit(1)


# --------------------------------------------------------------------------- plot


@app.command(
    **command(
        examples=(
            "qpatrol plot figure-2 --from results/sweeps/multiplier --out fig2.pdf",
            "qpatrol plot figure-6 --from results/runs/figure6-abc123 --out fig6.png",
            "qpatrol plot gamma                       (from results/runs/full/gamma)",
        )
    )
)
def plot(
    name: Annotated[
        str,
        typer.Argument(
            metavar="FIGURE",
            help="figure-2, figure-3, figure-4, gamma, figure-5, figure-6, team-size, "
            "strategies, policies, learning, field, field-models, security, security-failures, "
            "security-recovery or neural.",
        ),
    ],
    from_: Annotated[
        Path | None,
        typer.Option(
            "--from",
            "-f",
            metavar="DIR",
            help="Experiment folder (a sweep or run folder) "
            "(default: results/runs/full/<experiment>, else the quick one).",
        ),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out",
            "-o",
            metavar="FILE",
            help="Image file; .png, .svg, .pdf (.gif for figure-5) (default: "
            "results/figures/FIGURE.png). Its CSV is written beside it.",
        ),
    ] = None,
    force: Annotated[
        bool,
        typer.Option(
            "--force",
            metavar="",
            help="Replace the image and CSV even if qpatrol did not write them as they are.",
        ),
    ] = False,
) -> None:
    """Draw one paper figure from an experiment folder, writing its CSV beside it.

    The folder must hold what the figure is drawn from: a sweep over the multiplier
    (figure-2), gamma (gamma) or agents (team-size), or a run folder (figure-3 to 6).
    """
    from qpatrol.study import plots
    from qpatrol.study import reproduce as rp

    try:
        fig = rp.figure(name)
        target = out or Path("results") / "figures" / f"{name}{fig.ext}"
        plots.check_image_path(target, extra=("gif",))
        for f in fig.files(target):
            outputs.check_writable_file(f)
        fresh = outputs.is_fresh(target.parent)
        if from_ is None:
            candidates = [
                rp.experiment_dir(Path("results"), fig.experiment, False),
                rp.experiment_dir(rp.default_out(True), fig.experiment, True),
                rp.experiment_dir(Path("results"), fig.experiment, True),
            ]
            from_ = next((c for c in candidates if c.exists()), None)
            if from_ is None:
                fail(
                    f"no experiment folder for {name} under results/; run `qpatrol reproduce` "
                    "(or --quick) first, or pass --from DIR"
                )
        if not from_.exists():
            fail(f"{from_}: no such folder")
        if not from_.is_dir():
            fail(f"--from {from_}: is a file; give an experiment folder")
        rp.check_source(fig, from_)

        def check(files: list[Path], csv_text: str) -> None:
            same = {files[0]: csv_text.encode("utf-8")}  # a CSV as it would be written
            outputs.check_files(files, force, same=same)

        made = rp.make_figure(name, from_, target, check=check)
        outputs.record_files(target.parent, [p.name for p in made], fresh)
    except (ConfigError, MapError) as e:
        fail(str(e))
    except (FileNotFoundError, KeyError, ValueError) as e:
        fail(f"{name} from {from_}: {e}")
    for path in made:
        typer.echo(f"wrote {path}")


# --------------------------------------------------------------------------- reproduce


@app.command(
    **command(
        examples=(
            "qpatrol reproduce                        (1 to 3 minutes on 2 cores, into results/)",
            "qpatrol reproduce --quick --out /tmp/q   (a minute; verdicts indicative only)",
        )
    )
)
def reproduce(
    quick: Annotated[
        bool,
        typer.Option(
            "--quick",
            metavar="",
            help="Fewer seeds and steps: every figure in under two minutes; the report's "
            "verdicts are then indicative only.",
        ),
    ] = False,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out",
            "-o",
            metavar="DIR",
            help="Results folder (default: results, or results/quick with --quick).",
        ),
    ] = None,
    jobs: Annotated[
        int | None,
        typer.Option(
            "--jobs", "-j", metavar="N", help="Experiments run at once (default: 2, or 1 core)."
        ),
    ] = None,
    force: Annotated[
        bool,
        typer.Option(
            "--force",
            metavar="",
            help="Compute everything anew in --out: when it was written by another version, "
            "a file of it changed, or its points differ from what this qpatrol would write.",
        ),
    ] = False,
    update_references: Annotated[
        bool,
        typer.Option(
            "--update-references",
            metavar="",
            help="With --quick: store its CSVs as the references the tests compare "
            "(results/reference/quick).",
        ),
    ] = False,
    quiet: QuietOpt = False,
) -> None:
    """Run the paper's experiments, draw every figure and write REPORT.md.

    Writes OUT/figures/, OUT/data/, OUT/REPORT.md and OUT/meta.json. Resumable:
    finished experiment points are kept under OUT/runs/ and not rerun.
    """
    from qpatrol.study import reproduce as rp
    from qpatrol.world import limits

    if update_references and not quick:
        fail("--update-references needs --quick")
    try:
        n = jobs if jobs is not None else min(2, limits.cores())
        limits.check_jobs(n, "--jobs")
        target = out or rp.default_out(quick)
    except ConfigError as e:
        fail(str(e))
    bar = Bar("reproduce" + (" --quick" if quick else ""), unit="runs", quiet=quiet)
    try:
        path = rp.reproduce(
            target,
            quick=quick,
            jobs=n,
            update_references=update_references,
            log=bar.log,
            progress=bar,
            force=force,
        )
    except KeyboardInterrupt:
        bar.close()
        fail(
            f"interrupted; finished experiment points are kept in {target}/runs; rerun the "
            "same command to resume",
            code=130,
        )
    except (ConfigError, MapError) as e:
        bar.close()
        fail(str(e))
    except RuntimeError as e:
        bar.close()
        fail(str(e), code=1)
    bar.close()
    typer.echo(f"done: {path}")


def _print_summary(rows: list[dict]) -> None:
    import numpy as np

    keys = [
        "steps",
        "episodes_completed",
        "mean_steps_per_episode",
        "coverage",
        "avg_idleness",
        "worst_idleness",
        "division_of_labour",
    ]
    typer.echo(f"{'measure':24s} {'mean':>12s} {'min':>12s} {'max':>12s}   over {len(rows)} runs")
    for k in keys:
        vals = np.array([r[k] for r in rows if r[k] is not None], dtype=float)
        if vals.size:
            typer.echo(f"{k:24s} {vals.mean():12.4g} {vals.min():12.4g} {vals.max():12.4g}")
        else:
            typer.echo(f"{k:24s} {'-':>12s}")


# --------------------------------------------------------------------------- bench


@app.command(
    **command(
        examples=(
            "qpatrol bench                                (1 run, 1 agent, map_a)",
            "qpatrol bench --runs 2048 --engine numpy --json",
            "qpatrol bench --runs 256 --agents 4 --steps 2000",
        )
    )
)
def bench(
    runs: Annotated[int, typer.Option("--runs", "-B", metavar="B", help="Runs in the batch.")] = 1,
    agents: Annotated[
        int, typer.Option("--agents", "-K", metavar="K", help="Robots per team.")
    ] = 1,
    steps: Annotated[
        int | None,
        typer.Option(
            "--steps",
            "-T",
            metavar="T",
            help="Team steps per run (default: about a second of work on the compiled "
            "engine, 0.6 to 9 s on numpy, see qpatrol.run.bench.default_steps).",
        ),
    ] = None,
    engine: Annotated[
        str, typer.Option("--engine", "-e", metavar="E", help="auto, numpy or numba.")
    ] = "auto",
    map_: Annotated[str, typer.Option("--map", "-m", metavar="M", help="Map name or file.")] = (
        "map_a"
    ),
    threads: Annotated[
        int,
        typer.Option(
            "--threads",
            metavar="N",
            help="Threads of the compiled engine (0: every core of this process); "
            "the reference loop runs in one.",
        ),
    ] = 0,
    set_: SetOpt = None,
    as_json: Annotated[
        bool, typer.Option("--json", metavar="", help="One JSON object instead of text.")
    ] = False,
) -> None:
    """Measure agent-steps per second of a Q-learning workload (battery off) and of a
    plain-Python reference loop (qpatrol/run/reference.py) in the same process, with their
    ratio, bytes per run and peak memory. Says which engine ran, and why if it fell back,
    and how many threads it had (the runs of a batch are shared among them: use
    --threads 1 for the speed of one core).
    """
    from qpatrol.run import bench as bench_mod

    try:
        extra = dict(config_mod.parse_assignment(a) for a in set_ or [])
        if steps is None:
            steps = bench_mod.default_steps(runs, agents, engine)
        cfg = bench_mod.workload(runs, agents, steps, engine, map_, extra, threads)
        result = bench_mod.bench(cfg)
    except (ConfigError, MapError) as e:
        fail(str(e))
    typer.echo(json.dumps(result) if as_json else bench_mod.report(result))


# --------------------------------------------------------------------------- maps


@maps_app.command(**command("list", examples=("qpatrol maps list",)))
def maps_list() -> None:
    """Maps found by name in ./maps and the maps shipped with qpatrol."""
    for name, path in available_maps().items():
        try:
            m = load_map(path)
            size = "graph  " if m.is_graph else f"{m.shape[1]:3d}x{m.shape[0]:<3d}"
            typer.echo(
                f"{name:12s} {size} {m.n_cells:5d} cells  "
                f"{len(m.starts)} starts  {len(m.homes)} H   {m.description[:60]}"
            )
        except MapError as e:
            typer.echo(f"{name:12s} BROKEN: {e}")


@maps_app.command(
    **command(
        "show",
        examples=(
            "qpatrol maps show map_a                  (the grid with state numbers)",
            "qpatrol maps show map_a --png map_a.png",
            "qpatrol maps show my_floor.txt",
        ),
    )
)
def maps_show(
    name: Annotated[str, typer.Argument(metavar="MAP", help="Map name or path.")],
    png: Annotated[
        Path | None,
        typer.Option(
            "--png", metavar="FILE", help="Draw the map to this image file (.png, .svg, .pdf)."
        ),
    ] = None,
) -> None:
    """Print the grid with each free cell's state number (a graph: a summary), or draw
    it to an image."""
    try:
        if png is not None:
            from qpatrol.study.plots import check_image_path

            check_image_path(png)
            outputs.check_writable_file(png, "--png")
        m = load_map(resolve_map(name))
    except (MapError, ConfigError, ValueError) as e:
        fail(str(e))
    if png is not None:
        from qpatrol.study.plots import plot_map

        plot_map(m, png)
        typer.echo(f"wrote {png}")
        return
    typer.echo(f"{m.name}: {m.description}")
    if m.is_graph:
        typer.echo(graph_summary(m))
        return
    typer.echo(
        f"{m.shape[1]} x {m.shape[0]} grid, {m.n_cells} free cells, starts "
        f"{m.starts.tolist()}, charging stations {m.homes.tolist()}"
    )
    typer.echo(render_states(m))


@maps_app.command(**command("check", examples=("qpatrol maps check my_floor.txt other.txt",)))
def maps_check(
    files: Annotated[list[Path], typer.Argument(metavar="FILE...", help="Map files.")],
) -> None:
    """Check map files; print one line per problem and exit 2 if any is broken."""
    bad = 0
    for f in files:
        try:
            m = load_map(f)
            if m.is_graph:
                typer.echo(
                    f"{f}: ok (graph: {m.n_targets} vertices, {len(m.edges)} edges, "
                    f"{m.n_cells} cells, D = {m.n_ports}, {len(m.starts)} starts, "
                    f"{len(m.homes)} H)"
                )
                continue
            typer.echo(
                f"{f}: ok ({m.n_cells} free cells, {len(m.starts)} starts, {len(m.homes)} H)"
            )
        except MapError as e:
            typer.echo(f"qpatrol: error: {e}", err=True)
            bad += 1
    if bad:
        raise typer.Exit(2)


@maps_app.command(
    **command(
        "import",
        examples=(
            "qpatrol maps import floor.yaml --cell 1.2",
            "qpatrol maps import floor.yaml --cell 0.6 --agents 6 --stations 4 --out maps/f6.txt",
            "qpatrol maps import floor.yaml --cell 1.2 --out -",
            "qpatrol maps import cumberland.graph                (patrolling_sim graph)",
            "qpatrol maps import grid.graph --unit-edges --agents 2",
            "qpatrol maps import map_a.xml --edge-step 4         (SimPatrol graph)",
        ),
    )
)
def maps_import(
    source: Annotated[
        Path,
        typer.Argument(
            metavar="FILE",
            help="ROS map_server map YAML (and its image), patrolling_sim .graph or "
            "SimPatrol .xml graph.",
        ),
    ],
    cell: Annotated[
        float | None,
        typer.Option(help="ROS maps: cell side in metres (required), at least one pixel."),
    ] = None,
    edge_step: Annotated[
        float | None,
        typer.Option(
            "--edge-step",
            metavar="LENGTH",
            help="Graphs: the length of one move; an edge of length l becomes "
            "max(1, round(l / LENGTH)) moves (default: the shortest edge).",
        ),
    ] = None,
    unit_edges: Annotated[
        bool, typer.Option("--unit-edges", metavar="", help="Graphs: every edge one move.")
    ] = False,
    out: Annotated[
        str | None,
        typer.Option(
            "--out", "-o", help="Map file to write (default: maps/<FILE stem>.txt; '-': stdout)."
        ),
    ] = None,
    agents: Annotated[
        int, typer.Option(help="Start cells (vertices) 0..N-1 to place (ROS maps: 0 to 10).")
    ] = 4,
    stations: Annotated[
        int | None,
        typer.Option(
            help="Charging stations (default: one per 150 free cells or vertices, rounded "
            "up; a SimPatrol graph's fuel nodes if it has any)."
        ),
    ] = None,
    force: Annotated[
        bool, typer.Option("--force", metavar="", help="Replace an existing map file.")
    ] = False,
) -> None:
    """Import a ROS occupancy map or a patrol graph as a qpatrol map.

    The kind follows the suffix. .yaml: a ROS map_server map (YAML + PGM/PNG); cells are
    free only if all their pixels are free, the largest 4-connected free region is kept
    and cropped. .graph (patrolling_sim) or .xml (SimPatrol): a patrol graph, each edge
    cut into whole moves. Starts and stations are spread by farthest-point sampling.
    Details: docs/maps.md.
    """
    from qpatrol.util import atomic

    suffix = source.suffix.lower()
    graph = suffix in (".graph", ".xml")
    if not graph and suffix not in (".yaml", ".yml"):
        fail(
            f"{source}: unknown map file kind {suffix or '(no suffix)'!r}; expected .yaml "
            "(ROS map_server), .graph (patrolling_sim) or .xml (SimPatrol)"
        )
    if graph and cell is not None:
        fail(
            f"maps import: --cell is for ROS maps (.yaml); {source.name} is a patrol graph "
            "(its edges become moves: --edge-step or --unit-edges)"
        )
    if not graph and (edge_step is not None or unit_edges):
        fail("maps import: --edge-step and --unit-edges are for patrol graphs (.graph, .xml)")
    if graph and edge_step is not None and unit_edges:
        fail("maps import: --edge-step and --unit-edges exclude each other; give one")
    if not graph and cell is None:
        fail("maps import: --cell METRES is required (the side of a grid cell)")
    target = None if out == "-" else Path(out or Path("maps") / f"{source.stem}.txt")
    if target is not None and target.exists() and not force:
        fail(f"{target} already exists; pass --force to replace it or --out to choose another")
    if target is not None:
        try:
            outputs.check_writable_file(target)
        except ConfigError as e:
            fail(str(e))
    name = target.stem if target is not None else None
    if graph:
        text, report = _import_graph(source, name, agents, stations, edge_step, unit_edges)
    else:
        text, report = _import_ros(source, target, name, cell, agents, stations)
    if target is None:
        typer.echo(text, nl=False)
        typer.echo(report, err=True)
        return
    try:
        atomic.write_text(target, text)
    except OSError as e:
        fail(f"{target}: cannot write ({e.strerror or e})")
    typer.echo(f"wrote {target}: {report}")


def _import_ros(
    yaml_file: Path,
    target: Path | None,
    name: str | None,
    cell: float,
    agents: int,
    stations: int | None,
) -> tuple[str, str]:
    """The map text of a ROS map and the one-line report of ``maps import``."""
    from qpatrol.maps.importer import RosMapError, import_map

    try:
        result = import_map(yaml_file, cell, agents=agents, stations=stations, name=name)
        m = parse_map(result.text, source=str(target or "<stdout>"))
    except (RosMapError, MapError) as e:
        fail(str(e))
    rows, cols = m.shape
    reach = (
        f"farthest cell {result.farthest_station} moves from an H"
        if len(m.homes)
        else "no H: train it with battery.enabled=false"
    )
    report = (
        f"{cols} x {rows} grid, {m.n_cells} free cells of {cell:g} m ({result.cell_pixels:.4g} "
        f"px), {len(m.starts)} starts, {len(m.homes)} H; {reach}"
    )
    if result.regions > 1:
        report += (
            f"; kept the largest of {result.regions} free regions "
            f"({m.n_cells} of {result.free_cells} free cells)"
        )
    return result.text, report


def _import_graph(
    source: Path,
    name: str | None,
    agents: int,
    stations: int | None,
    edge_step: float | None,
    unit_edges: bool,
) -> tuple[str, str]:
    """The graph map text of a patrolling_sim or SimPatrol file and the one-line report."""
    from qpatrol.maps.graphfile import import_graph_file

    try:
        r = import_graph_file(source, name, agents, stations, edge_step, unit_edges)
    except MapError as e:
        fail(str(e))
    m = r.map
    unit = f" {r.source.unit}" if r.source.unit else ""
    step = "every edge one move" if r.step is None else f"edge step {r.step:g}{unit}"
    reach = (
        f"farthest vertex {r.farthest_station} moves from a station"
        if len(m.homes)
        else "no station: train it with battery.enabled=false"
    )
    report = (
        f"graph of {m.n_targets} vertices, {len(m.edges)} edges of "
        f"{int(m.edges[:, 2].sum()) if len(m.edges) else 0} moves ({m.n_cells} cells, "
        f"D = {m.n_ports}), {step}, {len(m.starts)} starts, {len(m.homes)} "
        f"station{'' if len(m.homes) == 1 else 's'}; {reach}"
    )
    for note in r.source.notes:
        report += f"; {note}"
    return r.text, report


# --------------------------------------------------------------------------- config


@config_app.command(**command("keys", examples=("qpatrol config keys",)))
def config_keys() -> None:
    """Every config key with its default, allowed values and meaning."""
    typer.echo(config_mod.keys_table())


@config_app.command(**command("list", examples=("qpatrol config list", "qpatrol train paper")))
def config_list() -> None:
    """The configs shipped with qpatrol, usable by name (qpatrol train paper)."""
    for name, path in config_mod.shipped_configs().items():
        first = ""
        for line in path.read_text(encoding="utf-8").splitlines():
            if line.startswith("#"):
                first = line.lstrip("# ").strip()
                break
        typer.echo(f"{name:12s} {first}")


@config_app.command(
    **command(
        "show",
        examples=(
            "qpatrol config show configs/paper.yaml --set agents=2",
            "qpatrol config show paper --json",
        ),
    )
)
def config_show(
    config: Annotated[
        Path, typer.Argument(metavar="CONFIG", help="YAML experiment config (file or name).")
    ],
    set_: SetOpt = None,
    as_json: Annotated[
        bool, typer.Option("--json", metavar="", help="JSON instead of YAML.")
    ] = False,
) -> None:
    """Print the fully resolved config (defaults filled in, overrides applied)."""
    try:
        cfg = config_mod.load_config(config, set_ or [])
    except ConfigError as e:
        fail(str(e))
    typer.echo(json.dumps(cfg.tree(), indent=2) if as_json else cfg.to_yaml().rstrip())


# --------------------------------------------------------------------------- entry point


def crash_log(exc: BaseException) -> Path | None:
    """Write ``exc``'s traceback to a log file; its path, or None if none could be written.

    The folder is ``$QPATROL_LOG_DIR``, else the system's temporary folder.
    """
    folder = Path(os.environ.get("QPATROL_LOG_DIR") or tempfile.gettempdir())
    stamp = time.strftime("%Y%m%d-%H%M%S")
    path = folder / f"qpatrol-crash-{stamp}-{os.getpid()}.log"
    text = (
        f"qpatrol {__version__}\ncommand: {provenance.command()}\ntime: {provenance.now()}\n\n"
        + "".join(traceback.format_exception(exc))
    )
    try:
        folder.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    except OSError:
        return None
    return path


def main(argv: list[str] | None = None) -> None:
    """Console entry point: runs the command in ``argv`` (default ``sys.argv[1:]``) and
    exits. Usage errors, interrupts and internal errors each end with one line."""
    args = list(sys.argv[1:] if argv is None else argv)
    provenance.set_command(["qpatrol", *args])
    _said.clear()
    try:
        code = app(args=args, prog_name="qpatrol", standalone_mode=False)
    except (typer.Abort, KeyboardInterrupt):
        typer.echo("qpatrol: interrupted", err=True)
        sys.exit(130)
    except BrokenPipeError:  # `qpatrol ... | head`: the reader left; say nothing more
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        sys.exit(141)
    except _click_exc.UsageError as e:
        ctx = e.ctx
        hint = f" (see '{ctx.command_path} -h')" if ctx is not None else ""
        message = " ".join(e.format_message().split()).rstrip(".")
        if message:  # no message: click already printed the help (no arguments given)
            typer.echo(f"qpatrol: error: {message}{hint}", err=True)
        sys.exit(e.exit_code)
    except _click_exc.ClickException as e:
        typer.echo(f"qpatrol: error: {' '.join(e.format_message().split())}", err=True)
        sys.exit(e.exit_code)
    except SystemExit:
        raise
    except Exception as e:
        path = crash_log(e)
        first = str(e).splitlines()[0] if str(e) else ""
        where = f"; full traceback in {path}" if path else ""
        typer.echo(
            f"qpatrol: internal error: {type(e).__name__}: {first}{where}; please report it",
            err=True,
        )
        sys.exit(1)
    code = code if isinstance(code, int) else 0
    if code == 130 and not _said:  # typer turns Ctrl-C into a silent exit 130
        typer.echo("qpatrol: interrupted", err=True)
    sys.exit(code)


def _unwrap(doc: str) -> str:
    """Docstring -> help text: paragraphs kept, the line breaks inside them removed (rich
    help keeps them, which breaks lines in odd places)."""
    paragraphs = inspect.cleandoc(doc).split("\n\n")
    return "\n\n".join(" ".join(p.split()) for p in paragraphs)


for _app in (app, maps_app, config_app):
    for _info in _app.registered_commands:
        if _info.help is None and _info.callback is not None and _info.callback.__doc__:
            _info.help = _unwrap(_info.callback.__doc__)


if __name__ == "__main__":
    main()
