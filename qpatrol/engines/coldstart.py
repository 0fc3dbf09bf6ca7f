"""Cold start: ``engine: auto`` before numba's cache holds the compiled loop a batch needs.

Each loop of the compiled engine (:func:`qpatrol.engines.compiled_loop`) is compiled on
its first use, 11 to 124 s of CPU here, and kept in numba's on-disk cache; a warm run loads it
in under a second. A fresh install has an empty cache, and a small batch (the paper's
default experiment takes about 3 s on the numpy engine) would wait for the compile.
So ``engine: auto`` runs a batch on the numpy engine when its loop is not cached yet
and the numpy engine would finish sooner than the compile (:func:`numpy_seconds`
against :func:`compile_seconds`), and starts a background process that compiles the
loop into the cache (:func:`warm_in_background`), so the next run is compiled. Both
engines write the same files to the bit: a wrong guess costs time, never a number.

Whether a loop is cached (:func:`cached`) is read from numba's own cache index: after a
compiled run, :func:`record` writes a marker next to numba's cache files naming the
signatures that the run compiled or loaded (per dispatcher of
:mod:`qpatrol.engines`); the loop counts as cached when numba's index of each of those
dispatchers (which numba empties when a source file changes,
:func:`qpatrol.engines.compiled.key_cache`) lists each of them. An emptied cache folder
takes the marker with it.
"""

from __future__ import annotations

import functools
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from qpatrol.config import Config

#: The numpy engine's CPU time per team step, ``(fixed, per robot, per agent-step)``
#: microseconds (:mod:`qpatrol.engines.numpy_loop`: the general step, the one it has).
#: It advances every run of a batch at once, so a step costs ``fixed + per robot *
#: agents + per agent-step * runs * agents``. Measured with ``benchmarks/cold_start.py
#: --rates`` (map_a, 1,000 steps, 1, 32 and 256 runs, CPU time); the numbers are those of
#: its costlier cases (teams with the battery's rules; ``qlearning-idleness``), so that
#: the estimate errs towards compiling, the choice made before a cache was looked at.
NUMPY_US: tuple[float, float, float] = (250.0, 120.0, 2.6)

#: CPU seconds to compile each loop into an empty cache (fresh process, the loop run
#: for a few steps), measured with ``benchmarks/cold_start.py --compile`` on this
#: project's 2-core machine (6 December 2026, other work running at low priority):
#: 123.5, 25.7, 10.7 and 20.4 s.
COMPILE_SECONDS: dict[str, float] = {
    "any": 124.0,
    "qlearning": 26.0,
    "qlearning-solo": 11.0,
    "qlearning-team": 20.0,
}

#: Seconds a lock file of a loop being compiled (:func:`warm_in_background`) is
#: trusted without its process: older ones are left over from a killed process.
LOCK_STALE = 600.0

#: How the note of a batch run on numpy for a cold cache begins.
COLD = "auto: compiled loop"
MARKER = "qpatrol-loop-{}.json"
LOCK = "qpatrol-loop-{}.lock"


def numpy_seconds(cfg: Config, rows: int | None = None) -> float:
    """Estimated CPU seconds of ``cfg``'s time loop on the numpy engine (``rows``: the
    batch's runs, default ``cfg['runs']``): :data:`NUMPY_US`, and the strategy's own
    cost per robot-step and cell (:attr:`qpatrol.strategies.base.Strategy.numpy_cell_us`:
    8 `dta-ssi-part` robots on facility take 12 times the world's step)."""
    from qpatrol.strategies import strategy_class

    fixed, per_robot, per = NUMPY_US
    k = cfg["agents"]
    size = (cfg["runs"] if rows is None else rows) * k
    per_cell = strategy_class(cfg["policy"]).numpy_cell_us
    if per_cell:
        per += per_cell * _cells(cfg["map"])
    return cfg["steps"] * (fixed + per_robot * k + per * size) * 1e-6


@functools.lru_cache(maxsize=64)
def _cells(name: str) -> int:
    """Free cells of map ``name`` (a name or a file), 0 if it cannot be read."""
    from qpatrol.maps import get_map

    try:
        return get_map(name).n_cells
    except Exception:  # (a config error is reported where the map is loaded)
        return 0


def compile_seconds(loop: str) -> float:
    """Estimated CPU seconds to compile ``loop`` into an empty cache."""
    return COMPILE_SECONDS.get(loop, max(COMPILE_SECONDS.values()))


#: Estimated numpy CPU seconds of all the batches of each compiled loop that the pool
#: this process works for will run (:func:`set_pool_work`); empty outside a pool.
_pool_work: dict[str, float] = {}


def set_pool_work(work: Mapping[str, float] | None) -> None:
    """Tell this process the numpy seconds of all the batches of each loop its pool
    (a sweep's, ``reproduce``'s) will run (:func:`pool_work`): a loop worth compiling
    for the pool's batches together is compiled, not dodged batch after batch."""
    global _pool_work
    _pool_work = dict(work or {})


def pool_work(batches: Iterable[tuple[Config, str | None]]) -> dict[str, float]:
    """Estimated numpy seconds per compiled loop of ``(config, loop)`` batches (loop
    None: a batch the numpy engine runs anyway), counting ``engine: auto`` ones only."""
    work: dict[str, float] = {}
    for cfg, loop in batches:
        if loop is not None and cfg["engine"] == "auto":
            work[loop] = work.get(loop, 0.0) + numpy_seconds(cfg)
    return work


def cold_note(
    cfg: Config, loop: str, rows: int | None = None, folder: Path | None = None
) -> str | None:
    """Why ``engine: auto`` runs ``cfg`` on numpy although its ``loop`` is compiled
    (None: it does not, the compiled engine runs it): the loop is not in numba's cache
    (:func:`cached`), and the numpy engine would finish sooner than compiling it: this
    batch, and the pool's batches of the loop together (:func:`set_pool_work`); or,
    while another process compiles the loop, this batch sooner than the compile's
    rest (else this one waits for it, :class:`Compiling`). ``rows``: the batch's runs
    (default ``cfg['runs']``). Reads the cache; changes nothing."""
    if cached(loop, folder=folder):
        return None
    est = numpy_seconds(cfg, rows)
    busy = _compiling_for(loop, folder)
    if busy > 0.0:
        left = max(1.0, compile_seconds(loop) - busy)
        if est >= left:
            return None
        why = f"another process compiling it, about {left:.0f} s left"
    else:
        left = compile_seconds(loop)
        if max(est, _pool_work.get(loop, 0.0)) >= left:
            return None
        why = f"compiling it about {left:.0f} s; compiling it in the background for the next run"
    return f"{COLD} {loop!r} not cached yet (numpy about {est:.0f} s, {why})"


# ------------------------------------------------------------------ numba's cache


#: :func:`dispatchers` of the modules of :mod:`qpatrol.engines` loaded so far, by their
#: names: ``(names, dispatchers)`` (scanning every module's names costs milliseconds, and
#: a sweep asks at every point).
_DISPATCHERS: tuple[tuple[str, ...], dict[str, Any]] | None = None


def dispatchers() -> dict[str, Any]:
    """The compiled engine's numba dispatchers that keep an on-disk cache, by qualified
    name (those of the modules of :mod:`qpatrol.engines` loaded so far; importing
    :mod:`qpatrol.engines.numba_core` loads them all). The same dict until another
    module of :mod:`qpatrol.engines` is loaded (do not modify it)."""
    global _DISPATCHERS
    from qpatrol.engines import numba_core  # noqa: F401  (defines them all)

    names = tuple(sorted(n for n in list(sys.modules) if n.startswith("qpatrol.engines")))
    if _DISPATCHERS is not None and _DISPATCHERS[0] == names:
        return _DISPATCHERS[1]
    from numba.core.dispatcher import Dispatcher

    out: dict[str, Any] = {}
    for name in names:
        mod = sys.modules.get(name)
        if mod is None:
            continue
        for attr, v in list(vars(mod).items()):
            if not isinstance(v, Dispatcher) or v.py_func.__module__ != name:
                continue  # (a dispatcher is counted in the module defining it)
            if hasattr(getattr(v, "_cache", None), "cache_path"):  # a NullCache has none
                out[f"{name}.{attr}"] = v
    _DISPATCHERS = (names, out)
    return out


def signatures(disp: Mapping[str, Any] | None = None) -> dict[str, set[str]]:
    """Each dispatcher's signatures compiled or loaded in this process, as text."""
    disp = dispatchers() if disp is None else disp
    return {name: {str(tuple(s)) for s in d.signatures} for name, d in disp.items()}


def cache_folder(disp: Mapping[str, Any] | None = None) -> Path:
    """The folder numba keeps the compiled engine's cache in (that of
    :mod:`qpatrol.engines.numba_core`, where the markers go)."""
    disp = dispatchers() if disp is None else disp
    for name, d in disp.items():
        if name.startswith("qpatrol.engines.numba_core."):
            return Path(d._cache.cache_path)
    return Path(next(iter(disp.values()))._cache.cache_path)


def record(
    loop: str,
    before: Mapping[str, set[str]],
    disp: Mapping[str, Any] | None = None,
    folder: Path | None = None,
) -> None:
    """After a compiled run of ``loop``: add the signatures it compiled or loaded (those
    in :func:`signatures` now and not in ``before``) to the loop's marker. Never
    raises (a marker not written costs one more cold start, not a result)."""
    try:
        disp = dispatchers() if disp is None else disp
        now = signatures(disp)
        new = {n: sorted(s - before.get(n, set())) for n, s in now.items()}
        new = {n: s for n, s in new.items() if s}
        if not new:
            return
        folder = cache_folder(disp) if folder is None else Path(folder)
        path = folder / MARKER.format(loop)
        have = _read_marker(path) or {}
        for n, s in new.items():
            have[n] = sorted(set(have.get(n, [])) | set(s))
        folder.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps({"loop": loop, "signatures": have}, indent=1) + "\n")
        os.replace(tmp, path)
    except Exception:  # noqa: BLE001  (numba's private cache objects may change)
        return


def _read_marker(path: Path) -> dict[str, list[str]] | None:
    try:
        sigs = json.loads(path.read_text())["signatures"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not isinstance(sigs, dict):
        return None
    return {str(k): [str(x) for x in v] for k, v in sigs.items()}


#: ``(loop, cache folder)`` found cached by this process (:func:`cached`): a loop once
#: in the cache stays there while the process lives, and reading numba's index of every
#: dispatcher (some 60 pickles) costs tens of milliseconds at every point of a sweep.
_CACHED: set[tuple[str, str]] = set()


def cached(loop: str, disp: Mapping[str, Any] | None = None, folder: Path | None = None) -> bool:
    """True when numba's cache holds ``loop``: its marker (:func:`record`) names
    signatures, and numba's current index of each dispatcher lists every one of them
    (an index numba would not use, of older sources or another numba, lists none).
    True too when numba's cache objects are not the ones this reads (another numba
    version): the compiled engine then runs, as without this check. A loop of the
    engine's own dispatchers (``disp`` None) found cached is not read again by this
    process."""
    own = disp is None
    try:
        disp = dispatchers() if disp is None else disp
        folder = cache_folder(disp) if folder is None else Path(folder)
    except Exception:  # noqa: BLE001
        return True
    key = (loop, str(folder))
    if own and key in _CACHED:
        return True
    if not _index_lists(loop, disp, folder):
        return False
    if own:
        _CACHED.add(key)
    return True


def _index_lists(loop: str, disp: Mapping[str, Any], folder: Path) -> bool:
    """:func:`cached`, read from the loop's marker and numba's index files."""
    sigs = _read_marker(folder / MARKER.format(loop))
    if not sigs:
        return False
    for name, want in sigs.items():
        d = disp.get(name)
        if d is None:
            return False
        try:
            index = d._cache._cache_file._load_index()
        except AttributeError:
            return True
        except Exception:  # noqa: BLE001  (an unreadable index: not cached)
            return False
        have = {str(tuple(key[0])) for key in index}
        if not set(want) <= have:
            return False
    return True


# ------------------------------------------------------------------ warming


class Compiling:
    """A compiled run of ``loop`` in this process: holds the loop's lock (when no other
    process holds it) until :meth:`done`, which records the signatures the run compiled
    or loaded (:func:`record`) and releases the lock. Call :meth:`done` once the loop's
    first call returned (it is compiled then), and again at the end (idempotent). Never
    raises: a lock or marker that could not be written costs time, never a number."""

    def __init__(self, loop: str | None):
        self.loop = loop
        self.lock: Path | None = None
        self.before: dict[str, set[str]] | None = None
        if loop is None:
            return
        try:
            self.before = signatures()
            _wait_for_others(loop)
            path = _lock_path(loop, None)
            if _compiling_for(loop) == 0.0:
                path.parent.mkdir(parents=True, exist_ok=True)  # (numba makes it later)
                path.unlink(missing_ok=True)  # a stale lock
                fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
                os.write(fd, f"{os.getpid()}\n".encode())
                os.close(fd)
                self.lock = path
        except Exception:  # noqa: BLE001
            pass

    def done(self) -> None:
        """The loop is compiled: record it, release the lock (once)."""
        if self.before is not None and self.loop is not None:
            record(self.loop, self.before)
            self.before = None
        self.release()

    def release(self) -> None:
        """Release the lock (if held), recording nothing."""
        if self.lock is not None:
            self.lock.unlink(missing_ok=True)
            self.lock = None


def _lock_path(loop: str, folder: Path | None) -> Path:
    return (cache_folder() if folder is None else Path(folder)) / LOCK.format(loop)


def _compiling_for(loop: str, folder: Path | None = None) -> float:
    """Seconds a live process has been compiling ``loop`` (0: none is)."""
    try:
        path = _lock_path(loop, folder)
        pid = int(path.read_text().split()[0])
        age = time.time() - path.stat().st_mtime
    except (OSError, ValueError, IndexError):
        return 0.0
    if age > LOCK_STALE or not _alive(pid):
        return 0.0
    return max(0.0, age)


def _wait_for_others(loop: str, poll: float = 0.25) -> float:
    """While another process compiles ``loop`` and it is not cached, wait (compiling
    it here too would take longer and cost a core): seconds waited."""
    t = time.monotonic()
    while _compiling_for(loop) > 0.0 and not cached(loop):
        time.sleep(poll)
    return time.monotonic() - t


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def warm_in_background(cfg: Config, loop: str, folder: Path | None = None) -> bool:
    """Start a process that compiles ``loop`` into numba's cache (running one run of
    ``cfg`` for a few steps on the compiled engine, writing nothing else), unless one is
    compiling it already. It runs at a lower priority, detached: this process does not
    wait for it. Returns whether one was started."""
    try:
        if _compiling_for(loop, folder) > 0.0:
            return False
        fd, name = tempfile.mkstemp(prefix="qpatrol-warm-", suffix=".json")
        with os.fdopen(fd, "w") as f:
            json.dump({"loop": loop, "config": dict(cfg.values)}, f, default=str)
        subprocess.Popen(
            [sys.executable, "-m", "qpatrol.run.warmup", name],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
            close_fds=True,
        )
        return True
    except Exception:  # noqa: BLE001  (warming is a convenience)
        return False
