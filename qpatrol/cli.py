"""``qpatrol`` command line: a thin layer over the Python API.

Bad input (config, map, file) ends with one line on stderr and exit code 2.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from qpatrol import config as config_mod
from qpatrol.config import ConfigError
from qpatrol.maps import MapError, available_maps, load_map, parse_map, render_states, resolve_map
from qpatrol.progress import Bar

app = typer.Typer(
    help="Learned multi-robot patrolling: Q-learning teams on Pac-Man-like mazes.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
maps_app = typer.Typer(help="List, show, check and import maps.", no_args_is_help=True)
config_app = typer.Typer(help="Config keys and resolved configs.", no_args_is_help=True)
app.add_typer(maps_app, name="maps")
app.add_typer(config_app, name="config")

SetOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--set",
        "-s",
        metavar="KEY=VALUE",
        help="Override a config key, e.g. --set learning.gamma=0.5 (repeatable).",
    ),
]


def fail(message: str, code: int = 2) -> None:
    """Print one line to stderr and exit."""
    typer.echo(f"qpatrol: error: {message}", err=True)
    raise typer.Exit(code)


@app.command()
def train(
    config: Annotated[Path, typer.Argument(help="YAML experiment config.")],
    set_: SetOpt = None,
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Output folder (default: results/runs/<config>-<hash>)."),
    ] = None,
    force: Annotated[bool, typer.Option(help="Replace an existing output folder.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No summary table.")] = False,
) -> None:
    """Train a team on CONFIG and write config.yaml, episodes.csv, summary.json, q_table.npz."""
    from qpatrol.run import default_out_dir, prepare, simulate, write_run

    try:
        cfg = config_mod.load_config(config, set_ or [])
        prepared = prepare(cfg)
    except (ConfigError, MapError) as e:
        fail(str(e))
    target = out or default_out_dir(cfg, config)
    if target.exists() and not force:
        fail(f"{target} already exists; pass --force to replace it or --out to choose another")
    bar = Bar(f"train {config.name}")
    result = simulate(cfg, progress=bar, prepared=prepared)
    bar.close()
    write_run(result, target, replace=force)
    if not quiet:
        _print_summary(result.summary)
    typer.echo(f"wrote {target}")


@app.command(
    context_settings={"help_option_names": ["-h", "--help"]},
    epilog="Examples: qpatrol sweep gamma | qpatrol sweep learning.gamma --values 0.1,0.5 "
    "configs/paper.yaml | qpatrol sweep --grid agents=1,2,4 --grid team.communication=on,off "
    "configs/team_size.yaml",
)
def sweep(
    args: Annotated[
        list[str] | None,
        typer.Argument(
            metavar="[NAME|PARAM] [CONFIG]",
            help="A named sweep (gamma, multiplier, team-size) with an optional CONFIG, or a "
            "config key PARAM with --values and a CONFIG, or just CONFIG with --grid.",
        ),
    ] = None,
    values: Annotated[
        str | None, typer.Option("--values", "-v", help="Comma-separated values of PARAM.")
    ] = None,
    grid: Annotated[
        list[str] | None,
        typer.Option("--grid", "-g", metavar="KEY=V1,V2", help="A grid axis (repeatable)."),
    ] = None,
    runs: Annotated[int | None, typer.Option(help="Runs per point (sets `runs`).")] = None,
    jobs: Annotated[
        int, typer.Option("--jobs", "-j", help="Parallel workers (-1: all cores).")
    ] = 1,
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Sweep folder (default: results/sweeps/NAME)."),
    ] = None,
    set_: SetOpt = None,
    backend: Annotated[str, typer.Option(help="joblib or dask.")] = "joblib",
    scheduler: Annotated[
        str | None, typer.Option(help="Dask scheduler address (with --backend dask).")
    ] = None,
    force: Annotated[bool, typer.Option(help="Discard an existing sweep in --out.")] = False,
) -> None:
    """Run a config at many parameter values, each point's runs as one batch, in parallel.

    Resumable: rerunning the same command skips finished points. Writes
    OUT/points/<id>/ (the files `train` writes) and OUT/results.csv.
    """
    from qpatrol import sweep as sw

    args = list(args or [])
    try:
        if not grid and args and args[0] in sw.NAMED_SWEEPS and values is None:
            named = sw.NAMED_SWEEPS[args[0]]
            name = args[0]
            config = Path(args[1]) if len(args) > 1 else _repo_path(named.config)
            points = named.points()
            if len(args) > 2:
                fail(f"sweep {name}: too many arguments {args[2:]}")
        elif grid:
            if len(args) != 1:
                fail("sweep --grid: give exactly one CONFIG")
            config, name = Path(args[0]), "grid"
            axes = {}
            for g in grid:
                if "=" not in g:
                    fail(f"--grid {g!r}: expected KEY=V1,V2,...")
                key, text = g.split("=", 1)
                axes[key.strip()] = sw.parse_values(key.strip(), text)
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
        overrides = list(set_ or []) + ([f"runs={runs}"] if runs is not None else [])
        base = config_mod.load_config(config, overrides)
        target = out or Path("results") / "sweeps" / name
        bar = Bar(f"sweep {name}", unit="runs")
        result = sw.run_sweep(
            base,
            points,
            target,
            jobs=jobs,
            backend=backend,
            scheduler=scheduler,
            progress=bar,
            force=force,
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


@app.command()
def plot(
    name: Annotated[
        str,
        typer.Argument(
            help="figure-2, figure-3, figure-4, gamma, figure-5, figure-6 or team-size."
        ),
    ],
    from_: Annotated[
        Path | None,
        typer.Option(
            "--from",
            "-f",
            help="Experiment folder (a sweep or run folder) "
            "(default: results/runs/full/<experiment>, else .../quick/<experiment>).",
        ),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out",
            "-o",
            help="Image file; .png, .svg, .pdf (.gif for figure-5) (default: "
            "results/figures/NAME.png). Its CSV is written beside it.",
        ),
    ] = None,
) -> None:
    """Draw one paper figure from an experiment folder, writing its CSV beside it."""
    from qpatrol import reproduce as rp

    try:
        fig = rp.figure(name)
    except ConfigError as e:
        fail(str(e))
    if from_ is None:
        candidates = [rp.experiment_dir(Path("results"), fig.experiment, q) for q in (False, True)]
        from_ = next((c for c in candidates if c.exists()), None)
        if from_ is None:
            fail(
                f"no experiment folder for {name} under results/runs/; run `qpatrol reproduce` "
                "(or --quick) first, or pass --from DIR"
            )
    if not from_.exists():
        fail(f"{from_}: no such folder")
    target = out or Path("results") / "figures" / f"{name}{fig.ext}"
    try:
        made = rp.make_figure(name, from_, target)
    except (FileNotFoundError, KeyError, ValueError) as e:
        fail(f"{name} from {from_}: {e}")
    for path in made:
        typer.echo(f"wrote {path}")


@app.command()
def reproduce(
    quick: Annotated[
        bool, typer.Option(help="Fewer seeds and steps: every figure in under a minute.")
    ] = False,
    out: Annotated[Path, typer.Option("--out", "-o", help="Results folder.")] = Path("results"),
    jobs: Annotated[int, typer.Option("--jobs", "-j", help="Experiments run at once.")] = 2,
    update_references: Annotated[
        bool,
        typer.Option(help="With --quick: store its CSVs as the references the tests compare."),
    ] = False,
) -> None:
    """Run the paper's experiments, draw every figure and write REPORT.md.

    Resumable: finished experiment points are kept under OUT/runs/ and not rerun.
    """
    from qpatrol import reproduce as rp

    if update_references and not quick:
        fail("--update-references needs --quick")
    try:
        path = rp.reproduce(
            out, quick=quick, jobs=jobs, update_references=update_references, log=typer.echo
        )
    except (ConfigError, MapError) as e:
        fail(str(e))
    except RuntimeError as e:
        fail(str(e), code=1)
    typer.echo(f"done: {path}")


def _repo_path(relative: str) -> Path:
    """A file of the qpatrol checkout (configs/...), preferring one in the working dir."""
    here = Path(relative)
    if here.exists():
        return here
    return Path(__file__).resolve().parent.parent / relative


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


@maps_app.command("list")
def maps_list() -> None:
    """Maps found by name in ./maps and the shipped maps/ folder."""
    for name, path in available_maps().items():
        try:
            m = load_map(path)
            typer.echo(
                f"{name:12s} {m.shape[1]:3d}x{m.shape[0]:<3d} {m.n_cells:5d} cells  "
                f"{len(m.starts)} starts  {len(m.homes)} H   {m.description[:60]}"
            )
        except MapError as e:
            typer.echo(f"{name:12s} BROKEN: {e}")


@maps_app.command("show")
def maps_show(
    name: Annotated[str, typer.Argument(help="Map name or path.")],
    png: Annotated[Path | None, typer.Option(help="Draw the map to this image file.")] = None,
) -> None:
    """Print the grid with each free cell's state number, or draw it to an image."""
    try:
        m = load_map(resolve_map(name))
    except MapError as e:
        fail(str(e))
    if png is not None:
        from qpatrol.plots import plot_map

        plot_map(m, png)
        typer.echo(f"wrote {png}")
        return
    typer.echo(f"{m.name}: {m.description}")
    typer.echo(
        f"{m.shape[1]} x {m.shape[0]} grid, {m.n_cells} free cells, starts "
        f"{m.starts.tolist()}, charging stations {m.homes.tolist()}"
    )
    typer.echo(render_states(m))


@maps_app.command("check")
def maps_check(files: Annotated[list[Path], typer.Argument(help="Map files.")]) -> None:
    """Check map files; print one line per problem and exit 2 if any is broken."""
    bad = 0
    for f in files:
        try:
            m = load_map(f)
            typer.echo(
                f"{f}: ok ({m.n_cells} free cells, {len(m.starts)} starts, {len(m.homes)} H)"
            )
        except MapError as e:
            typer.echo(f"qpatrol: error: {e}", err=True)
            bad += 1
    if bad:
        raise typer.Exit(2)


@maps_app.command("import")
def maps_import(
    yaml_file: Annotated[
        Path, typer.Argument(metavar="FILE.yaml", help="ROS map_server map YAML (and its image).")
    ],
    cell: Annotated[
        float | None,
        typer.Option(help="Cell side in metres (required), at least one pixel."),
    ] = None,
    out: Annotated[
        str | None,
        typer.Option(
            "--out", "-o", help="Map file to write (default: maps/<YAML stem>.txt; '-': stdout)."
        ),
    ] = None,
    agents: Annotated[int, typer.Option(help="Start digits 0..N-1 to place (0 to 10).")] = 4,
    stations: Annotated[
        int | None,
        typer.Option(help="Charging stations H (default: one per 150 free cells, rounded up)."),
    ] = None,
    force: Annotated[bool, typer.Option(help="Replace an existing map file.")] = False,
) -> None:
    """Import a ROS occupancy map (map_server YAML + PGM/PNG) as a qpatrol map.

    Cells are free only if all their pixels are free; the largest 4-connected free
    region is kept and cropped; starts and stations are spread by farthest-point
    sampling. Details: README (maps import) and qpatrol/mapimport.py.
    """
    from qpatrol import atomic
    from qpatrol.mapimport import RosMapError, import_map

    if cell is None:
        fail("maps import: --cell METRES is required (the side of a grid cell)")
    target = None if out == "-" else Path(out or Path("maps") / f"{yaml_file.stem}.txt")
    if target is not None and target.exists() and not force:
        fail(f"{target} already exists; pass --force to replace it or --out to choose another")
    name = target.stem if target is not None else None
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
    if target is None:
        typer.echo(result.text, nl=False)
        typer.echo(report, err=True)
        return
    try:
        atomic.write_text(target, result.text)
    except OSError as e:
        fail(f"{target}: cannot write ({e.strerror or e})")
    typer.echo(f"wrote {target}: {report}")


@config_app.command("keys")
def config_keys() -> None:
    """Every config key with its default, allowed values and meaning."""
    typer.echo(config_mod.keys_table())


@config_app.command("show")
def config_show(
    config: Annotated[Path, typer.Argument(help="YAML experiment config.")],
    set_: SetOpt = None,
    as_json: Annotated[bool, typer.Option("--json", help="JSON instead of YAML.")] = False,
) -> None:
    """Print the fully resolved config (defaults filled in, overrides applied)."""
    try:
        cfg = config_mod.load_config(config, set_ or [])
    except ConfigError as e:
        fail(str(e))
    typer.echo(json.dumps(cfg.tree(), indent=2) if as_json else cfg.to_yaml().rstrip())


def main() -> None:
    """Console entry point."""
    try:
        app()
    except KeyboardInterrupt:
        typer.echo("qpatrol: interrupted", err=True)
        sys.exit(130)


if __name__ == "__main__":
    main()
