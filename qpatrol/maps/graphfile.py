"""Import a patrol graph file, whichever tool wrote it: the readers' common entry.

:func:`import_graph_file` picks the reader by suffix (``.graph``:
:mod:`qpatrol.maps.patrolling_sim`, ``.xml``: :mod:`qpatrol.maps.simpatrol`) and turns
what it read into a qpatrol graph map (:func:`qpatrol.maps.graphimport.to_graph_map`).
"""

from __future__ import annotations

from pathlib import Path

from qpatrol.maps.graphimport import GraphImportError, ImportedGraph, to_graph_map
from qpatrol.maps.patrolling_sim import read_patrolling_sim
from qpatrol.maps.simpatrol import read_simpatrol

__all__ = ["import_graph_file"]


def import_graph_file(
    path: str | Path,
    name: str | None = None,
    agents: int = 4,
    stations: int | None = None,
    edge_step: float | None = None,
    unit_edges: bool = False,
) -> ImportedGraph:
    """Import a patrolling_sim ``.graph`` or a SimPatrol ``.xml`` file (by its suffix)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".graph":
        g = read_patrolling_sim(p)
    elif suffix == ".xml":
        g = read_simpatrol(p)
    else:
        raise GraphImportError(
            f"{p}: unknown graph file kind {suffix or '(no suffix)'!r}; "
            "expected .graph (patrolling_sim) or .xml (SimPatrol)"
        )
    return to_graph_map(g, name or p.stem, agents, stations, edge_step, unit_edges)
