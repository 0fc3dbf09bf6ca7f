import io

from qpatrol.util.progress import Bar


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_bar_draws_on_a_terminal_only():
    piped = io.StringIO()
    bar = Bar("train", stream=piped)
    bar(5, 10)
    bar(10, 10)
    bar.close()
    assert piped.getvalue() == ""
    tty = Tty()
    bar = Bar("train", stream=tty)
    bar(10, 10)
    bar.close()
    out = tty.getvalue()
    assert "train" in out and "10/10 steps" in out and out.endswith("\n")


def test_piped_progress_reports_a_line_every_so_often():
    piped = io.StringIO()
    bar = Bar("sweep gamma", stream=piped, unit="runs", every=0.0)
    bar(2.5, 10)
    bar(5, 10)
    bar.close()
    lines = piped.getvalue().splitlines()
    assert lines[0].startswith("sweep gamma: 2.5/10 runs (25%), ") and "left" in lines[0]
    assert lines[1].startswith("sweep gamma: 5/10 runs (50%)")
    quiet = Tty()
    bar = Bar("x", stream=quiet, quiet=True)
    bar(1, 2)
    bar.close()
    assert quiet.getvalue() == ""


def test_sweep_progress_moves_during_a_point(tmp_path):
    """One point of 2 runs: progress reports fractions of its runs before it ends."""
    from qpatrol.config import from_flat
    from qpatrol.study.sweep import points_for, run_sweep

    base = from_flat(
        {"map": "map_b", "agents": 2, "runs": 2, "steps": 4000, "battery.enabled": False}
    )
    calls = []
    run_sweep(base, points_for("seed", [1]), tmp_path / "s", progress=lambda d, t: calls.append(d))
    inside = [d for d in calls if 0 < d < 2]
    assert inside, calls
    assert calls == sorted(calls) and calls[-1] == 2
    assert not list((tmp_path / "s" / "points").glob(".*progress*"))
