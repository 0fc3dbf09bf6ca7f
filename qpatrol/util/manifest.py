"""What qpatrol wrote in a folder: ``manifest.json``.

Every folder qpatrol writes (a run folder, a sweep point, a sweep, a reproduction, a
folder of figures) carries a manifest of the files it wrote there::

    {"format": "qpatrol-manifest/1",
     "kind": "run",                  run, sweep, reproduction, figures or references
     "qpatrol": "0.1.0",             the version that wrote the folder
     "config": "9f2c...",            sha256 of what the folder was computed from
                                     (a run: its config.yaml; a sweep: its description,
                                     as in sweep.json), or null
     "files": {"episodes.csv": {"size": 5123, "sha256": "..."}, ...},
     "provenance": ["meta.json"],
     "folders": ["points/gamma=0.1", ...]}

``files`` holds every file qpatrol wrote there (paths relative to the folder, with
``/``), ``provenance`` the files it wrote whose content changes from one rerun to the
next (``meta.json``: times, the command line), listed without a hash so that the
manifest of a rerun is byte-identical, and ``folders`` the folders inside it that
qpatrol wrote and that carry their own manifest.

The manifest decides what ``--force`` may remove (:func:`remove`: exactly the listed
files and folders, and nothing at all when the folder holds anything else,
:func:`strays`) and whether a result may be reused (:func:`changed`: a listed file
whose size or hash is no longer the one qpatrol wrote). Besides the listed entries, a
folder may hold qpatrol's unfinished temporary files (``.NAME.*.tmp``, left by a killed
process), which count as qpatrol's.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from qpatrol import __version__
from qpatrol.util import atomic

MANIFEST_FILE = "manifest.json"
FORMAT = "qpatrol-manifest/1"
KINDS = ("run", "sweep", "reproduction", "figures", "references")
#: a manifest larger than this is not one qpatrol wrote (bytes)
MAX_BYTES = 64 * 2**20


class ManifestError(ValueError):
    """A ``manifest.json`` that cannot be read or is not a qpatrol manifest."""


@dataclass
class Manifest:
    """A folder's manifest (see the module docstring for the fields)."""

    kind: str
    qpatrol: str = __version__
    config: str | None = None
    files: dict[str, dict[str, Any]] = field(default_factory=dict)
    folders: list[str] = field(default_factory=list)
    provenance: list[str] = field(default_factory=list)

    def to_json(self) -> str:
        doc = {
            "format": FORMAT,
            "kind": self.kind,
            "qpatrol": self.qpatrol,
            "config": self.config,
            "files": {k: self.files[k] for k in sorted(self.files)},
            "provenance": sorted(set(self.provenance)),
            "folders": sorted(set(self.folders)),
        }
        return json.dumps(doc, indent=1) + "\n"


def file_entry(path: str | Path) -> dict[str, Any]:
    """``{"size", "sha256"}`` of a file."""
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
            size += len(block)
    return {"size": size, "sha256": h.hexdigest()}


def text_digest(text: str | bytes) -> str:
    """sha256 of a text (what ``config`` holds)."""
    data = text.encode("utf-8") if isinstance(text, str) else text
    return hashlib.sha256(data).hexdigest()


def read(folder: str | Path) -> Manifest | None:
    """The manifest of ``folder``, or None when it has none.

    Raises:
        ManifestError: ``manifest.json`` is there but unreadable, too large, or not a
            qpatrol manifest.
    """
    path = Path(folder) / MANIFEST_FILE
    if not path.exists() and not path.is_symlink():
        return None
    if path.is_symlink() or not path.is_file():
        raise ManifestError(f"{path}: not a file qpatrol wrote")
    try:
        if path.stat().st_size > MAX_BYTES:
            raise ManifestError(f"{path}: larger than any manifest qpatrol writes")
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as e:
        if isinstance(e, ManifestError):
            raise
        raise ManifestError(f"{path}: unreadable ({type(e).__name__})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ManifestError(f"{path}: not a qpatrol manifest")
    files, folders = doc.get("files"), doc.get("folders")
    prov = doc.get("provenance", [])
    ok = (
        doc.get("kind") in KINDS
        and isinstance(doc.get("qpatrol"), str)
        and (doc.get("config") is None or isinstance(doc.get("config"), str))
        and isinstance(files, dict)
        and all(
            _safe(k)
            and isinstance(v, dict)
            and isinstance(v.get("size"), int)
            and isinstance(v.get("sha256"), str)
            for k, v in files.items()
        )
        and isinstance(folders, list)
        and all(isinstance(d, str) and _safe(d) for d in folders)
        and isinstance(prov, list)
        and all(isinstance(d, str) and _safe(d) for d in prov)
    )
    if not ok:
        raise ManifestError(f"{path}: not a qpatrol manifest (malformed fields)")
    return Manifest(doc["kind"], doc["qpatrol"], doc.get("config"), files, folders, prov)


def _safe(rel: str) -> bool:
    """A relative path inside the folder: no ``..``, not absolute, not the manifest."""
    parts = rel.split("/")
    return (
        bool(rel)
        and not rel.startswith("/")
        and all(p not in ("", ".", "..") for p in parts)
        and rel != MANIFEST_FILE
    )


def write(
    folder: str | Path,
    kind: str,
    files: Iterable[str],
    folders: Iterable[str] = (),
    config: str | None = None,
    known: dict[str, dict[str, Any]] | None = None,
    provenance: Iterable[str] = (),
) -> Manifest:
    """Write ``folder``'s manifest (atomically), hashing each of ``files`` (relative
    paths) that exists; ``known`` gives entries already hashed (taken as they are);
    ``provenance`` files (that exist) are listed without a hash. Files and folders that
    are gone are left out."""
    folder = Path(folder)
    known = known or {}
    files, folders, provenance = list(files), list(folders), list(provenance)
    is_file, is_dir = _present(folder, [*files, *folders, *provenance])
    prov = [rel for rel in provenance if rel in is_file]
    entries: dict[str, dict[str, Any]] = {}
    for rel in files:
        if rel in prov:
            continue
        if rel in is_file:
            entries[rel] = known[rel] if rel in known else file_entry(folder / rel)
    dirs = [d for d in folders if d in is_dir]
    m = Manifest(kind, __version__, config, entries, dirs, prov)
    atomic.write_text(folder / MANIFEST_FILE, m.to_json())
    return m


def _present(folder: Path, rels: Iterable[str]) -> tuple[set[str], set[str]]:
    """``(files, folders)``: those of ``rels`` (paths relative to ``folder``, with ``/``)
    that are a file, or a folder, now (symbolic links followed, as ``Path.is_file``
    does). One listing per parent folder, not a ``stat`` per path: a sweep's manifest
    lists every point, and is written again as each point finishes."""
    by_parent: dict[str, set[str]] = {}
    for rel in rels:
        parent, _, name = rel.rpartition("/")
        by_parent.setdefault(parent, set()).add(name)
    files: set[str] = set()
    dirs: set[str] = set()
    for parent, names in by_parent.items():
        try:
            with os.scandir(folder / parent if parent else folder) as listing:
                for e in listing:
                    if e.name not in names:
                        continue
                    rel = f"{parent}/{e.name}" if parent else e.name
                    try:
                        if e.is_file():
                            files.add(rel)
                        elif e.is_dir():
                            dirs.add(rel)
                    except OSError:
                        pass
        except (FileNotFoundError, NotADirectoryError):
            pass
    return files, dirs


def add(
    folder: str | Path,
    kind: str,
    files: Iterable[str] = (),
    folders: Iterable[str] = (),
    config: str | None = None,
    provenance: Iterable[str] = (),
) -> Manifest:
    """List ``files`` (hashed anew), ``folders`` and ``provenance`` files in ``folder``'s
    manifest, keeping what it listed before (but entries that are gone); a folder
    without a manifest gets one of ``kind``. ``config`` replaces the recorded one when
    given."""
    folder = Path(folder)
    old = read(folder)
    files = list(files)
    known = {k: v for k, v in (old.files if old else {}).items() if k not in files}
    return write(
        folder,
        old.kind if old is not None else kind,
        [*known, *files],
        [*(old.folders if old is not None else ()), *folders],
        config if config is not None else (old.config if old is not None else None),
        known,
        [*(old.provenance if old is not None else ()), *provenance],
    )


def seal(
    folder: str | Path, kind: str, config: str | None = None, provenance: Iterable[str] = ()
) -> Manifest:
    """Write the manifest of a folder qpatrol has just written whole: every file in it
    is listed (``provenance`` ones without a hash), every subfolder with a manifest of
    its own is listed as a folder."""
    folder = Path(folder)
    files: list[str] = []
    folders: list[str] = []
    for root, dirs, names in os.walk(folder):
        rel_root = Path(root).relative_to(folder)
        for d in list(dirs):
            if (Path(root) / d / MANIFEST_FILE).is_file():
                folders.append((rel_root / d).as_posix())
                dirs.remove(d)
        for n in names:
            rel = (rel_root / n).as_posix()
            if rel != MANIFEST_FILE and not _is_tmp(n):
                files.append(rel)
    return write(folder, kind, files, folders, config, provenance=provenance)


def _is_tmp(name: str) -> bool:
    """qpatrol's own temporary file or folder name (``.NAME.*.tmp``, see util.atomic)."""
    return name.startswith(".") and ".tmp" in name


def strays(folder: str | Path, limit: int = 1, also: Iterable[str] = ()) -> list[str]:
    """Paths in ``folder`` (relative) that qpatrol did not write, at most ``limit``.

    A folder without a manifest is all strays (the folder itself: ``"."``). Nested
    folders are checked against their own manifests. ``also`` names entries the
    manifest does not list that count as qpatrol's all the same (files, or folders
    with a manifest of their own, e.g. a sweep point that finished just before its
    sweep was killed). Raises :class:`ManifestError` for a damaged manifest.
    """
    folder = Path(folder)
    found: list[str] = []
    _strays(folder, "", found, limit, set(also))
    return found


def _strays(folder: Path, prefix: str, found: list[str], limit: int, also: set[str]) -> None:
    m = read(folder)
    if m is None:
        found.append(prefix.rstrip("/") or ".")
        return
    listed = set(m.files) | set(m.provenance) | {a for a in also if (folder / a).is_file()}
    nested = set(m.folders) | {a for a in also if (folder / a).is_dir()}
    parents = {p.as_posix() for rel in [*listed, *nested] for p in Path(rel).parents}
    for root, dirs, names in os.walk(folder):
        rel_root = Path(root).relative_to(folder).as_posix()
        rel_root = "" if rel_root == "." else rel_root + "/"
        for d in sorted(dirs):
            rel = rel_root + d
            full = Path(root) / d
            if full.is_symlink():
                found.append(prefix + rel)
            elif rel in nested:
                _strays(full, prefix + rel + "/", found, limit, set())
            elif rel not in parents and not _is_tmp(d):
                found.append(prefix + rel)
            if len(found) >= limit:
                return
        dirs[:] = [
            d for d in dirs if (rel_root + d) in parents and not (Path(root) / d).is_symlink()
        ]
        for n in sorted(names):
            rel = rel_root + n
            full = Path(root) / n
            if rel == MANIFEST_FILE or (_is_tmp(n) and not full.is_symlink()):
                continue
            if rel not in listed or full.is_symlink() or not full.is_file():
                found.append(prefix + rel)
                if len(found) >= limit:
                    return


def changed(folder: str | Path, limit: int = 1, nested: bool = True) -> list[str]:
    """Listed files (relative) whose size or hash is not what qpatrol wrote, or that are
    gone, at most ``limit``; with ``nested``, those of nested folders too. Raises
    :class:`ManifestError`."""
    folder = Path(folder)
    found: list[str] = []
    _changed(folder, "", found, limit, nested)
    return found


def _changed(folder: Path, prefix: str, found: list[str], limit: int, nested: bool) -> None:
    m = read(folder)
    if m is None:
        found.append(prefix.rstrip("/") or ".")
        return
    for rel, want in sorted(m.files.items()):
        path = folder / rel
        try:
            ok = path.is_file() and not path.is_symlink() and path.stat().st_size == want["size"]
            ok = ok and file_entry(path)["sha256"] == want["sha256"]
        except OSError:
            ok = False
        if not ok:
            found.append(prefix + rel)
            if len(found) >= limit:
                return
    for d in sorted(m.folders) if nested else ():
        if not (folder / d).exists():
            continue  # a nested folder removed whole: nothing of it to reuse
        _changed(folder / d, prefix + d + "/", found, limit, nested)
        if len(found) >= limit:
            return


def remove(folder: str | Path, keep: Iterable[str] = ()) -> None:
    """Remove what qpatrol wrote in ``folder``: its listed files (but ``keep``), its
    nested qpatrol folders, its temporary files, its manifest, then the folders left
    empty (``folder`` itself included). Call only after :func:`strays` found nothing; a
    file that is not listed is never removed, whatever happened in between."""
    folder = Path(folder)
    m = read(folder)
    if m is None:
        return
    kept = set(keep)
    for rel in [*m.files, *m.provenance]:
        if rel in kept:
            continue
        p = folder / rel
        if p.is_file() or p.is_symlink():
            p.unlink(missing_ok=True)
    for d in m.folders:
        if (folder / d).is_dir() and not (folder / d).is_symlink():
            remove(folder / d)
    for root, dirs, names in os.walk(folder, topdown=False):
        for n in names:
            if _is_tmp(n) and not (Path(root) / n).is_symlink():
                (Path(root) / n).unlink(missing_ok=True)
        for d in dirs:
            p = Path(root) / d
            if _is_tmp(d) and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
    (folder / MANIFEST_FILE).unlink(missing_ok=True)
    for root, dirs, _ in os.walk(folder, topdown=False):
        for d in dirs:
            _rmdir(Path(root) / d)
    _rmdir(folder)


def _rmdir(path: Path) -> None:
    try:
        if not path.is_symlink():
            path.rmdir()
    except OSError:
        pass  # not empty: something qpatrol did not write is there; it stays
