"""Atomic file output: write to a temporary name beside the target, then rename.

A reader (or a resumed sweep) never sees a half-written file or folder: either the
old one, or nothing, or the complete new one.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def write_text(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (temp file in the same folder, fsync, rename)."""
    write_bytes(path, text.encode("utf-8"))


def write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@contextmanager
def staged_dir(target: str | Path, replace: bool = False) -> Iterator[Path]:
    """Yield a fresh temporary folder; on success it is renamed to ``target``.

    If the body raises, the temporary folder is removed and ``target`` is untouched.
    With ``replace``, an existing ``target`` is swapped out only after the new one is
    complete.
    """
    t = Path(target)
    t.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{t.name}.", suffix=".tmp", dir=t.parent))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)
    try:
        yield tmp
        if t.exists():
            if not replace:
                raise FileExistsError(f"{t} already exists")
            old = t.with_name(f".{t.name}.old.tmp")
            if old.exists():
                shutil.rmtree(old)
            os.replace(t, old)
            os.replace(tmp, t)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, t)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
