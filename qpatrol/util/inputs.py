"""Reading untrusted input files within fixed bounds, before anything large is built.

* :func:`read_capped` reads a regular file of at most a given size: a folder, a device
  (``/dev/zero``), a FIFO or a socket is refused by its kind before it is opened (a FIFO
  would block, a device never ends), and at most ``limit + 1`` bytes are ever read.
* :func:`short_repr` is a value's ``repr`` cut to about 200 characters without building
  the whole of it (a YAML alias bomb has a repr of gigabytes).
* :class:`BoundedLoader` is ``yaml.SafeLoader`` with a nesting depth and an expanded
  size bound: aliases are counted as often as they are used, so a YAML alias bomb is
  refused after composing its (small) node graph, before any Python value is built.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any

import yaml

#: Most characters :func:`short_repr` keeps of a value's repr.
SHORT_REPR = 200
#: Largest YAML file read (configs, ROS map YAML): PyYAML reads about 0.3 MB a second.
MAX_YAML_BYTES = 1 << 20
#: Most values (scalars, lists and mappings) one YAML document may hold once its aliases
#: are expanded; a file of MAX_YAML_BYTES without aliases holds fewer.
MAX_YAML_NODES = 1_000_000
#: Deepest nesting of lists and mappings in a YAML document.
MAX_YAML_DEPTH = 100


class InputError(ValueError):
    """An input file refused before it was read; the message is one line naming it."""


class YAMLRefused(yaml.MarkedYAMLError):
    """Well-formed YAML that :class:`BoundedLoader` refuses (too deep, too large, a value
    Python cannot build); ``problem`` and ``problem_mark`` say what and where."""


def kind_of(mode: int) -> str:
    """What a file of ``st_mode`` is, in words: "a folder", "a character device", ..."""
    for test, words in (
        (stat.S_ISREG, "a regular file"),
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return words
    return "not a regular file"


def not_a_file(path: str | Path) -> str | None:
    """What ``path`` is when it exists but is not a regular file (None otherwise)."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    return None if stat.S_ISREG(mode) else kind_of(mode)


def size_text(n: int) -> str:
    """A byte count in words: ``1.5 MiB``, ``300 bytes``."""
    for unit, shift in (("GiB", 30), ("MiB", 20), ("KiB", 10)):
        if n >= 1 << shift:
            return f"{n / (1 << shift):.3g} {unit}"
    return f"{n} bytes"


def read_capped(path: str | Path, limit: int, noun: str) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them.

    Raises :class:`InputError` (``PATH: is a character device, not a map file``; ``PATH:
    more than 16 MiB, the most qpatrol reads of a map file``) for anything else, before
    reading more than ``limit + 1`` bytes; ``FileNotFoundError`` and other ``OSError``
    as ``open`` raises them. The file is opened non-blocking, so a FIFO put in its place
    after the check cannot hang the read either.
    """
    p = Path(path)
    mode = os.stat(p).st_mode
    if not stat.S_ISREG(mode):
        raise InputError(f"{p}: is {kind_of(mode)}, not {noun}")
    with os.fdopen(os.open(p, os.O_RDONLY | os.O_NONBLOCK), "rb") as f:
        mode = os.fstat(f.fileno()).st_mode
        if not stat.S_ISREG(mode):  # replaced since the stat
            raise InputError(f"{p}: is {kind_of(mode)}, not {noun}")
        data = f.read(limit + 1)
    if len(data) > limit:
        raise InputError(
            f"{p}: more than {size_text(limit)}, the most qpatrol reads of {noun}; "
            "refused before reading it all"
        )
    return data


def read_text_capped(path: str | Path, limit: int, noun: str) -> str:
    """:func:`read_capped` decoded as UTF-8 (``UnicodeDecodeError`` if it is not)."""
    return read_capped(path, limit, noun).decode("utf-8")


class _Full(Exception):
    pass


def short_repr(value: Any, limit: int = SHORT_REPR) -> str:
    """``repr(value)`` cut to about ``limit`` characters (``...`` marks the cut).

    Lists, tuples, sets and dicts are walked item by item and the walk stops once the
    text is long enough, so a value shared many times (a YAML alias bomb) costs
    ``O(limit)``, never the size of its repr.
    """
    parts: list[str] = []
    room = [limit]

    def put(s: str) -> None:
        if len(s) > room[0]:
            parts.append(s[: max(room[0], 0)])
            raise _Full
        parts.append(s)
        room[0] -= len(s)

    def leaf(v: Any) -> str:
        if isinstance(v, str | bytes):
            return repr(v[: limit + 1])
        if isinstance(v, int) and not isinstance(v, bool) and v.bit_length() > 600:
            return f"<an integer of {v.bit_length():,} bits>"
        try:
            return repr(v)
        except Exception:  # a repr that fails (a huge int beyond the digit limit, ...)
            return f"<{type(v).__name__}>"

    # an explicit stack: a value nested 10,000 deep is no RecursionError
    stack: list[Any] = [value]
    closer = object()
    try:
        while stack:
            v = stack.pop()
            if isinstance(v, tuple) and len(v) == 2 and v[0] is closer:
                put(v[1])
                continue
            if isinstance(v, list | tuple | set | frozenset | dict):
                if isinstance(v, dict):
                    items: list[Any] = []
                    for i, (k, x) in enumerate(v.items()):
                        if i * 2 > limit:
                            break
                        items.append((closer, (", " if i else "") + leaf(k) + ": "))
                        items.append(x)
                    opener, end = "{", "}"
                else:
                    items = []
                    for i, x in enumerate(v):
                        if i * 2 > limit:
                            break
                        if i:
                            items.append((closer, ", "))
                        items.append(x)
                    opener, end = {
                        list: ("[", "]"),
                        tuple: ("(", ")"),
                    }.get(type(v), ("{", "}"))
                put(opener)
                stack.append((closer, end))
                stack.extend(reversed(items))
            else:
                put(leaf(v))
    except _Full:
        return "".join(parts) + "..."
    return "".join(parts)


class BoundedLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses, with a ``yaml.MarkedYAMLError`` naming the place,
    nesting deeper than :data:`MAX_YAML_DEPTH`, more than :data:`MAX_YAML_NODES` values
    once aliases are expanded, and values Python cannot build (an integer of more than
    4,300 digits, a date of month 13)."""

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        """A node, refused past :data:`MAX_YAML_DEPTH` levels (PyYAML recurses here)."""
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise YAMLRefused(
                    problem=f"nested more than {MAX_YAML_DEPTH} levels deep",
                    problem_mark=self.peek_event().start_mark,
                )
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_document(self, node: Any) -> Any:
        """The document's value, refused first if its expanded size is too large."""
        sizes = expanded_sizes(node, MAX_YAML_NODES)
        if sizes[id(node)] > MAX_YAML_NODES:
            keys, where = _largest_path(node, sizes)
            what = f"the value of {'.'.join(keys)}" if keys else "the document"
            raise YAMLRefused(
                problem=f"{what} holds more than {MAX_YAML_NODES:,} values once its aliases "
                "are expanded (an alias bomb?); refused before building them",
                problem_mark=where.start_mark,
            )
        return super().construct_document(node)

    def construct_object(self, node: Any, deep: bool = False) -> Any:
        """A value, or a marked error when Python cannot build it."""
        try:
            return super().construct_object(node, deep=deep)
        except (ValueError, OverflowError) as e:
            first = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise YAMLRefused(
                problem=f"cannot read the value {short_repr(node.value, 40)} "
                f"({short_repr(first, 80).strip(chr(39))})",
                problem_mark=node.start_mark,
            ) from None


def expanded_sizes(root: Any, limit: int) -> dict[int, int]:
    """Nodes under each node of a composed YAML node graph, itself included and every
    alias use counted, by ``id(node)``; counts stop at ``limit + 1``.

    Each distinct node is sized once, so the cost is that of the file, not of the
    expansion. A node inside its own anchor (a cycle) counts ``limit + 1``."""
    size: dict[int, int] = {}
    stack: list[tuple[Any, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if key in size and not done:
            continue
        kids = _children(node)
        if done:
            size[key] = min(1 + sum(size[id(k)] for k in kids), limit + 1)
            continue
        size[key] = limit + 1  # while its children are counted: reached again = a cycle
        stack.append((node, True))
        stack.extend((k, False) for k in kids if id(k) not in size)
    return size


def _largest_path(node: Any, sizes: dict[int, int]) -> tuple[list[str], Any]:
    """The dotted keys down to the largest value of nested mappings, and that value."""
    keys: list[str] = []
    while isinstance(node, yaml.MappingNode) and node.value:
        k, v = max(node.value, key=lambda kv: sizes.get(id(kv[1]), 0))
        if not isinstance(k, yaml.ScalarNode):
            break
        keys.append(str(k.value))
        node = v
    return keys, node


def _children(node: Any) -> list[Any]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [x for pair in node.value for x in pair]
    return []
