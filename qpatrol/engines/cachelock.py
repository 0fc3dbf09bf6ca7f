"""Processes that share numba's on-disk cache write it one at a time.

numba's cache (``njit(cache=True)``) keeps, per function, an index (signature -> data
file) and numbered data files. Saving a new signature reads the index, picks the first
free number, writes the index, then the data file, with no lock between processes. Two
processes that finish compiling two signatures of one function at about the same time
(the compiled loop's specializations ``numba_core.SPEC_*`` are signatures of one
function) can both pick the same number: the index then names, for one signature, the
data file of the other, and a later process loads the other signature's machine code
(seen with four processes compiling four signatures of a toy function on an empty
cache: in one start of fifteen, a signature's call returned another signature's result).

:func:`install` makes numba's cache file object hold a ``flock`` on a lock file next to
the function's index while it saves an entry (exclusive: index and data written
together) or loads one (shared: index and data read together). Compiling is not
serialized: processes still compile different signatures side by side, and two that
compile the same one both save the same bytes. Uses numba's private cache class;
without it (another numba version) or where the lock file cannot be opened, the cache
works as before.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

_installed = False


def install() -> bool:
    """Wrap the save and load of numba's cache files with the lock (once per process);
    False when numba (or ``fcntl``) is missing."""
    global _installed
    if _installed:
        return True
    try:
        import fcntl

        from numba.core.caching import IndexDataCacheFile
    except ImportError:
        return False
    save, load = IndexDataCacheFile.save, IndexDataCacheFile.load

    @contextlib.contextmanager
    def locked(cache_file, how: int) -> Iterator[None]:
        index = getattr(cache_file, "_index_path", None)
        lock = None
        if isinstance(index, str):
            with contextlib.suppress(OSError):  # no folder yet (nothing saved), read-only
                lock = open(index + ".lock", "ab")  # closed below: releases the flock
        if lock is None:
            yield
            return
        with lock:
            fcntl.flock(lock, how)
            yield

    def locked_save(self, key, data):
        with locked(self, fcntl.LOCK_EX):
            return save(self, key, data)

    def locked_load(self, key):
        with locked(self, fcntl.LOCK_SH):
            return load(self, key)

    IndexDataCacheFile.save, IndexDataCacheFile.load = locked_save, locked_load
    _installed = True
    return True
