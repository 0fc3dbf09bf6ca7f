"""Checkpoints of a long computation: save its whole state, continue from it later.

The mechanics know nothing of the simulator: a *payload* is a tree of plain data (dict,
list, tuple, str, int, float, bool, None), numpy arrays and numbers, numpy random
generators, and objects of qpatrol's own classes listed in :data:`CLASSES` (for
:func:`qpatrol.run.simulate`, the tuple of simulator state, strategy, measures, random
streams, recorders, trajectory buffer and timeline); a *position* is how far the
computation got (the team step). The surface is three names::

    save(obj, path)        write atomically: the arrays to an npz, the rest to JSON,
                           then their sha256 to the manifest ``path``
    load(path)             check the sha256, then read it back (no code of its own runs)
    Checkpointer(folder)   decides when: every ``every`` seconds, and at once on
                           SIGINT/SIGTERM (then raises :class:`Interrupted`)

A checkpoint folder holds::

    checkpoint.sha256      the manifest, in the format of ``sha256sum``: the sha256 of
                           the two parts below
    checkpoint-<h>.json    the object tree (<h>: the first 16 hex digits of its sha256)
    checkpoint-<h>.npz     its arrays, uncompressed, in numpy's format (no pickles)
    info.json              position, time and command, for people (never read back)

:func:`load` checks both parts against the manifest before it parses either, then reads
the JSON and the arrays (``allow_pickle=False``; object arrays are refused). An object
is rebuilt only for a class of :data:`CLASSES`, by ``cls.__new__(cls)`` and its
attributes (or the class's own ``__setstate__``); a random generator from its
``.state``, for a bit generator of :data:`BIT_GENERATORS`. A damaged, truncated or
incomplete checkpoint, an object array, an unknown class or format raise
:class:`CheckpointError`. A save writes new parts beside the old ones, then replaces the
manifest, then removes the old parts: a kill at any moment leaves the old checkpoint or
the new one.

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

import contextlib
import hashlib
import hmac
import importlib
import json
import math
import os
import re
import signal
import tempfile
import threading
import time
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from qpatrol.util import atomic

FORMAT = "qpatrol-checkpoint/2"
#: The manifest: its presence says a checkpoint is there.
STATE_FILE = "checkpoint.sha256"
#: The pickle older versions wrote; never read.
OLD_STATE_FILE = "checkpoint.pkl"
INFO_FILE = "info.json"
#: What to do about a checkpoint that cannot be read.
ADVICE = "resume from an intact copy of it, or pass --force to start over"
#: Seconds between two periodic checkpoints unless told otherwise.
DEFAULT_EVERY = 60.0

#: The classes whose objects a checkpoint may hold ("module:name"): qpatrol's own, and
#: no other. :func:`save` refuses any other object; :func:`load` any other tag.
CLASSES: frozenset[str] = frozenset(
    {
        "qpatrol.config:Config",
        "qpatrol.maps.core:Map",
        "qpatrol.measures:Measures",
        "qpatrol.measures.records:Recorder",
        "qpatrol.measures.records:Tail",
        "qpatrol.measures.timeline:Timeline",
        "qpatrol.world:Params",
        "qpatrol.world:State",
        "qpatrol.world.rng:KeyWords",
        "qpatrol.world.rng:RunKey",
        "qpatrol.world.rng:Streams",
        "qpatrol.strategies.cbls:Strategy",
        "qpatrol.strategies.cc:Strategy",
        "qpatrol.strategies.conscientious:Strategy",
        "qpatrol.strategies.cyclic:Strategy",
        "qpatrol.strategies.dta:Greedy",
        "qpatrol.strategies.dta:PartSSI",
        "qpatrol.strategies.dta:SSI",
        "qpatrol.strategies.evap:Strategy",
        "qpatrol.strategies.gbs:Strategy",
        "qpatrol.strategies.gravitational:Strategy",
        "qpatrol.strategies.hcr:Strategy",
        "qpatrol.strategies.hpcc:Strategy",
        "qpatrol.strategies.learned_tour:Strategy",
        "qpatrol.strategies.partition:Strategy",
        "qpatrol.strategies.qlearning:Strategy",
        "qpatrol.strategies.qlearning_idleness:Strategy",
        "qpatrol.strategies.random:Strategy",
        "qpatrol.strategies.sebs:Strategy",
        "qpatrol.strategies.shared_conscientious:Strategy",
    }
)

#: The bit generators a random ``Generator`` of a checkpoint may draw from, by name.
BIT_GENERATORS: dict[str, type[np.random.BitGenerator]] = {
    "PCG64": np.random.PCG64,
    "PCG64DXSM": np.random.PCG64DXSM,
    "MT19937": np.random.MT19937,
    "Philox": np.random.Philox,
    "SFC64": np.random.SFC64,
}

#: Array kinds a checkpoint may hold: bool, signed and unsigned int, float, complex.
ARRAY_KINDS = "biufc"
#: Arrays smaller than this many bytes share one npz member per dtype (a run may hold
#: hundreds of thousands of tiny arrays: one per step and column of a record).
SMALL_ARRAY = 1 << 16


class CheckpointError(ValueError):
    """A checkpoint that cannot be used (missing, damaged, refused, or of another
    computation)."""


# --------------------------------------------------------------------- writing


def class_tag(cls: type) -> str:
    """``"module:name"``, how a checkpoint names class ``cls``."""
    return f"{cls.__module__}:{cls.__qualname__}"


class _Encoder:
    """An object tree -> JSON-able nodes, its arrays collected in :attr:`arrays`.

    Nodes: JSON's scalars stand for themselves; the rest is a JSON object tagged by its
    first key: ``list``, ``tuple``, ``dict`` (str keys) or ``pairs`` (other keys),
    ``float`` (not finite), ``array`` (an index into the arrays), ``scalar`` (a numpy
    number), ``object`` or ``named_tuple`` (a class of :data:`CLASSES`), ``generator``,
    ``bit_generator``, ``seed_sequence``, and ``ref``: an object met before (its
    ``id``), so that shared objects stay shared and cycles close."""

    def __init__(self) -> None:
        self.arrays: list[np.ndarray] = []
        self._memo: dict[int, tuple[Any, dict[str, int]]] = {}

    def _mutable(self, o: Any) -> int:
        n = len(self._memo)
        self._memo[id(o)] = (o, {"ref": n})  # the object kept alive: ids stay unique
        return n

    def node(self, o: Any, where: str) -> Any:
        t = type(o)
        if o is None or t is bool or t is int or t is str:
            return o
        if t is float:
            return o if math.isfinite(o) else {"float": repr(o)}
        if t is tuple:
            return {"tuple": [self.node(v, f"{where}[{i}]") for i, v in enumerate(o)]}
        seen = self._memo.get(id(o))
        if seen is not None:
            return seen[1]
        if t is np.ndarray:
            if o.dtype.kind not in ARRAY_KINDS or o.dtype.fields is not None:
                raise TypeError(f"checkpoint: {where} is an array of dtype {o.dtype}")
            self._memo[id(o)] = (o, {"array": len(self.arrays)})
            self.arrays.append(o)
            return {"array": len(self.arrays) - 1}
        if isinstance(o, np.generic):
            if o.dtype.kind not in ARRAY_KINDS[:-1]:
                raise TypeError(f"checkpoint: {where} is a numpy {o.dtype}")
            return {"scalar": o.dtype.str, "value": self.node(o.item(), where)}
        if t is list:
            n = self._mutable(o)
            return {"list": [self.node(v, f"{where}[{i}]") for i, v in enumerate(o)], "id": n}
        if t is dict:
            n = self._mutable(o)
            if all(type(k) is str for k in o):
                return {"dict": {k: self.node(v, f"{where}[{k!r}]") for k, v in o.items()}, "id": n}
            items = [[self.node(k, where), self.node(v, f"{where}[{k!r}]")] for k, v in o.items()]
            return {"pairs": items, "id": n}
        if t is np.random.Generator:
            n = self._mutable(o)
            return {"generator": self.node(o.bit_generator, f"{where}.bit_generator"), "id": n}
        if t in BIT_GENERATORS.values():
            n = self._mutable(o)
            return {
                "bit_generator": t.__name__,
                "state": self.node(o.state, f"{where}.state"),
                "seed_seq": self.node(o.seed_seq, f"{where}.seed_seq"),
                "id": n,
            }
        if t is np.random.SeedSequence:
            n = self._mutable(o)
            entropy = o.entropy
            if isinstance(entropy, np.ndarray | list | tuple):
                entropy = [int(e) for e in entropy]
            return {
                "seed_sequence": {
                    "entropy": entropy,
                    "spawn_key": [int(k) for k in o.spawn_key],
                    "pool_size": int(o.pool_size),
                    "n_children_spawned": int(o.n_children_spawned),
                },
                "id": n,
            }
        tag = class_tag(t)
        if tag not in CLASSES:
            raise TypeError(f"checkpoint: {where} is a {tag}, not a class of checkpoint.CLASSES")
        if isinstance(o, tuple):
            items = [self.node(v, f"{where}[{i}]") for i, v in enumerate(o)]
            return {"named_tuple": tag, "items": items}
        n = self._mutable(o)
        state = o.__getstate__() if t.__getstate__ is not object.__getstate__ else vars(o)
        if type(state) is not dict or not all(type(k) is str for k in state):
            raise TypeError(f"checkpoint: {where}: the state of a {tag} is not a dict of names")
        attrs = {k: self.node(v, f"{where}.{k}") for k, v in state.items()}
        return {"object": tag, "state": attrs, "id": n}


def _layout(arrays: list[np.ndarray]) -> tuple[list[list[Any]], list[tuple[str, np.ndarray]]]:
    """Where each array goes in the npz: ``[member, offset, shape, order]`` per array
    (offset None: the member is the array; else its elements start there in the member,
    a 1-d pool of its dtype, laid out in ``order``), and the members to write."""
    table: list[list[Any]] = []
    members: list[tuple[str, np.ndarray]] = []
    pools: dict[str, tuple[str, list[np.ndarray], list[int]]] = {}
    for a in arrays:
        order = "F" if a.flags.f_contiguous and not a.flags.c_contiguous else "C"
        shape = [int(n) for n in a.shape]
        if a.nbytes >= SMALL_ARRAY:
            name = f"a{len(members)}"
            members.append((name, a))
            table.append([name, None, shape, order])
            continue
        key = a.dtype.str
        if key not in pools:
            pools[key] = (f"p{len(pools)}", [], [0])
        name, parts, size = pools[key]
        table.append([name, size[0], shape, order])
        parts.append(a.ravel(order=order))
        size[0] += a.size
    for key, (name, parts, _) in pools.items():
        members.append((name, np.concatenate(parts) if parts else np.zeros(0, np.dtype(key))))
    return table, members


class _Hashing:
    """A write-only, unseekable file that hashes what passes through (so a zip file is
    written and hashed in one pass)."""

    def __init__(self, f: IO[bytes]):
        self.f = f
        self.sha = hashlib.sha256()

    def write(self, data: Any) -> int:
        self.sha.update(data)
        return self.f.write(data)

    def flush(self) -> None:
        self.f.flush()


def _write_npz(f: Any, members: list[tuple[str, np.ndarray]]) -> None:
    """Uncompressed npz with fixed zip timestamps: equal arrays give equal bytes."""
    with zipfile.ZipFile(f, "w", compression=zipfile.ZIP_STORED) as zf:
        for name, arr in members:
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            with zf.open(info, "w", force_zip64=True) as out:
                np.lib.format.write_array(out, arr, allow_pickle=False)


def _write_part(folder: Path, stem: str, suffix: str, write: Callable[[Any], None]) -> str:
    """Write a part through ``write(file)`` to a temporary file, synced, then renamed to
    ``<stem>-<first 16 hex of its sha256><suffix>``; returns ``"<sha256>  <name>"``."""
    fd, tmp = tempfile.mkstemp(prefix=f".{stem}.", suffix=".tmp", dir=folder)
    try:
        os.fchmod(fd, atomic.file_mode())
        with os.fdopen(fd, "wb") as f:
            h = _Hashing(f)
            write(h)
            f.flush()
            os.fsync(f.fileno())
        digest = h.sha.hexdigest()
        name = f"{stem}-{digest[:16]}{suffix}"
        os.replace(tmp, folder / name)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return f"{digest}  {name}"


def save(obj: Any, path: str | Path) -> None:
    """Write ``obj`` as a checkpoint whose manifest is ``path`` (its parts beside it).

    The parts are written under new names (synced), the manifest is replaced atomically
    last, then parts and temporary files of earlier saves are removed: ``path`` names
    the old checkpoint or the new one, whole. Raises TypeError for an object
    :func:`load` could not rebuild (a class outside :data:`CLASSES`, an object array).
    """
    path = Path(path)
    folder, stem = path.parent, path.stem
    enc = _Encoder()
    tree = enc.node(obj, "payload")
    table, members = _layout(enc.arrays)
    doc = {"format": FORMAT, "arrays": table, "tree": tree}
    text = json.dumps(doc, separators=(",", ":"), allow_nan=False).encode("utf-8")
    folder.mkdir(parents=True, exist_ok=True)
    lines = [
        _write_part(folder, stem, ".json", lambda f: f.write(text)),
        _write_part(folder, stem, ".npz", lambda f: _write_npz(f, members)),
    ]
    atomic.write_text(path, "".join(line + "\n" for line in lines))
    keep = {line.split("  ", 1)[1] for line in lines} | {path.name}
    stale = re.compile(
        rf"{re.escape(stem)}-[0-9a-f]{{16}}\.(json|npz)|\.{re.escape(stem)}\..*\.tmp"
    )
    for p in folder.iterdir():
        if p.name not in keep and stale.fullmatch(p.name):
            p.unlink(missing_ok=True)


# --------------------------------------------------------------------- reading


def _manifest(path: Path) -> tuple[tuple[str, str], tuple[str, str]]:
    """The (sha256, name) of the JSON and of the npz part, as the manifest says."""
    try:
        with open(path, "rb") as f:
            data = f.read(1024)
    except FileNotFoundError:
        raise CheckpointError(f"{path}: no checkpoint") from None
    except OSError as e:
        raise CheckpointError(f"{path}: unreadable checkpoint ({e.strerror})") from None
    stem = re.escape(path.stem.encode())
    line = re.compile(rb"([0-9a-f]{64})  (" + stem + rb"-([0-9a-f]{16})\.(json|npz))")
    found = [line.fullmatch(x) for x in data.split(b"\n")]
    parts = [m for m in found[:-1] if m is not None]
    if len(found) != 3 or found[-1] is not None or data[-1:] != b"\n" or len(parts) != 2:
        raise CheckpointError(f"{path}: unreadable checkpoint (not a manifest of two parts)")
    if [m[4] for m in parts] != [b"json", b"npz"] or any(m[3] != m[1][:16] for m in parts):
        raise CheckpointError(f"{path}: unreadable checkpoint (not a manifest of two parts)")
    (js, jn), (ns, nn) = ((m[1].decode(), m[2].decode()) for m in parts)
    return (js, jn), (ns, nn)


def _check(f: IO[bytes], digest: str, name: str, path: Path) -> bytes:
    """Raise unless the bytes of ``f`` have sha256 ``digest``; then rewind it. Returns
    them when ``name`` is the JSON part (read whole), else b"" (the npz, streamed)."""
    sha = hashlib.sha256()
    whole = name.endswith(".json")
    data = f.read() if whole else b""
    sha.update(data)
    while not whole and (chunk := f.read(1 << 20)):
        sha.update(chunk)
    if not hmac.compare_digest(sha.hexdigest(), digest):
        raise CheckpointError(
            f"{path.parent}: damaged checkpoint ({name} does not match its sha256 in {path.name})"
        )
    f.seek(0)
    return data


def _open_part(folder: Path, name: str, manifest: Path) -> IO[bytes]:
    try:
        return open(folder / name, "rb")
    except FileNotFoundError:
        raise CheckpointError(
            f"{folder}: incomplete checkpoint ({name}, named in {manifest.name}, is missing)"
        ) from None


class _Arrays:
    """The arrays of a checkpoint's table, read from its npz on first use."""

    def __init__(self, zf: zipfile.ZipFile, table: Any, where: Path):
        if type(table) is not list:
            raise CheckpointError(f"{where}: unreadable checkpoint (no table of arrays)")
        self.zf, self.table, self.where = zf, table, where
        self._members: dict[str, np.ndarray] = {}
        self._arrays: dict[int, np.ndarray] = {}

    def _member(self, name: Any) -> np.ndarray:
        if type(name) is not str:
            raise CheckpointError(f"{self.where}: unreadable checkpoint (an array's member)")
        if name not in self._members:
            try:
                info = self.zf.getinfo(f"{name}.npy")
            except KeyError:
                raise CheckpointError(
                    f"{self.where}: unreadable checkpoint (it names array {name!r}, which its "
                    "npz does not hold)"
                ) from None
            with self.zf.open(info) as f:  # the header first: dtype, and size for the bytes
                version = np.lib.format.read_magic(f)
                if version == (1, 0):
                    shape, _, dtype = np.lib.format.read_array_header_1_0(f)
                else:
                    shape, _, dtype = np.lib.format.read_array_header_2_0(f)
                if dtype.kind not in ARRAY_KINDS or dtype.fields is not None:
                    raise CheckpointError(
                        f"{self.where}: refused checkpoint (array {name!r} has dtype {dtype}, "
                        "which a checkpoint does not hold)"
                    )
                if math.prod(shape) * dtype.itemsize != info.file_size - f.tell():
                    raise CheckpointError(
                        f"{self.where}: unreadable checkpoint (array {name!r} is not the size "
                        "its header says)"
                    )
            with self.zf.open(info) as f:
                self._members[name] = np.lib.format.read_array(f, allow_pickle=False)
        return self._members[name]

    def _entry(self, i: int) -> CheckpointError:
        return CheckpointError(f"{self.where}: unreadable checkpoint (array {i}'s entry)")

    def get(self, i: Any) -> np.ndarray:
        if type(i) is not int or not 0 <= i < len(self.table):
            raise CheckpointError(f"{self.where}: unreadable checkpoint (no array {i!r})")
        if i not in self._arrays:
            entry = self.table[i]
            if type(entry) is not list or len(entry) != 4:
                raise self._entry(i)
            name, offset, shape, order = entry
            if type(shape) is not list or any(type(n) is not int or n < 0 for n in shape):
                raise self._entry(i)
            if order not in ("C", "F"):
                raise self._entry(i)
            a = self._member(name)
            if offset is None:
                if list(a.shape) != shape:
                    raise self._entry(i)
            else:
                size = math.prod(shape)
                if type(offset) is not int or a.ndim != 1 or not 0 <= offset <= a.size - size:
                    raise self._entry(i)
                a = a[offset : offset + size].reshape(shape, order=order).copy(order=order)
            self._arrays[i] = a
        return self._arrays[i]


def _class(tag: Any, where: Path) -> type:
    """The class named ``tag``, if :data:`CLASSES` has it (nothing is imported else)."""
    if type(tag) is not str or tag not in CLASSES:
        raise CheckpointError(
            f"{where}: refused checkpoint (it holds an object of class {str(tag)[:80]!r}, "
            "not one a checkpoint may hold)"
        )
    module, _, name = tag.partition(":")
    return getattr(importlib.import_module(module), name)


class _Decoder:
    """JSON-able nodes (:class:`_Encoder`) -> the object tree."""

    def __init__(self, arrays: _Arrays, where: Path):
        self.arrays, self.where = arrays, where
        self._ids: dict[int, Any] = {}

    def _bad(self, what: str) -> CheckpointError:
        return CheckpointError(f"{self.where}: unreadable checkpoint ({what})")

    def _keep(self, x: dict, obj: Any) -> Any:
        n = x.get("id")
        if type(n) is not int or n in self._ids:
            raise self._bad("an object without a new id")
        self._ids[n] = obj
        return obj

    def _list(self, x: Any, what: str) -> list:
        if type(x) is not list:
            raise self._bad(f"{what} is not a list")
        return x

    def node(self, x: Any) -> Any:
        t = type(x)
        if x is None or t is bool or t is int or t is str or t is float:
            return x
        if t is not dict or not x:
            raise self._bad("a node of the tree")
        tag = next(iter(x))
        v = x[tag]
        if tag == "ref":
            if type(v) is not int or v not in self._ids:
                raise self._bad(f"a reference to {str(v)[:20]}, not met before")
            return self._ids[v]
        if tag == "array":
            return self.arrays.get(v)
        if tag == "tuple":
            return tuple(self.node(y) for y in self._list(v, "a tuple"))
        if tag == "list":
            out: list = self._keep(x, [])
            out.extend(self.node(y) for y in self._list(v, "a list"))
            return out
        if tag == "dict":
            if type(v) is not dict:
                raise self._bad("a dict")
            d: dict = self._keep(x, {})
            for k, y in v.items():
                d[k] = self.node(y)
            return d
        if tag == "pairs":
            d = self._keep(x, {})
            for pair in self._list(v, "a dict's pairs"):
                if type(pair) is not list or len(pair) != 2:
                    raise self._bad("a dict's pair")
                d[self.node(pair[0])] = self.node(pair[1])
            return d
        if tag == "float":
            if v not in ("nan", "inf", "-inf"):
                raise self._bad("a float")
            return float(v)
        if tag == "scalar":
            dtype = self._dtype(v)
            if dtype.kind not in ARRAY_KINDS[:-1]:
                raise self._bad("a numpy number")
            return dtype.type(self.node(x.get("value")))
        if tag == "named_tuple":
            cls = _class(v, self.where)
            if not issubclass(cls, tuple):
                raise self._bad(f"{v} is not a named tuple")
            return tuple.__new__(cls, [self.node(y) for y in self._list(x.get("items"), "items")])
        if tag == "object":
            cls = _class(v, self.where)
            if issubclass(cls, tuple):
                raise self._bad(f"{v} is a named tuple")
            obj = self._keep(x, cls.__new__(cls))
            state = x.get("state")
            if type(state) is not dict:
                raise self._bad(f"the state of a {v}")
            attrs = {k: self.node(y) for k, y in state.items()}
            if getattr(cls, "__setstate__", None) is not None:
                obj.__setstate__(attrs)  # the class's own (a class of CLASSES)
            else:
                obj.__dict__.update(attrs)
            return obj
        if tag == "generator":
            bg = self.node(v)
            if not isinstance(bg, np.random.BitGenerator):
                raise self._bad("a generator's bit generator")
            return self._keep(x, np.random.Generator(bg))
        if tag == "bit_generator":
            if v not in BIT_GENERATORS:
                raise CheckpointError(
                    f"{self.where}: refused checkpoint (bit generator {str(v)[:40]!r})"
                )
            seq = self.node(x.get("seed_seq"))
            state = self.node(x.get("state"))
            if type(state) is not dict or state.get("bit_generator") != v:
                raise self._bad(f"the state of a {v}")
            bg = BIT_GENERATORS[v](seq)
            bg.state = state
            return self._keep(x, bg)
        if tag == "seed_sequence":
            if type(v) is not dict:
                raise self._bad("a seed sequence")
            entropy = v.get("entropy")
            keys = self._list(v.get("spawn_key"), "a spawn key")
            ints = [entropy] if type(entropy) is int else entropy
            for n in [*self._list(ints, "an entropy"), *keys]:
                if type(n) is not int:
                    raise self._bad("a seed sequence")
            seq = np.random.SeedSequence(
                entropy,
                spawn_key=tuple(keys),
                pool_size=int(v.get("pool_size", 4)),
                n_children_spawned=int(v.get("n_children_spawned", 0)),
            )
            return self._keep(x, seq)
        raise self._bad(f"an unknown tag {tag[:20]!r}")

    def _dtype(self, v: Any) -> np.dtype:
        if type(v) is not str or not re.fullmatch(r"[<>|=][biufc][0-9]{1,2}", v):
            raise self._bad("a numpy number's dtype")
        return np.dtype(v)


def load(path: str | Path) -> Any:
    """The object saved by :func:`save` with manifest ``path``.

    Both parts are checked against the manifest's sha256 before either is parsed; then
    the JSON is read and the arrays (never a pickle). Raises :class:`CheckpointError`
    for a missing, truncated, damaged or refused checkpoint (an object array, a class
    outside :data:`CLASSES`, another format).
    """
    path = Path(path)
    folder = path.parent
    (js, jn), (ns, nn) = _manifest(path)
    with _open_part(folder, jn, path) as f:
        text = _check(f, js, jn, path)
    with _open_part(folder, nn, path) as f:
        _check(f, ns, nn, path)
        try:
            doc = json.loads(text, parse_constant=_no_constant)
            if type(doc) is not dict or doc.get("format") != FORMAT:
                said = doc.get("format") if type(doc) is dict else None
                raise CheckpointError(
                    f"{folder}: unreadable checkpoint (format {str(said)[:40]!r}; this qpatrol "
                    f"reads {FORMAT})"
                )
            with zipfile.ZipFile(f) as zf:
                arrays = _Arrays(zf, doc.get("arrays"), folder)
                return _Decoder(arrays, folder).node(doc.get("tree"))
        except CheckpointError:
            raise
        except (ValueError, TypeError, KeyError, AttributeError, RecursionError) as e:
            raise CheckpointError(f"{folder}: unreadable checkpoint ({_one_line(e)})") from None
        except (OSError, zipfile.BadZipFile, EOFError) as e:
            raise CheckpointError(f"{folder}: unreadable checkpoint ({_one_line(e)})") from None


def _no_constant(name: str) -> Any:
    raise ValueError(f"JSON constant {name} (a checkpoint writes none)")


def _one_line(e: BaseException) -> str:
    text = " ".join(str(e).split()) or type(e).__name__
    return text[:200]


# --------------------------------------------------------------------- checkpointer


def location(out: str | Path) -> Path:
    """The checkpoint folder of an output folder: ``<out>.checkpoint`` beside it."""
    out = Path(out)
    return out.with_name(out.name + ".checkpoint")


@dataclass(frozen=True)
class Snapshot:
    """A loaded checkpoint: where the computation was, its state, when it was saved and
    the checkpointer's ``info`` then."""

    position: int
    payload: Any
    saved: str
    info: dict[str, Any] = field(default_factory=dict)


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
        info: extra JSON-able fields saved with the state (:attr:`Snapshot.info`) and
            written to ``info.json`` beside it.
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
        """The checkpoint's manifest (:data:`STATE_FILE`)."""
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
            CheckpointError: none there (or only one of an older format, which is never
                read), damaged, refused, or saved with a different key.
        """
        if not self.exists():
            if (self.folder / OLD_STATE_FILE).exists():
                raise CheckpointError(
                    f"{self.folder}: a checkpoint of an older format ({OLD_STATE_FILE}) that "
                    "qpatrol no longer reads; pass --force to start over"
                )
            raise CheckpointError(f"{self.folder}: no checkpoint to resume from")
        try:
            blob = load(self.path)
        except CheckpointError as e:
            raise CheckpointError(f"{e}; {ADVICE}") from None
        fields = ("key", "position", "payload", "saved", "info")
        if type(blob) is not dict or sorted(blob) != sorted(fields):
            raise CheckpointError(f"{self.folder}: not a checkpoint of a Checkpointer; {ADVICE}")
        if type(blob["position"]) is not int or type(blob["info"]) is not dict:
            raise CheckpointError(f"{self.folder}: not a checkpoint of a Checkpointer; {ADVICE}")
        if blob["key"] != self.key:
            old = blob["key"] if type(blob["key"]) is dict else {}
            diff = [k for k in sorted(set(old) | set(self.key)) if old.get(k) != self.key.get(k)]
            raise CheckpointError(
                f"{self.folder}: the checkpoint is of a different computation (differs in "
                f"{', '.join(diff)}); resume with the same config and --set, or pass --force "
                "to start over"
            )
        self.resumed = Snapshot(blob["position"], blob["payload"], str(blob["saved"]), blob["info"])
        return self.resumed

    def save(self, position: int, payload: Any) -> None:
        """Save ``payload`` at ``position`` now (atomically, replacing the previous one)."""
        from qpatrol.util.provenance import now

        saved = now()
        info = json.loads(json.dumps(self.info, default=str))
        blob = {
            "key": self.key,
            "position": int(position),
            "payload": payload,
            "saved": saved,
            "info": info,
        }
        self.folder.mkdir(parents=True, exist_ok=True)
        save(blob, self.path)
        info = {"format": FORMAT, "position": int(position), "saved": saved, **info}
        atomic.write_text(self.folder / INFO_FILE, json.dumps(info, indent=2, default=str) + "\n")
        self.saves += 1
        self._last = self.clock()

    def tick(self, position: int, payload: Any) -> None:
        """Call after each unit of work: saves when due, and on a pending signal saves and
        raises :class:`Interrupted`. ``payload`` is only written out when saved."""
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
        """Remove the checkpoint folder (after the computation's results are written):
        its checkpoint files only (:func:`remove_folder`)."""
        remove_folder(self.folder)


#: The names a checkpoint folder holds: its parts, the manifest, ``info.json``, the
#: pickle of older versions, and temporary files of a save cut short.
_OWN_NAME = re.compile(
    r"(checkpoint\.sha256|checkpoint\.pkl|info\.json|checkpoint-[0-9a-f]+\.(json|npz)"
    r"|\..+\.tmp.*)"
)


def foreign(folder: str | Path) -> str | None:
    """The first entry of checkpoint folder ``folder`` that is not a checkpoint file (a
    folder, a link or another name), or None; ``folder`` itself when it is not a folder."""
    folder = Path(folder)
    if folder.is_symlink() or not folder.is_dir():
        return str(folder)
    for p in sorted(folder.iterdir()):
        if p.is_symlink() or not p.is_file() or not _OWN_NAME.fullmatch(p.name):
            return str(p)
    return None


def remove_folder(folder: str | Path) -> None:
    """Remove a checkpoint folder's checkpoint files, then the folder if that left it
    empty; anything else in it stays."""
    folder = Path(folder)
    if folder.is_symlink() or not folder.is_dir():
        return
    for p in folder.iterdir():
        if not p.is_symlink() and p.is_file() and _OWN_NAME.fullmatch(p.name):
            p.unlink(missing_ok=True)
    with contextlib.suppress(OSError):
        folder.rmdir()
