"""Atomic file output: write to a temporary name beside the target, then rename.

A reader (or a resumed sweep) never sees a half-written file or folder: either the
old one, or nothing, or the complete new one. Files get the usual permissions
(``0666`` less the umask, so ``0644`` by default), folders ``0777`` less the umask.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """The mode of a new file: ``0666`` less the umask."""
    return 0o666 & ~_umask()


def write_text(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (temp file in the same folder, fsync, rename)."""
    write_bytes(path, text.encode("utf-8"))


def write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically, with mode ``0666`` less the umask."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        os.fchmod(fd, file_mode())
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextmanager
def staged_file(target: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``target`` (same suffix); renamed to it on success.

    For writers that want a file name (``savefig``, ``np.savez``); the temporary file is
    removed if the body raises.
    """
    t = Path(target)
    t.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{t.stem}.", suffix=f".tmp{t.suffix}", dir=t.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, file_mode())
        os.replace(tmp_path, t)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


@contextmanager
def staged_dir(
    target: str | Path,
    replace: bool = False,
    check: Callable[[Path], None] | None = None,
    discard: Callable[[Path], None] | None = None,
) -> Iterator[Path]:
    """Yield a fresh temporary folder; on success it is renamed to ``target``.

    If the body raises, the temporary folder is removed and ``target`` is untouched.
    With ``replace``, an existing ``target`` folder is swapped out only after the new
    one is complete; a ``target`` that is not a folder is never replaced. The old
    folder is first moved aside and given to ``check`` (which raises to keep it: it is
    moved back), then, once the new one is in place, to ``discard`` (default: removed
    whole).
    """
    t = Path(target)
    t.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{t.name}.", suffix=".tmp", dir=t.parent))
    os.chmod(tmp, 0o777 & ~_umask())
    try:
        yield tmp
        if t.exists() or t.is_symlink():
            if not replace:
                raise FileExistsError(f"{t} already exists")
            if not t.is_dir() or t.is_symlink():
                raise FileExistsError(f"{t} exists and is not a folder; not replacing it")
            old = t.with_name(f".{t.name}.old.tmp")
            if old.exists() or old.is_symlink():
                _remove(old)
            os.replace(t, old)
            if check is not None:
                try:
                    check(old)
                except BaseException:
                    os.replace(old, t)
                    raise
            os.replace(tmp, t)
            (discard or _remove)(old)
        else:
            os.replace(tmp, t)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
