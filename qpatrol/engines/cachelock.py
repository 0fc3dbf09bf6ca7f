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

:func:`install` also makes two processes that need the same function compiled take
turns: :meth:`numba.core.dispatcher.Dispatcher.compile` holds an exclusive ``flock`` on a
second lock file next to the function's index while it compiles a signature it does not
have yet, so the second process, once it has the lock, loads what the first saved
instead of compiling it again (parallel test workers on an empty cache otherwise compile
every function of the compiled loop twice). A compile that needs a callee compiled takes
the callee's lock while holding its own; callers come before callees and no compiled
function calls itself through another, so the waits cannot form a circle.
"""

from __future__ import annotations

import contextlib
import os
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
    _serialize_compiles(fcntl)
    _installed = True
    return True


def _serialize_compiles(fcntl) -> None:
    """Wrap ``Dispatcher.compile`` with the per-function compile lock (module doc)."""
    try:
        from numba.core import sigutils
        from numba.core.dispatcher import Dispatcher
    except ImportError:
        return
    compile_ = Dispatcher.compile
    held: set[str] = set()  # index paths whose lock this process holds (re-entry)

    def compile_in_turn(self, sig):
        cache_file = getattr(getattr(self, "_cache", None), "_cache_file", None)
        index = getattr(cache_file, "_index_path", None)
        if not isinstance(index, str) or index in held:
            return compile_(self, sig)
        with contextlib.suppress(Exception):
            args, _ = sigutils.normalize_signature(sig)
            if tuple(args) in self.overloads:  # compiled already: nothing to wait for
                return compile_(self, sig)
        try:
            os.makedirs(os.path.dirname(index), exist_ok=True)
            lock = open(index + ".compile.lock", "ab")  # closed below: releases the flock
        except OSError:
            return compile_(self, sig)
        with lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            held.add(index)
            try:
                return compile_(self, sig)
            finally:
                held.discard(index)

    Dispatcher.compile = compile_in_turn
