"""The progress line printed when stderr is not a terminal (``qpatrol.util.progress``)."""

from __future__ import annotations

import io

from qpatrol.util import progress


def test_the_time_left_is_estimated_once_enough_work_is_done():
    bar = progress.Bar("reproduce", stream=io.StringIO(), unit="runs", every=1e9)
    bar(0.1, 20316)  # the first runs wait for the compile: no guide to the rest
    line = bar.report_line(now=bar.start + 115)
    assert line == "reproduce: 0.1/20,316 runs (0%), 1 min 55 s elapsed"
    bar(1000, 4000)  # a quarter done in 60 s: 180 s left
    assert bar.report_line(now=bar.start + 60) == (
        "reproduce: 1,000/4,000 runs (25%), 1 min 00 s elapsed, about 3 min 00 s left"
    )
    bar(4000, 4000)
    assert bar.report_line(now=bar.start + 240).endswith("(100%), 4 min 00 s elapsed")
