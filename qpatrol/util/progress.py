"""Progress on stderr: a rich bar on a terminal, a one-line report every ten seconds
when stderr is piped or logged, nothing with ``--quiet``.

``Bar(label, unit="runs")(done, total)`` updates it (``done`` may be fractional: a
sweep counts the runs of a point as they advance); :meth:`Bar.close` ends it. Calls
may come from several threads. ``QPATROL_PROGRESS_EVERY`` sets the seconds between
two reports when not on a terminal (default 10).
"""

from __future__ import annotations

import os
import sys
import threading
import time
from typing import Any, TextIO

#: Seconds between two progress lines when the stream is not a terminal.
REPORT_EVERY = 10.0

#: The share of the work done before a report estimates the time left: the first runs
#: of a study wait for the compile and are no guide (a cold reproduction said "about
#: 12,201 h left" at 0.1 of 20,316 runs, and finished in minutes).
ETA_AFTER = 0.05


def _every() -> float:
    try:
        return float(os.environ.get("QPATROL_PROGRESS_EVERY", REPORT_EVERY))
    except ValueError:
        return REPORT_EVERY


def _num(x: float) -> str:
    return f"{int(x):,}" if float(x).is_integer() else f"{x:,.1f}"


def _duration(seconds: float) -> str:
    s = int(round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


class Bar:
    """A progress display for one task.

    Args:
        label: what is being done (``train paper.yaml``).
        stream: where to draw (default ``sys.stderr``).
        force: draw a bar even if ``stream`` is not a terminal.
        unit: what ``done`` and ``total`` count.
        quiet: show nothing at all.
        every: seconds between two report lines when not on a terminal.
    """

    def __init__(
        self,
        label: str,
        stream: TextIO | None = None,
        force: bool = False,
        unit: str = "steps",
        quiet: bool = False,
        every: float | None = None,
    ):
        self.label = label
        self.unit = unit
        self.stream = stream or sys.stderr
        self.quiet = quiet
        tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.enabled = not quiet and (force or tty)  # draws a bar
        self.reports = not quiet and not self.enabled  # prints a line now and then
        self.every = _every() if every is None else every
        self.start = time.monotonic()
        self._last_report = self.start
        self._lock = threading.Lock()
        self._progress: Any = None
        self._task: Any = None
        self._last_draw = 0.0
        self._done = 0.0
        self._total = 0.0

    # -- rich -----------------------------------------------------------------------
    def _rich(self) -> Any:
        if self._progress is None:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            class _Console(Console):
                def show_cursor(self, show: bool = True) -> bool:  # keep the cursor alone
                    return False

            console = _Console(file=self.stream, force_terminal=True, highlight=False)
            self._progress = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                TextColumn("{task.fields[count]}"),
                TimeElapsedColumn(),
                TextColumn("eta"),
                TimeRemainingColumn(),
                console=console,
                auto_refresh=False,
            )
            self._progress.start()
            self._task = self._progress.add_task(self.label, total=None, count="")
        return self._progress

    def __call__(self, done: float, total: float) -> None:
        if self.quiet:
            return
        with self._lock:
            self._done, self._total = float(done), float(total)
            now = time.monotonic()
            if self.enabled:
                if done < total and now - self._last_draw < 0.1:
                    return
                self._last_draw = now
                p = self._rich()
                count = f"{_num(done)}/{_num(total)} {self.unit}"
                p.update(self._task, completed=done, total=total or None, count=count)
                p.refresh()
            elif self.reports and now - self._last_report >= self.every:
                self._last_report = now
                self.stream.write(self.report_line(now) + "\n")
                self.stream.flush()

    def report_line(self, now: float | None = None) -> str:
        """``label: done/total unit (pct%), elapsed, about eta left`` (the time left once
        :data:`ETA_AFTER` of the work is done)."""
        now = time.monotonic() if now is None else now
        elapsed = now - self.start
        frac = self._done / self._total if self._total else 0.0
        line = f"{self.label}: {_num(self._done)}/{_num(self._total)} {self.unit}"
        line += f" ({100 * frac:.0f}%), {_duration(elapsed)} elapsed"
        if ETA_AFTER <= frac < 1:
            line += f", about {_duration(elapsed / frac - elapsed)} left"
        return line

    def log(self, line: str) -> None:
        """Print a line of output without breaking the bar (stdout when there is none)."""
        if self.quiet:
            return
        with self._lock:
            if self._progress is not None:
                self._progress.console.print(line, markup=False, highlight=False)
            else:
                sys.stdout.write(line + "\n")
                sys.stdout.flush()

    def close(self) -> None:
        """End the display (the bar stays on screen, followed by a new line)."""
        with self._lock:
            if self._progress is not None:
                self._progress.refresh()
                self._progress.stop()
                self._progress = None

    def __enter__(self) -> Bar:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
