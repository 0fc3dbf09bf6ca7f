"""SimPatrol XML graphs -> :class:`~qpatrol.maps.graphimport.SourceGraph`.

SimPatrol (the multi-agent patrolling simulator of the Machado et al. / Moreira et al.
line of work) describes a graph as XML, alone (a map file) or inside an
``<environment>`` with its agent societies::

    <graph label="map_a">
      <node id="v1" label="v1" visibility="true" idleness="0.0" fuel="false" is_enabled="true"/>
      ...
      <edge id="e1" source="v1" target="v2" directed="false" length="6.0" visibility="true"/>
    </graph>

Older files say ``<vertex>`` for ``<node>``, ``emitter_id``/``collector_id`` for
``source``/``target`` and ``oriented`` for ``directed``; both are read. Nodes carry no
position, so the importer lays the graph out (:func:`qpatrol.maps.graphimport.layout`).
Of the node attributes only ``id`` and ``fuel`` are used: a node with ``fuel="true"`` is
where agents refuel, and becomes a charging station unless ``--stations`` is given.
``priority``, ``idleness``, ``visibility`` (whether agents perceive the node; every vertex
of a qpatrol graph is seen by whoever stands on it), ``is_enabled`` and any time
distributions inside elements are ignored, as are ``<stigma>`` and ``<society>``.

Vertices are numbered in the natural order of their ids (``v2`` before ``v10``), edges
sorted by their two vertices, so the same graph gives the same map whatever order the
file lists it in. A directed edge is accepted only when the reverse edge exists with the
same length (the pair becomes one undirected edge); parallel edges between two nodes (the
SimPatrol map A lists v37-v39 twice) become one edge of the shortest length.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from qpatrol.maps.core import MAX_MAGNITUDE
from qpatrol.maps.graphimport import (
    GraphImportError,
    SourceGraph,
    check_connected,
    merge_parallel,
    read_text,
)
from qpatrol.util.inputs import short_repr

__all__ = ["read_simpatrol"]

_TRUE, _FALSE = "true", "false"


def _natural(s: str) -> tuple:
    return tuple((1, int(p), "") if p.isdigit() else (0, 0, p) for p in re.split(r"(\d+)", s))


def _name(el: ET.Element, k: int) -> str:
    """How an error names an element: ``<edge id="e5">``, or by its position."""
    eid = el.get("id")
    return f'<{el.tag} id="{eid}">' if eid else f"<{el.tag}> number {k}"


def _flag(el: ET.Element, keys: tuple[str, ...], where: str) -> bool:
    for key in keys:
        v = el.get(key)
        if v is not None:
            if v.strip().lower() not in (_TRUE, _FALSE):
                raise GraphImportError(f"{where}: {key} {short_repr(v, 60)} is not true or false")
            return v.strip().lower() == _TRUE
    return False


def _attr(el: ET.Element, keys: tuple[str, ...], where: str) -> str:
    for key in keys:
        v = el.get(key)
        if v is not None:
            return v
    raise GraphImportError(f"{where}: no {' or '.join(keys)} attribute")


def read_simpatrol(path: str | Path) -> SourceGraph:
    """Read a SimPatrol graph (module doc); :class:`GraphImportError` names the file and
    the XML element (or the line of an XML syntax error)."""
    p = Path(path)
    text = read_text(p, "a SimPatrol graph file")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        line, col = e.position
        msg = str(e).split(":")[0]
        raise GraphImportError(f"{p}:{line}:{col + 1}: not well-formed XML ({msg})") from None
    graphs = [root] if root.tag == "graph" else list(root.iter("graph"))
    if not graphs:
        raise GraphImportError(f"{p}: no <graph> element (root is <{root.tag}>)")
    if len(graphs) > 1:
        raise GraphImportError(f"{p}: {len(graphs)} <graph> elements; expected one")
    graph = graphs[0]
    nodes = [el for el in graph.iter() if el.tag in ("node", "vertex")]
    edge_els = [el for el in graph.iter() if el.tag == "edge"]
    if not nodes:
        raise GraphImportError(f"{p}: <graph> has no <node> element")
    seen: dict[str, str] = {}
    fuel: dict[str, bool] = {}
    for k, el in enumerate(nodes, start=1):
        where = f"{p}: {_name(el, k)}"
        nid = el.get("id")
        if nid is None or not nid.strip():
            raise GraphImportError(f"{where}: no id attribute")
        if nid in seen:
            raise GraphImportError(
                f"{where}: id {short_repr(nid, 60)} repeated (first {seen[nid]})"
            )
        seen[nid] = _name(el, k)
        fuel[nid] = _flag(el, ("fuel",), where)
    ids = sorted(seen, key=_natural)
    index = {nid: i for i, nid in enumerate(ids)}
    pairs: dict[tuple[int, int], list[float]] = {}
    directed: dict[tuple[int, int], list[tuple[float, str]]] = {}
    for k, el in enumerate(edge_els, start=1):
        name = _name(el, k)
        where = f"{p}: {name}"
        ends = []
        for keys in (("source", "emitter_id"), ("target", "collector_id")):
            v = _attr(el, keys, where)
            if v not in index:
                raise GraphImportError(
                    f"{where}: {keys[0]} {short_repr(v, 60)} is not the id of a node"
                )
            ends.append(index[v])
        a, b = ends
        if a == b:
            raise GraphImportError(f"{where}: edge from node {short_repr(ids[a], 60)} to itself")
        raw = _attr(el, ("length",), where)
        try:
            length = float(raw)
        except ValueError:
            raise GraphImportError(
                f"{where}: length {short_repr(raw, 40)} is not a number"
            ) from None
        if not (math.isfinite(length) and length > 0):
            raise GraphImportError(f"{where}: length {short_repr(raw, 40)} is not a number > 0")
        if length > MAX_MAGNITUDE:
            raise GraphImportError(
                f"{where}: length {short_repr(raw, 40)} is out of range; allowed: a number "
                f"> 0 and at most {MAX_MAGNITUDE:g}"
            )
        if _flag(el, ("directed", "oriented"), where):
            directed.setdefault((a, b), []).append((length, name))
        else:
            pairs.setdefault((min(a, b), max(a, b)), []).append(length)
    for (a, b), arcs in sorted(directed.items()):
        back = sorted(directed.get((b, a), []))
        for length, name in sorted(arcs):
            match = [x for x in back if x[0] == length]
            if not match:
                other = f"; the reverse edge {back[0][1]} has length {back[0][0]:g}" if back else ""
                raise GraphImportError(
                    f"{p}: {name}: directed edge {ids[a]} -> {ids[b]} (length {length:g}) "
                    f"has no reverse edge of the same length{other}; qpatrol patrol graphs "
                    "are undirected"
                )
            back.remove(match[0])
            if a < b:
                pairs.setdefault((a, b), []).append(length)
    labels = tuple(re.sub(r"\s+", "_", i.strip()) for i in ids)
    edges, notes = merge_parallel(pairs, labels)
    check_connected(len(ids), edges, labels, str(p))
    lengths = edges[:, 2]
    label = graph.get("label")
    facts = f"graph {label!r}, " if label else ""
    facts += f"{len(ids)} nodes, {edges.shape[0]} edges"
    if edges.size:
        facts += f" of length {lengths.min():g}-{lengths.max():g}"
    n_fuel = sum(fuel.values())
    if n_fuel:
        facts += f", {n_fuel} fuel node(s)"
    return SourceGraph(
        kind="SimPatrol graph",
        path=p,
        labels=labels,
        xy=None,
        edges=edges,
        stations=np.array([fuel[i] for i in ids], dtype=bool),
        unit="",
        facts=facts,
        notes=notes,
    )
