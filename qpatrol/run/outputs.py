"""Output paths, checked before any work starts.

Every command that writes calls one of these checks first, so an output that cannot
be written is found out in a fraction of a second, with one line, instead of after the
simulation. ``--force`` removes only what qpatrol wrote itself: the files a folder's
``manifest.json`` lists (:mod:`qpatrol.util.manifest`), and nothing when the folder
holds anything else, a file, a link or someone else's folder.
"""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Iterable
from pathlib import Path

from qpatrol.config import ConfigError
from qpatrol.util import inputs, manifest


class OutputError(ConfigError):
    """An output path that cannot or must not be written; the message is one line."""


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
    kind = inputs.not_a_file(p)  # a device or FIFO is never replaced by the renamed output
    if kind is not None:
        raise OutputError(f"{label} {p}: is {kind}; give the name of a file to write")
    anc = nearest_existing(p.parent)
    if not anc.is_dir():
        raise OutputError(f"{label} {p}: {anc} is a file, not a folder")
    _probe(anc, label, p)


def check_replaceable(
    path: str | Path,
    kinds: tuple[str, ...],
    label: str = "--out",
    what: str = "folder",
    also: Iterable[str] = (),
    hint: str = "",
    shown: str | Path | None = None,
) -> manifest.Manifest:
    """Check that ``--force`` may remove folder ``path``: qpatrol wrote it (its
    ``manifest.json`` is of one of ``kinds``) and it holds nothing else (but ``also``:
    entries its manifest does not list that qpatrol wrote all the same, see
    :func:`qpatrol.util.manifest.strays`). Messages name ``shown`` (default ``path``).

    Raises:
        OutputError: one line naming the first file or folder qpatrol did not write.
    """
    p = Path(path)
    name = shown if shown is not None else p
    keep = hint or (
        f"--force removes only what qpatrol wrote; move it away or choose another {label}"
    )
    if p.is_symlink() or not p.is_dir():
        raise OutputError(f"{label} {name}: {_kind_of(p)}, not a {what} qpatrol wrote; {keep}")
    try:
        m = manifest.read(p)
        if m is None:
            raise OutputError(
                f"{label} {name}: has no {manifest.MANIFEST_FILE}, so qpatrol did not write it "
                f"(or a version that kept none did); {keep}"
            )
        if m.kind not in kinds:
            raise OutputError(f"{label} {name}: a {m.kind} folder, not a {what}; {keep}")
        extra = manifest.strays(p, also=also)
    except manifest.ManifestError as e:
        raise OutputError(f"{label} {name}: {e}; {keep}") from None
    if extra:
        raise OutputError(f"{label} {name}: holds {extra[0]}, which qpatrol did not write; {keep}")
    return m


def _kind_of(p: Path) -> str:
    """What a path that is not a plain folder is, in a few words."""
    if p.is_symlink():
        return "a symbolic link"
    try:
        mode = p.stat().st_mode
    except OSError:
        return "not readable"
    return "a file" if stat.S_ISREG(mode) else inputs.kind_of(mode)


def check_out_path(path: str | Path, label: str = "--out") -> None:
    """Refuse output folder paths that can never be a qpatrol folder: empty, the root,
    the current folder, or an existing non-folder."""
    text = str(path)
    if text.strip() == "":
        raise OutputError(f"{label}: empty; give a folder path")
    p = Path(os.path.abspath(text))
    if p == p.parent:
        raise OutputError(f"{label} {text}: the root folder; give a folder of its own")
    if p == Path(os.path.abspath(".")):
        raise OutputError(f"{label} {text}: the current folder; give a folder of its own")
    if (Path(text).exists() or Path(text).is_symlink()) and not Path(text).is_dir():
        raise OutputError(
            f"{label} {text}: exists and is {_kind_of(Path(text))}, not a folder; "
            "choose another path"
        )


def check_run_target(path: str | Path, force: bool, label: str = "--out") -> None:
    """Check the output folder of ``train``: writable, and replaceable only with ``force``
    and only if qpatrol wrote it and it holds nothing else."""
    p = Path(path)
    check_out_path(p, label)
    if p.exists() or p.is_symlink():
        if not force:
            raise OutputError(
                f"{p} already exists; pass --force to replace it or --out to choose another"
            )
        check_replaceable(p, ("run",), label, "run folder")
    check_writable_dir(p, label)


def check_sweep_target(
    path: str | Path, force: bool, label: str = "--out", also: Iterable[str] = ()
) -> None:
    """Check a sweep folder: a path for a folder, writable; one that exists and is not
    empty must be a sweep folder qpatrol wrote holding nothing else (resumed, or with
    ``force`` started over)."""
    p = Path(path)
    check_out_path(p, label)
    if p.is_dir() and any(p.iterdir()):
        hint = (
            "a sweep writes only into a new or empty folder or one of its own (which "
            f"--force starts over); choose another {label}"
        )
        check_replaceable(p, ("sweep",), label, "sweep folder", also, hint)
    check_writable_dir(p, label, inside=True)


def replace_written(old: Path) -> None:
    """``discard`` of :func:`qpatrol.util.atomic.staged_dir` for qpatrol folders: removes
    what the manifest lists, nothing else."""
    manifest.remove(old)


def check_files(
    paths: Iterable[str | Path],
    force: bool,
    label: str = "--out",
    same: dict[Path, bytes] | None = None,
) -> None:
    """Check the files a command is about to write: each is new, or listed unchanged in
    the ``manifest.json`` of its folder (qpatrol wrote it as it is), or holds exactly
    the bytes ``same`` says it will get (nothing is lost), or ``force`` allows replacing
    it. A folder or a non-file in the way is refused even with ``force``."""
    for path in paths:
        p = Path(path)
        check_writable_file(p, label)
        if not (p.exists() or p.is_symlink()) or force:
            continue
        want = (same or {}).get(p)
        if want is not None and not p.is_symlink() and p.stat().st_size == len(want):
            if p.read_bytes() == want:
                continue
        try:
            m = manifest.read(p.parent)
        except manifest.ManifestError:
            m = None
        entry = m.files.get(p.name) if m is not None else None
        if entry is None or p.is_symlink() or manifest.file_entry(p) != entry:
            why = (
                "qpatrol did not write it"
                if entry is None
                else "it was changed after qpatrol wrote it"
            )
            raise OutputError(
                f"{label} {p}: already exists and {why}; pass --force to replace it or "
                f"choose another {label}"
            )


def record_files(
    folder: str | Path, names: Iterable[str], fresh: bool, kind: str = "figures"
) -> None:
    """After writing ``names`` in ``folder``: list them in its manifest if it has one, or
    start one (of ``kind``) if the folder was new or empty before (``fresh``); a folder
    of someone else's gets no manifest."""
    try:
        if manifest.read(folder) is None and not fresh:
            return
        manifest.add(folder, kind, names)
    except manifest.ManifestError:
        return


def is_fresh(folder: str | Path) -> bool:
    """True when ``folder`` does not exist or is empty (qpatrol may start a manifest)."""
    p = Path(folder)
    return not p.exists() or (p.is_dir() and not any(p.iterdir()))
