"""What made an output folder: ``meta.json`` and a copy of the map.

Every folder qpatrol writes (a run, a sweep point, a sweep, a reproduction) gets a
``meta.json``::

    qpatrol     the qpatrol version
    git         {"commit", "dirty"} when qpatrol runs from a git checkout, else null
    command     the command line (``qpatrol train ...``), or the Python process's argv
    config_file the config file, when there is one
    overrides   the ``--set KEY=VALUE`` overrides
    started     start time, ISO 8601 with UTC offset; ended: end time
    host        {"cores": ...}
    python, numpy  versions
    map         {"name", "file", "sha256"}: the map used, copied into the folder as
                ``map.txt`` (run folders)
    engine      (run folders) how the time loop ran, :func:`engine_entry`:
                {"asked": config key ``engine`` (auto, numpy or numba),
                 "ran": the engine that ran (numpy or numba),
                 "loop": that engine's loop (numba: any, qlearning, qlearning-solo or
                         qlearning-team; numpy: general, its one step),
                 "note": why "ran" is not "asked" ("" when it is, or when auto took
                         numba), e.g. "fallback from numba: policy ..."}

Times differ between two runs of the same config, so ``meta.json`` is the one file
of a run folder that is not byte-identical between reruns.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import platform
import shlex
import subprocess
import sys
from functools import lru_cache
from pathlib import Path
from typing import Any

from qpatrol import __version__

META_FILE = "meta.json"
MAP_FILE = "map.txt"

#: The command line of the current ``qpatrol`` invocation (set by the CLI).
_COMMAND: list[str] | None = None


def set_command(argv: list[str]) -> None:
    """Remember the command line (``["qpatrol", "train", ...]``) for ``meta.json``."""
    global _COMMAND
    _COMMAND = list(argv)


def command() -> str:
    """The command line as one shell-quoted string."""
    return shlex.join(_COMMAND if _COMMAND is not None else [Path(sys.argv[0]).name, *sys.argv[1:]])


def now() -> str:
    """The local time, ISO 8601 with its UTC offset, to the second."""
    return _dt.datetime.now().astimezone().isoformat(timespec="seconds")


@lru_cache(maxsize=1)
def git_info() -> dict[str, Any] | None:
    """``{"commit", "dirty"}`` of the checkout qpatrol is imported from, or None."""
    root = Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return None
    try:
        commit = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
        status = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    return {"commit": commit, "dirty": bool(status.strip())}


def collect(
    overrides: list[str] | None = None,
    config_file: str | Path | None = None,
    started: str | None = None,
    **extra: Any,
) -> dict[str, Any]:
    """The provenance fields known before a run (``ended`` is added when it is written)."""
    import numpy

    meta: dict[str, Any] = {
        "qpatrol": __version__,
        "git": git_info(),
        "command": command(),
        "config_file": str(config_file) if config_file is not None else None,
        "overrides": list(overrides or []),
        "started": started or now(),
        "ended": None,
        "host": {"cores": os.cpu_count()},
        "python": platform.python_version(),
        "numpy": numpy.__version__,
    }
    meta.update(extra)
    return meta


def engine_entry(asked: str, ran: str, loop: str, note: str = "") -> dict[str, str]:
    """The ``engine`` field of a run folder's ``meta.json`` (see the module's docstring):
    the engine the config asked for, the one that ran, its loop, and why they differ."""
    return {"asked": asked, "ran": ran, "loop": loop, "note": note}


def map_entry(text: str, name: str) -> dict[str, Any]:
    """The ``map`` field of ``meta.json`` for a map file's text."""
    return {
        "name": name,
        "file": MAP_FILE,
        "sha256": hashlib.sha256(text.encode("utf-8")).hexdigest(),
    }


def meta_text(meta: dict[str, Any]) -> str:
    """``meta.json`` content, with ``ended`` filled in if it is not yet."""
    meta = dict(meta)
    if not meta.get("ended"):
        meta["ended"] = now()
    return json.dumps(meta, indent=2, default=str) + "\n"


def read_meta(folder: str | Path) -> dict[str, Any] | None:
    """The ``meta.json`` of a folder, or None if it has none (or it is unreadable)."""
    try:
        return json.loads((Path(folder) / META_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
