"""patrolling_sim .graph and SimPatrol .xml patrol graphs -> qpatrol graph maps.

The three .graph files in tests/data are patrolling_sim's (BSD, tests/data/
LICENSE-patrolling_sim); simpatrol_example.xml is made up for these tests.
"""

import math
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qpatrol.cli import app
from qpatrol.maps import load_map, parse_map
from qpatrol.maps.graph import build_graph_map
from qpatrol.maps.graphfile import import_graph_file
from qpatrol.maps.graphimport import (
    GraphImportError,
    edge_moves,
    layout,
    shortest_lengths,
    stress,
)

DATA = Path(__file__).resolve().parent / "data"
GRID, EXAMPLE, CUMBERLAND = (DATA / f"{n}.graph" for n in ("grid", "example", "cumberland"))
SIMPATROL = DATA / "simpatrol_example.xml"
runner = CliRunner()


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def raw_edges(path: Path) -> dict[tuple[int, int], list[int]]:
    """(a, b), a < b -> the costs a .graph file lists at a for neighbour b (read plainly)."""
    tok = path.read_text().split()
    n, i = int(tok[0]), 6
    out: dict[tuple[int, int], list[int]] = {}
    for _ in range(n):
        v, degree = int(tok[i]), int(tok[i + 3])
        i += 4
        for _ in range(degree):
            nb, cost = int(tok[i]), int(tok[i + 2])
            i += 3
            if v < nb:
                out.setdefault((v, nb), []).append(cost)
    return out


def round_half_up(x: float) -> int:
    return int(math.floor(x + 0.5))


# --- patrolling_sim --------------------------------------------------------------------


def test_grid_unit_edges():
    r = import_graph_file(GRID, unit_edges=True)
    m = r.map
    assert m.is_graph and r.step is None
    assert (m.n_targets, len(m.edges), m.n_ports, m.n_cells) == (25, 40, 4, 25)
    assert (m.edges[:, 2] == 1).all()
    # the 5 x 5 lattice: vertex v = 5 * column + row, 0.075 m/px, 76 px apart
    assert np.allclose(np.diff(np.unique(m.xy[:, 0])), 76 * 0.075)
    assert np.allclose(m.xy[0], (19 * 0.075, 325 * 0.075))
    assert m.distances()[np.ix_(m.target, m.target)].max() == 8


def test_default_edge_step_is_the_shortest_edge_and_rounds_half_up():
    for path in (GRID, CUMBERLAND, EXAMPLE):
        raw = raw_edges(path)
        step = min(min(c) for c in raw.values())
        r = import_graph_file(path)
        assert r.step == step
        got = {(a, b): mv for a, b, mv in r.map.edges.tolist()}
        assert set(got) == set(raw)
        for pair, costs in raw.items():
            assert got[pair] == max(1, round_half_up(min(costs) / step)), (path.name, pair)
        # waypoints: every edge of m moves adds m - 1 cells
        assert r.map.n_cells == r.map.n_targets + int((r.map.edges[:, 2] - 1).sum())
    # cumberland's costs 22..177 px: 1..8 moves
    m = import_graph_file(CUMBERLAND).map
    assert (m.edges[:, 2].min(), m.edges[:, 2].max()) == (1, 8)


def test_edge_step_option_and_rounding():
    r = import_graph_file(GRID, edge_step=38)
    assert (r.map.edges[:, 2] == 2).all() and r.map.n_cells == 25 + 40
    assert import_graph_file(GRID, edge_step=50.6).map.edges[0, 2] == 2  # 76/50.6 = 1.502
    assert edge_moves(np.array([1.0, 5.0, 7.0, 9.0]), 2.0).tolist() == [1, 3, 4, 5]
    assert edge_moves(np.array([1.0, 50.0]), None).tolist() == [1, 1]


def test_example_and_cumberland_import_and_load(tmp_path: Path):
    for path, v, e in ((EXAMPLE, 29, 34), (CUMBERLAND, 40, 44)):
        r = import_graph_file(path, name=path.stem)
        out = tmp_path / f"{path.stem}.txt"
        out.write_text(r.text)
        m = load_map(out)
        assert m.is_graph and (m.n_targets, len(m.edges)) == (v, e)
        assert len(m.starts) == 4 and len(m.homes) == 1
        assert not set(m.starts.tolist()) & set(m.homes.tolist())
        assert m.description.startswith(f"imported from patrolling_sim graph {path.name}")
        assert "edge step" in m.description
    # example.graph lists 8-12 and 14-16 twice each way (two corridors): one edge each
    m = import_graph_file(EXAMPLE).map
    pairs = [tuple(e) for e in m.edges[:, :2].tolist()]
    assert pairs.count((8, 12)) == 1 and pairs.count((14, 16)) == 1
    assert "parallel edges kept only the shortest (8-12, 14-16)" in m.description


def test_round_trip_render_parse_gives_the_same_map():
    for path, kw in ((CUMBERLAND, {}), (SIMPATROL, {"edge_step": 1.5}), (GRID, {})):
        r = import_graph_file(path, **kw)
        built = build_graph_map(r.spec)
        parsed = parse_map(r.text)
        for key in ("neighbors", "back", "entry", "target", "xy", "dot_kind", "homes", "starts"):
            assert np.array_equal(getattr(built, key), getattr(parsed, key)), (path.name, key)
        assert np.array_equal(built.edges, parsed.edges) and built.labels == parsed.labels


def test_placement_spreads_starts_and_stations_on_vertices():
    r = import_graph_file(CUMBERLAND, agents=6, stations=3)
    m = r.map
    assert len(m.starts) == 6 and len(m.homes) == 3
    assert (m.starts < m.n_targets).all() and (m.homes < m.n_targets).all()
    assert not set(m.starts.tolist()) & set(m.homes.tolist())
    assert (m.degree[m.homes] >= 2).all()  # no station at a dead end while others remain
    assert (m.dot_kind[m.homes] == 0).all()
    # farthest-point: each next start is a vertex farthest (in moves) from those before it
    d = m.distances()
    for k in range(2, 6):
        near = d[m.starts[:k]].min(axis=0)
        assert near[m.starts[k]] == near[: m.n_targets].max()
    with pytest.raises(GraphImportError, match="cannot hold 30 starts, 11 charging stations"):
        import_graph_file(CUMBERLAND, agents=30, stations=11)


# --- SimPatrol -------------------------------------------------------------------------


def test_simpatrol_example():
    r = import_graph_file(SIMPATROL, agents=2)
    m = r.map
    assert (m.n_targets, len(m.edges), m.n_ports) == (10, 12, 3)
    assert m.labels == tuple(f"n{i}" for i in range(1, 11))  # natural order of the ids
    assert r.step == 2.0
    lengths = {("n1", "n2"): 4, ("n3", "n9"): 9, ("n9", "n10"): 2, ("n4", "n10"): 7}
    got = {(m.labels[a], m.labels[b]): mv for a, b, mv in m.edges.tolist()}
    for (a, b), length in lengths.items():
        key = (a, b) if (a, b) in got else (b, a)
        assert got[key] == max(1, round_half_up(length / 2.0))
    assert m.homes.tolist() == [m.labels.index("n6")]  # the fuel node
    assert "graph 'test_ten'" in m.description and "laid out by MDS" in m.description
    # --stations overrides the file's fuel nodes
    assert len(import_graph_file(SIMPATROL, agents=2, stations=2).map.homes) == 2


def test_simpatrol_layout_is_deterministic_and_order_free(tmp_path: Path):
    a = import_graph_file(SIMPATROL).text
    assert import_graph_file(SIMPATROL).text == a
    # the same graph listed in another order gives the same map
    text = SIMPATROL.read_text()
    nodes = re.findall(r"\t\t<node .*/>\n", text)
    edges = re.findall(r"\t\t<edge .*/>\n", text)
    body = "".join(nodes[::-1] + edges[::-1])
    start = text.index(nodes[0])
    end = text.index(edges[-1]) + len(edges[-1])
    other = tmp_path / SIMPATROL.name
    other.write_text(text[:start] + body + text[end:])
    assert import_graph_file(other).text == a


def test_layout_follows_path_lengths():
    # a path is drawn exactly: the layout's distances are the path lengths
    edges = np.array([[0, 1, 1.0], [1, 2, 2.0], [2, 3, 3.0]])
    xy = layout(4, edges)
    dist = np.linalg.norm(xy[:, None] - xy[None], axis=2)
    assert np.allclose(dist, shortest_lengths(4, edges), atol=1e-6)
    # a ring has no exact fit: stress majorisation cuts classical MDS's stress (2.28 to 0.32)
    ring = np.array([[i, (i + 1) % 8, 1.0 + (i % 3)] for i in range(8)])
    d = shortest_lengths(8, ring)
    assert stress(d, layout(8, ring)) < 0.5 * stress(d, layout(8, ring, iterations=0))


# --- CLI -------------------------------------------------------------------------------


def test_cli_import_show_check_list(tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = invoke("maps", "import", CUMBERLAND)
    assert res.exit_code == 0, res.output
    assert "wrote maps/cumberland.txt: graph of 40 vertices, 44 edges" in res.stdout
    res = invoke("maps", "import", SIMPATROL, "--out", "maps/sp.txt", "--unit-edges")
    assert res.exit_code == 0, res.output
    assert "every edge one move" in res.stdout
    res = invoke("maps", "import", GRID, "--out", "-", "--agents", "2")
    assert res.exit_code == 0 and res.stdout.startswith("; name: grid\n")
    assert "graph of 25 vertices" in res.stderr
    res = invoke("maps", "show", "cumberland")
    assert res.exit_code == 0
    assert "graph: 40 vertices, 44 edges" in res.stdout and "D = 4" in res.stdout
    assert "starts (agent: vertex): 0:" in res.stdout
    res = invoke("maps", "check", "maps/cumberland.txt", "maps/sp.txt")
    assert res.exit_code == 0 and "ok (graph: 10 vertices, 12 edges, 10 cells" in res.stdout
    res = invoke("maps", "list")
    assert re.search(r"cumberland\s+graph\s+152 cells", res.stdout), res.stdout
    png = tmp_path / "c.png"
    res = invoke("maps", "show", "cumberland", "--png", png)
    assert res.exit_code == 0 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _replace_line(path: Path, out: Path, lineno: int, new: str | None) -> Path:
    lines = path.read_text().splitlines()
    if new is None:
        del lines[lineno - 1 :]
    else:
        lines[lineno - 1] = new
    out.write_text("\n".join(lines) + "\n")
    return out


def _xml(tmp_path: Path, name: str, *old_new: str) -> Path:
    text = SIMPATROL.read_text()
    for old, new in zip(old_new[::2], old_new[1::2], strict=True):
        assert old in text
        text = text.replace(old, new)
    p = tmp_path / f"{name}.xml"
    p.write_text(text)
    return p


def _broken(tmp_path: Path) -> list[tuple[list, str]]:
    """(arguments after ``maps import``, words of the one-line error) per broken input."""

    def gr(name: str, line: int, new: str | None) -> Path:
        return _replace_line(GRID, tmp_path / name, line, new)

    def xml(name: str, *old_new: str) -> Path:
        return _xml(tmp_path, name, *old_new)

    e = '<edge id="{}">'.format
    dir_n10_n4 = ('"n10" target="n4" directed="false"', '"n10" target="n4" directed="true"')
    dir_n10_n9 = (
        '"n10" target="n9" directed="true" length="2.0"',
        '"n10" target="n9" directed="true" length="3.0"',
    )
    dir_n3_n9 = (
        'target="n9" directed="false" length="9.0"',
        'target="n9" directed="true" length="9.0"',
    )
    # cut n9 and n10 off: n3-n9 becomes n10-n9, n10-n4 becomes n9-n10
    island = (
        'source="n3" target="n9"',
        'source="n10" target="n9"',
        'source="n10" target="n4"',
        'source="n9" target="n10"',
    )
    # grid.graph: line 8 vertex 0's id, 11 its degree, 12-14 its first neighbour (1, S, 76),
    # vertex 1's block starts on line 19; vertex 24's on line 362, the file ends on 372
    return [
        ([gr("t1.graph", 370, None)], "t1.graph:369: file ends inside vertex 24's neighbours"),
        ([gr("t2.graph", 361, None)], "t2.graph:360: file ends after 24 of the 25 vertices"),
        ([gr("dir.graph", 13, "Q")],
         "dir.graph:13: vertex 0's neighbour 1 of 2: direction 'Q' is not one of N NE E SE S"),
        ([gr("cost.graph", 14, "77")],
         "cost.graph:12: edge 0-1 costs 77 at vertex 0 but 76 at vertex 1 (line 23)"),
        ([gr("deg.graph", 11, "3")],
         "deg.graph:11: vertex 0 has degree 3 but its block lists 6 neighbour value(s) where 9"),
        ([gr("miss.graph", 15, "6")],
         "miss.graph:15: vertex 0 lists neighbour 6 (cost 76) but vertex 6 does not list 0"),
        ([gr("id.graph", 8, "1")], "id.graph:8: vertex id 1 where 0 was expected"),
        ([gr("res.graph", 4, "fine")], "res.graph:4: resolution 'fine' is not a number"),
        ([gr("c.graph", 14, "x")], "c.graph:14: vertex 0's neighbour 1 of 2: cost 'x' is not a"),
        ([xml("nonode", 'source="n5" target="n6"', 'source="n5" target="n66"')],
         f"nonode.xml: {e('e5')}: target 'n66' is not the id of a node"),
        ([xml("len", 'length="6.0"', 'length="six"')],
         f"len.xml: {e('e3')}: length 'six' is not a number"),
        ([xml("neg", 'length="3.0"', 'length="-3"')],
         f"neg.xml: {e('e7')}: length '-3' is not a number > 0"),
        ([xml("dir", *dir_n10_n4)],
         f"dir.xml: {e('e13')}: directed edge n10 -> n4 (length 7) has no reverse edge of the"),
        ([xml("dir2", *dir_n10_n9)], f"the reverse edge {e('e12')} has length 3"),
        ([xml("cut", *dir_n3_n9)], f"cut.xml: {e('e10')}: directed edge n3 -> n9"),
        ([xml("dup", 'node id="n7"', 'node id="n8"')],
         "dup.xml: <node id=\"n8\">: id 'n8' repeated"),
        ([xml("syntax", "</graph>", "</grap>")],
         "syntax.xml:30:4: not well-formed XML (mismatched tag)"),
        ([xml("nograph", "graph", "map")],
         "nograph.xml: no <graph> element (root is <environment>)"),
        ([xml("flag", 'directed="true" length="2.0"', 'directed="yes" length="2.0"')],
         f"flag.xml: {e('e11')}: directed 'yes' is not true or false"),
        ([xml("island", *island)], "island.xml: vertex n9 cannot be reached from vertex n1"),
        ([tmp_path / "gone.graph"], "gone.graph: no such file"),
        ([GRID, "--cell", "1"], "--cell is for ROS maps (.yaml); grid.graph is a patrol graph"),
        ([GRID, "--edge-step", "1", "--unit-edges"], "--edge-step and --unit-edges exclude"),
        ([GRID, "--edge-step", "0"], "edge step: 0.0 is not a length > 0"),
        ([GRID, "--edge-step", "0.001"], "edge step 0.001 px makes 3039985 cells"),
        ([GRID, "--agents", "20", "--stations", "6"],
         "25 vertices cannot hold 20 starts, 6 charging stations"),
        ([DATA / "mspacman1.txt"], "unknown map file kind '.txt'"),
        ([tmp_path / "floor.yaml", "--edge-step", "2"],
         "--edge-step and --unit-edges are for patrol graphs"),
    ]  # fmt: skip


def test_broken_files_exit_2_with_one_line(tmp_path: Path):
    out = tmp_path / "out.txt"
    for args, words in _broken(tmp_path):
        res = invoke("maps", "import", *args, "--out", out)
        assert res.exit_code == 2, (args, res.output)
        assert words in res.stderr, (words, res.stderr)
        assert len(res.stderr.strip().splitlines()) == 1, res.stderr
        assert "Traceback" not in res.output
        assert not out.exists()


def test_positions_are_pixels_times_resolution_plus_offset(tmp_path: Path):
    """patrolling_sim's offset is in metres, added after scaling the pixels."""
    lines = GRID.read_text().splitlines()
    lines[4], lines[5] = "1.5", "-2.25"  # offset x, offset y
    shifted = tmp_path / "shifted.graph"
    shifted.write_text("\n".join(lines) + "\n")
    plain = import_graph_file(GRID, unit_edges=True).map
    m = import_graph_file(shifted, unit_edges=True).map
    assert np.allclose(m.xy[0], (19 * 0.075 + 1.5, 325 * 0.075 - 2.25))
    assert np.allclose(m.xy - plain.xy, (1.5, -2.25))
