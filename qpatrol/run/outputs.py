"""Output paths, checked before any work starts.

Every command that writes calls one of these checks first, so an output that cannot
be written is found out in a fraction of a second, with one line, instead of after the
simulation. ``--force`` replaces only what qpatrol wrote itself: a run folder (with
``meta.json``, or ``config.yaml`` and ``summary.json``) or a sweep folder (with
``sweep.json``), never a file or someone else's folder.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from qpatrol.config import ConfigError


class OutputError(ConfigError):
    """An output path that cannot or must not be written; the message is one line."""


def is_run_folder(path: Path) -> bool:
    """True for a folder ``qpatrol train`` (or a sweep point) wrote."""
    p = Path(path)
    return p.is_dir() and (
        (p / "meta.json").is_file()
        or ((p / "config.yaml").is_file() and (p / "summary.json").is_file())
    )


def is_sweep_folder(path: Path) -> bool:
    """True for a folder ``qpatrol sweep`` wrote."""
    return Path(path).is_dir() and (Path(path) / "sweep.json").is_file()


def nearest_existing(path: Path) -> Path:
    """``path`` itself if it exists, else its closest existing ancestor."""
    p = Path(os.path.abspath(path))
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _probe(folder: Path, label: str, target: Path) -> None:
    """Create and remove a temporary file in ``folder``; raise OutputError if we cannot."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=".qpatrol-probe-", suffix=".tmp", dir=folder)
    except OSError as e:
        why = e.strerror or type(e).__name__
        raise OutputError(f"{label} {target}: cannot write in {folder} ({why})") from None
    os.close(fd)
    os.unlink(tmp)


def check_writable_dir(path: str | Path, label: str = "--out", inside: bool = False) -> None:
    """Check that folder ``path`` can be created (or, with ``inside``, written into).

    Raises:
        OutputError: an ancestor is a file, ``path`` is a file, or the folder that would
            hold it is not writable (read-only, no permission, ...).
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise OutputError(f"{label} {p}: exists and is not a folder; choose another path")
    anc = nearest_existing(p)
    if not anc.is_dir():
        raise OutputError(f"{label} {p}: {anc} is a file, not a folder")
    if anc == Path(os.path.abspath(p)):  # p exists
        if inside:
            _probe(anc, label, p)
        parent = anc.parent
        _probe(parent if parent.is_dir() else anc, label, p)
    else:
        _probe(anc, label, p)


def check_writable_file(path: str | Path, label: str = "--out") -> None:
    """Check that file ``path`` can be written (created or replaced)."""
    p = Path(path)
    if p.is_dir():
        raise OutputError(f"{label} {p}: is a folder; give a file name")
    anc = nearest_existing(p.parent)
    if not anc.is_dir():
        raise OutputError(f"{label} {p}: {anc} is a file, not a folder")
    _probe(anc, label, p)


def check_run_target(path: str | Path, force: bool, label: str = "--out") -> None:
    """Check the output folder of ``train``: writable, and replaceable only with ``force``
    and only if it is a run folder."""
    p = Path(path)
    if p.exists() or p.is_symlink():
        if not force:
            raise OutputError(
                f"{p} already exists; pass --force to replace it or --out to choose another"
            )
        if p.is_symlink() or not is_run_folder(p):
            what = "a file" if not p.is_dir() else "a folder qpatrol did not write"
            raise OutputError(
                f"{label} {p}: {what} (no meta.json or summary.json); --force replaces only "
                "qpatrol run folders; choose another --out"
            )
    check_writable_dir(p, label)


def check_sweep_target(path: str | Path, force: bool, label: str = "--out") -> None:
    """Check a sweep folder: writable; with ``force``, only a sweep folder or an empty one."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise OutputError(f"{label} {p}: exists and is not a folder; choose another path")
    if force and p.is_dir() and not is_sweep_folder(p) and any(p.iterdir()):
        raise OutputError(
            f"{label} {p}: a folder qpatrol did not write (no sweep.json); --force starts over "
            "only in sweep folders; choose another --out"
        )
    check_writable_dir(p, label, inside=True)
