"""Checkpoints of a long computation: save its whole state, continue from it later.

The mechanics know nothing of the simulator: a *payload* is any picklable object
(for :func:`qpatrol.run.simulate`, the tuple of simulator state, random streams,
recorders and trajectory buffer) and a *position* is how far the computation got (the
team step). The surface is three names::

    save(obj, path)        pickle atomically (temporary file, fsync, rename)
    load(path)             read it back
    Checkpointer(folder)   decides when: every ``every`` seconds, and at once on
                           SIGINT/SIGTERM (then raises :class:`Interrupted`)

A loop uses it as::

    cp = Checkpointer(folder, every=60, key={"config": digest})
    cp.load()                      # if resuming: cp.resumed.payload / .position
    with cp.signals():
        for i in range(cp.position, total):
            ...one step...
            cp.tick(i + 1, (state, streams, recorder))
    cp.discard()                   # after the results are safely written

``key`` identifies the computation (config digest, map hash, version); a checkpoint
whose key differs is refused, so a resume never mixes two configs. A kill -9 loses at
most ``every`` seconds of work; Ctrl-C or SIGTERM lose none.
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from qpatrol.util import atomic

FORMAT = "qpatrol-checkpoint/1"
STATE_FILE = "checkpoint.pkl"
INFO_FILE = "info.json"
#: Seconds between two periodic checkpoints unless told otherwise.
DEFAULT_EVERY = 60.0


class CheckpointError(ValueError):
    """A checkpoint that cannot be used (missing, unreadable, or of another computation)."""


def save(obj: Any, path: str | Path) -> None:
    """Pickle ``obj`` to ``path`` atomically: the file is the old one or the new one.

    The pickle is streamed to a temporary file (no second copy of the state in memory),
    synced, then renamed over ``path``.
    """
    with atomic.staged_file(path) as tmp, open(tmp, "wb") as f:
        pickle.dump(obj, f, protocol=pickle.HIGHEST_PROTOCOL)
        f.flush()
        os.fsync(f.fileno())


def load(path: str | Path) -> Any:
    """Unpickle the object at ``path`` (written by :func:`save`; trusted input only)."""
    with open(path, "rb") as f:
        return pickle.load(f)


def location(out: str | Path) -> Path:
    """The checkpoint folder of an output folder: ``<out>.checkpoint`` beside it."""
    out = Path(out)
    return out.with_name(out.name + ".checkpoint")


@dataclass(frozen=True)
class Snapshot:
    """A loaded checkpoint: where the computation was and its state."""

    position: int
    payload: Any
    saved: str


class Interrupted(Exception):
    """Raised by :meth:`Checkpointer.tick` after saving, when a signal asked to stop."""

    def __init__(self, signum: int, position: int, folder: Path):
        try:
            name: object = signal.Signals(signum).name
        except ValueError:
            name = signum
        super().__init__(f"{name} at position {position}; checkpoint in {folder}")
        self.signum, self.position, self.folder = signum, position, folder


class Checkpointer:
    """Decides when to save a computation's state, and saves it.

    Args:
        folder: where the checkpoint lives (created on the first save).
        every: seconds between periodic saves (0 or less: only on a signal).
        key: JSON-able identity of the computation, checked on :meth:`load`.
        info: extra JSON-able fields written to ``info.json`` beside the state.
        clock: time source (for tests).
    """

    #: True: the loop calls :meth:`tick` after every team step. False (the default): the
    #: compiled engine calls it after each block of steps it computes at once (the
    #: blocks it runs without a checkpointer, each call at most about a second:
    #: :data:`qpatrol.run.COMPILED_CALL_SECONDS`), so a save or a stop comes at the end
    #: of that block (the numpy engine ticks after every step either way).
    every_step: bool = False

    def __init__(
        self,
        folder: str | Path,
        every: float = DEFAULT_EVERY,
        key: dict[str, Any] | None = None,
        info: dict[str, Any] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.folder = Path(folder)
        self.every = float(every)
        self.key = json.loads(json.dumps(key or {}, default=str))
        self.info = dict(info or {})
        self.clock = clock
        self.resumed: Snapshot | None = None
        self.saves = 0
        self._last = clock()
        self._signal: int | None = None

    @property
    def path(self) -> Path:
        """The pickled state file."""
        return self.folder / STATE_FILE

    @property
    def position(self) -> int:
        """Where to start: the loaded checkpoint's position, else 0."""
        return self.resumed.position if self.resumed is not None else 0

    def exists(self) -> bool:
        """True if a checkpoint has been saved in :attr:`folder`."""
        return self.path.is_file()

    def load(self) -> Snapshot:
        """Load the checkpoint in :attr:`folder` into :attr:`resumed`.

        Raises:
            CheckpointError: none there, unreadable, or saved with a different key.
        """
        if not self.exists():
            raise CheckpointError(f"{self.folder}: no checkpoint to resume from")
        try:
            blob = load(self.path)
        except Exception as e:  # pickle raises many types on a damaged file
            raise CheckpointError(f"{self.path}: unreadable checkpoint ({e})") from None
        if not isinstance(blob, dict) or blob.get("format") != FORMAT:
            raise CheckpointError(f"{self.path}: not a qpatrol checkpoint")
        if blob.get("key") != self.key:
            old = blob.get("key") or {}
            diff = [k for k in sorted(set(old) | set(self.key)) if old.get(k) != self.key.get(k)]
            raise CheckpointError(
                f"{self.folder}: the checkpoint is of a different computation (differs in "
                f"{', '.join(diff)}); resume with the same config and --set, or pass --force "
                "to start over"
            )
        self.resumed = Snapshot(int(blob["position"]), blob["payload"], str(blob.get("saved")))
        return self.resumed

    def save(self, position: int, payload: Any) -> None:
        """Save ``payload`` at ``position`` now (atomically, replacing the previous one)."""
        from qpatrol.util.provenance import now

        saved = now()
        blob = {
            "format": FORMAT,
            "key": self.key,
            "position": int(position),
            "payload": payload,
            "saved": saved,
        }
        self.folder.mkdir(parents=True, exist_ok=True)
        save(blob, self.path)
        info = {"format": FORMAT, "position": int(position), "saved": saved, **self.info}
        atomic.write_text(self.folder / INFO_FILE, json.dumps(info, indent=2, default=str) + "\n")
        self.saves += 1
        self._last = self.clock()

    def tick(self, position: int, payload: Any) -> None:
        """Call after each unit of work: saves when due, and on a pending signal saves and
        raises :class:`Interrupted`. ``payload`` is only pickled when saved."""
        if self._signal is not None:
            self.save(position, payload)
            raise Interrupted(self._signal, position, self.folder)
        if self.every > 0 and self.clock() - self._last >= self.every:
            self.save(position, payload)

    def request_stop(self, signum: int = signal.SIGINT) -> None:
        """Ask the loop to save and stop at its next :meth:`tick` (what the handlers do)."""
        self._signal = signum

    @contextmanager
    def signals(self) -> Iterator[None]:
        """While inside, SIGINT and SIGTERM make the next :meth:`tick` save and raise
        :class:`Interrupted`; a second signal interrupts at once. Does nothing outside
        the main thread (where Python cannot handle signals)."""
        if threading.current_thread() is not threading.main_thread():
            yield
            return

        def handler(signum: int, frame: Any) -> None:
            if self._signal is not None:  # a second Ctrl-C: stop now
                raise KeyboardInterrupt
            self._signal = signum

        old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield
        finally:
            for s, h in old.items():
                signal.signal(s, h)

    def discard(self) -> None:
        """Remove the checkpoint folder (after the computation's results are written)."""
        shutil.rmtree(self.folder, ignore_errors=True)
