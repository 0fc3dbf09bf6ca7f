"""Inputs whose size is checked before anything is built, through ``qpatrol.cli.main``.

Each used to exhaust memory, hang or end in an internal error (exit 1): a graph edge of
a billion moves, a YAML alias bomb, a 15,000-node SimPatrol chain (a V x V layout), a
PNG header claiming 60,000 x 60,000 pixels, ``image: /dev/zero``, a ``.graph`` of 10^12
vertices, ``--out`` under a file, positions of 1e308, devices and FIFOs given as
files. Each case asserts exit code 2 (or the documented result), one line on stderr
naming the cause, no traceback and nothing written; the last test runs a few of them in
a subprocess under a 1.5 GB address-space limit and a time limit.
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path
from typing import Any

import pytest
import yaml

from qpatrol.maps import graphimport, images
from qpatrol.maps.core import MAX_CELLS

ROS_KEYS = (
    "resolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
)


@pytest.fixture
def run(cli_run, monkeypatch, tmp_path):
    """Run ``qpatrol ARGS...`` in this process from ``tmp_path``, as the console script
    does; a crash log would land in ``tmp_path`` too (and so count as written)."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("QPATROL_LOG_DIR", str(tmp_path / "crash-logs"))
    return cli_run


def tree(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


def refused(res: Any, *words: str, limit: int = 400) -> str:
    """Exit 2 and one short line on stderr holding ``words``; returns the line."""
    assert res.code == 2, (res.code, res.out[-300:], res.err[-300:])
    lines = res.err.strip().splitlines()
    assert len(lines) == 1, res.err[:500]
    line = lines[0]
    assert line.startswith("qpatrol: error: "), line
    assert len(line) <= limit, f"{len(line)} characters: {line[:300]}"
    assert "Traceback" not in res.out + res.err
    for w in words:
        assert w in line, line
    return line


def graph_map(path: Path, *lines: str) -> Path:
    path.write_text("; kind: graph\n" + "\n".join(lines) + "\n")
    return path


def config(path: Path, **extra: object) -> Path:
    cfg = {"map": "map_b", "agents": 1, "runs": 1, "steps": 200, "battery": False, **extra}
    path.write_text(yaml.safe_dump(cfg))
    return path


def alias_bomb(path: Path, key: str, levels: int) -> Path:
    """A config whose ``key`` holds lists nested ``levels`` deep, each of nine aliases of
    the level below: 9^levels strings from a file of a few hundred bytes."""
    parts = ['&a0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    parts += [f"&a{i} [" + ",".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, levels)]
    value = "[" + ", ".join(parts) + "]"
    head, _, last = key.rpartition(".")
    nested = "".join(f"{'  ' * i}{k}:\n" for i, k in enumerate(head.split("."))) if head else ""
    indent = "  " * (head.count(".") + 1) if head else ""
    path.write_text(
        "map: map_b\nagents: 1\nruns: 1\nsteps: 200\nbattery: false\n"
        + nested
        + f"{indent}{last}: {value}\n"
    )
    return path


def chain_xml(path: Path, n: int) -> Path:
    nodes = "".join(f'<node id="v{i}"/>\n' for i in range(n))
    edges = "".join(
        f'<edge id="e{i}" source="v{i}" target="v{i + 1}" length="1.0"/>\n' for i in range(n - 1)
    )
    path.write_text(f'<graph label="chain">\n{nodes}{edges}</graph>\n')
    return path


def png_header(path: Path, width: int, height: int) -> Path:
    """A PNG whose IHDR says ``width`` x ``height`` grey pixels, with a one-row body."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = zlib.crc32(kind + data) & 0xFFFFFFFF
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    body = zlib.compress(b"\x00" * 64)
    path.write_bytes(
        images.PNG_MAGIC + chunk(b"IHDR", ihdr) + chunk(b"IDAT", body) + chunk(b"IEND", b"")
    )
    return path


def ros_yaml(path: Path, image: str) -> Path:
    path.write_text(f"image: {image}\n" + ROS_KEYS)
    return path


def small_ros_map(tmp_path: Path) -> Path:
    (tmp_path / "ok.pgm").write_bytes(b"P5\n40 30\n255\n" + bytes([254]) * 1200)
    return ros_yaml(tmp_path / "ok.yaml", "ok.pgm")


# --- graph maps: cells, ports and positions ----------------------------------------------


@pytest.mark.parametrize("command", ["check", "train"])
def test_an_edge_of_a_billion_moves_is_refused_on_its_line(run, tmp_path, command):
    m = graph_map(tmp_path / "g.txt", "v 0 0 0 start=0", "v 1 1 0", "e 0 1 1000000000")
    before = tree(tmp_path)
    if command == "check":
        res = run("maps", "check", m)
    else:
        res = run("train", config(tmp_path / "c.yaml"), "--set", f"map={m}")
        before |= {"c.yaml"}
    refused(res, "g.txt:4: edge 0-1 of 1,000,000,000 moves", f"at most {MAX_CELLS:,} cells")
    assert tree(tmp_path) == before


def test_vertices_and_waypoints_count_together(run, tmp_path):
    # 300,001 cells: 2 vertices and an edge of 300,000 moves (was built, then refused by
    # the memory estimate naming the placement of agents)
    m = graph_map(tmp_path / "g.txt", "v 0 0 0 start=0", "v 1 1 0", "e 0 1 300000")
    refused(run("maps", "check", m), "300,001 cells", "refused before building")


def test_a_hub_of_many_edges_is_refused_by_its_ports(run, tmp_path):
    n = 1300  # 1,300 cells of 1,299 ports each: more than 8 x 200,000 slots
    lines = [f"v {i} {i} 0" for i in range(n)] + [f"e 0 {i} 1" for i in range(1, n)]
    m = graph_map(tmp_path / "star.txt", *lines)
    refused(run("maps", "check", m), "vertex 0 has 1,299 edges", "1,688,700", "cells x ports")


def test_positions_beyond_1e100_are_refused_before_drawing(run, tmp_path):
    m = graph_map(
        tmp_path / "far.txt",
        "v 0 0 0 start=0",
        "v 1 1e308 1e308 station",
        "v 2 -1e308 0",
        "e 0 1 2",
        "e 1 2 1",
    )
    before = tree(tmp_path)
    res = run("maps", "show", m, "--png", tmp_path / "far.png")
    refused(res, "far.txt:3: x '1e308' is out of range", "1e+100")
    assert tree(tmp_path) == before


def test_a_grid_is_refused_by_its_area_and_its_free_cells(run, tmp_path):
    wide = tmp_path / "wide.txt"
    wide.write_text("0" + "#" * 4000 + "\n" + "\n".join(["#" * 4001] * 999) + "\n")
    refused(run("maps", "check", wide), "4,001 x 1,000", "at most 4,000,000")
    free = tmp_path / "free.txt"
    free.write_text("0" + "." * 200_000 + "\n")
    refused(run("maps", "check", free), "200,001 free cells", f"at most {MAX_CELLS:,}")


def test_a_map_file_beyond_16_mib_is_refused_unread(run, tmp_path):
    big = tmp_path / "big.txt"
    with open(big, "wb") as f:
        f.truncate((16 << 20) + 1)  # sparse: nothing written to disk
    refused(run("maps", "check", big), "big.txt: more than 16 MiB", "a map file")


def test_a_strategy_that_keeps_a_distance_table_is_refused_on_a_large_map(run, tmp_path):
    """A map of 150,001 cells: no table is built on the way of train, but a strategy
    that keeps one (hcr) is refused before any work, naming the limit."""
    m = graph_map(tmp_path / "g.txt", "v 0 0 0 start=0", "v 1 1 0", "e 0 1 150000")
    res = run("train", config(tmp_path / "c.yaml"), "--set", f"map={m}", "--set", "policy=hcr")
    refused(res, "hcr keeps a cells x cells table", "150,001 cells", "at most 4,096", limit=600)
    assert sorted(tree(tmp_path)) == ["c.yaml", "g.txt"]


# --- YAML ---------------------------------------------------------------------------------


@pytest.mark.parametrize("key", ["learning.q_init.north", "record.watch"])
def test_a_yaml_alias_bomb_is_refused_before_it_is_built(run, tmp_path, key):
    cfg = alias_bomb(tmp_path / "bomb.yaml", key, 9)  # 387 million strings
    before = tree(tmp_path)
    refused(run("train", cfg), f"the value of {key} holds more than 1,000,000 values", "alias")
    assert tree(tmp_path) == before


def test_a_smaller_alias_bomb_gets_a_short_message(run, tmp_path):
    cfg = alias_bomb(tmp_path / "bomb.yaml", "learning.q_init.north", 6)  # 531,441 strings
    line = refused(run("train", cfg), "learning.q_init.north: got [[", "allowed: a number")
    assert "..." in line  # the value's repr is cut (it was 4.3 MB)


def test_a_bomb_in_set_gets_a_short_message(run, tmp_path):
    flow = '[&a ["x","x","x","x","x","x","x","x"], &b [*a,*a,*a,*a,*a,*a,*a,*a], '
    flow += "&c [*b,*b,*b,*b,*b,*b,*b,*b], [*c,*c,*c,*c,*c,*c,*c,*c]]"
    res = run("train", config(tmp_path / "c.yaml"), "--set", f"record.watch={flow}")
    refused(res, "record.watch: got ", "allowed: a list of state numbers")


@pytest.mark.parametrize(
    "text, words",
    [
        ("record:\n  watch: " + "[" * 5000 + "]" * 5000, "nested more than 100 levels deep"),
        ("steps: " + "1" * 5000, "cannot read the value '1111"),
        ("seed: 2020-13-45", "month must be in 1..12"),
    ],
    ids=["deep", "huge-int", "month-13"],
)
def test_yaml_python_cannot_build_is_one_line(run, tmp_path, text, words):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("map: map_b\n" + text + "\n")
    refused(run("train", cfg), "c.yaml:", words)


# --- devices, FIFOs and output paths -------------------------------------------------------


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/null"])
def test_a_device_is_not_a_folder_nor_a_config(run, tmp_path, device):
    refused(run("train", device), f"{device}: is a character device, not a config file")
    res = run("train", config(tmp_path / "c.yaml"), "--set", f"map={device}")
    refused(res, f"{device}: is a character device, not a map file")
    refused(run("maps", "check", device), f"{device}: is a character device, not a map file")
    assert sorted(tree(tmp_path)) == ["c.yaml"]


def test_a_ros_image_on_dev_zero_is_not_read(run, tmp_path):
    y = ros_yaml(tmp_path / "zero.yaml", "/dev/zero")
    before = tree(tmp_path)
    res = run("maps", "import", y, "--cell", "0.2", "--out", tmp_path / "z.txt")
    refused(res, "zero.yaml: image: /dev/zero: is a character device, not an image file")
    assert tree(tmp_path) == before


def test_out_under_an_existing_file_exits_2(run, tmp_path):
    y = small_ros_map(tmp_path)
    before = tree(tmp_path)
    res = run("maps", "import", y, "--cell", "0.2", "--out", tmp_path / "ok.pgm" / "x.txt")
    refused(res, "ok.pgm/x.txt", "is a file, not a folder")
    assert tree(tmp_path) == before


def test_out_in_a_read_only_folder_exits_2(run, tmp_path, readonly):
    y = small_ros_map(tmp_path)
    res = run("maps", "import", y, "--cell", "0.2", "--out", readonly / "x.txt")
    refused(res, f"{readonly / 'x.txt'}: cannot write in")
    assert not (readonly / "x.txt").exists()


def test_force_never_replaces_a_fifo(run, tmp_path):
    y = small_ros_map(tmp_path)
    fifo = tmp_path / "out.txt"
    os.mkfifo(fifo)
    res = run("maps", "import", y, "--cell", "0.2", "--out", fifo, "--force")
    refused(res, "out.txt: is a FIFO (named pipe); give the name of a file to write")
    assert fifo.is_fifo()
    os.mkfifo(tmp_path / "pipe.png")
    refused(run("maps", "show", "map_b", "--png", tmp_path / "pipe.png"), "is a FIFO")
    assert (tmp_path / "pipe.png").is_fifo()


# --- images -------------------------------------------------------------------------------


def test_a_png_header_of_60000_squared_is_refused_before_decoding(run, tmp_path, monkeypatch):
    png_header(tmp_path / "huge.png", 60_000, 60_000)  # 139 bytes on disk
    y = ros_yaml(tmp_path / "huge.yaml", "huge.png")

    def no_decoding(path):
        raise AssertionError("the pixels were decoded")

    monkeypatch.setattr(images, "_read_png", no_decoding)
    before = tree(tmp_path)
    res = run("maps", "import", y, "--cell", "0.2", "--out", tmp_path / "h.txt")
    refused(res, "huge.png: PNG of 60,000 x 60,000 pixels", "refused before decoding")
    assert tree(tmp_path) == before


def test_a_pgm_header_of_60000_squared_is_refused_before_reading_it(run, tmp_path):
    (tmp_path / "huge.pgm").write_bytes(b"P5\n60000 60000\n255\n")
    y = ros_yaml(tmp_path / "huge.yaml", "huge.pgm")
    res = run("maps", "import", y, "--cell", "0.2", "--out", tmp_path / "h.txt")
    refused(res, "huge.pgm: PGM of 60,000 x 60,000 pixels (3,600,000,000 samples)")


# --- patrolling_sim and SimPatrol files ---------------------------------------------------


def test_a_graph_header_of_10_to_the_12_vertices_is_refused(run, tmp_path):
    g = tmp_path / "tera.graph"
    g.write_text("1000000000000\n100 100\n0.05\n0 0\n\n0 1 1 0\n")
    res = run("maps", "import", g, "--out", "-")
    refused(res, "tera.graph:1: vertex count 1,000,000,000,000", "allowed: at most 200,000")
    g.write_text("150000\n100 100\n0.05\n0 0\n\n0 1 1 0\n")  # more than the file holds
    refused(run("maps", "import", g, "--out", "-"), "vertex count 150,000, but the file holds")


def test_a_graph_cost_of_400_digits_is_refused(run, tmp_path):
    g = tmp_path / "cost.graph"
    big = "9" * 400
    g.write_text(f"2\n100 100\n0.05\n0 0\n\n0 1 1 1\n1 E {big}\n\n1 2 2 1\n0 W {big}\n")
    refused(run("maps", "import", g, "--out", "-"), "cost of 400 digits must be at most 1e+100")


def test_xml_lengths_are_counted_in_floating_point(run, tmp_path):
    def xml(length: str) -> Path:
        p = tmp_path / "long.xml"
        p.write_text(
            '<graph><node id="a"/><node id="b"/><node id="c"/>\n'
            '<edge id="e1" source="a" target="b" length="1"/>\n'
            f'<edge id="e2" source="b" target="c" length="{length}"/></graph>\n'
        )
        return p

    res = run("maps", "import", xml("1e300"), "--out", "-")
    refused(res, "long.xml: <edge id=\"e2\">: length '1e300' is out of range")
    res = run("maps", "import", xml("1e99"), "--out", "-")
    line = refused(res, "edge step 1 makes 1e+99 cells", "b-c of length 1e+99")
    assert "9223372036854775" not in line


def test_a_15000_node_chain_is_laid_out_without_a_square_matrix(run, tmp_path, monkeypatch):
    def no_square(*args):
        raise AssertionError("a V x V path length matrix was built")

    monkeypatch.setattr(graphimport, "shortest_lengths", no_square)
    src = chain_xml(tmp_path / "chain.xml", 15_000)
    res = run("maps", "import", src, "--out", tmp_path / "chain.txt")
    assert res.code == 0, res.err
    text = (tmp_path / "chain.txt").read_text()
    assert "positions laid out by pivot MDS" in text
    xy = {}
    for line in text.splitlines():
        if line.startswith("v "):
            tok = line.split()
            xy[int(tok[1])] = (float(tok[2]), float(tok[3]))
    (x0, y0), (x1, y1) = xy[0], xy[14_999]
    assert abs(((x1 - x0) ** 2 + (y1 - y0) ** 2) ** 0.5 - 14_999) < 1.0  # drawn straight


# --- memory and time, in a subprocess -----------------------------------------------------

_CHILD = r"""
import json, resource, sys, time
limit = int(sys.argv[1])
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
from qpatrol import cli
out = []
for args in json.loads(sys.argv[2]):
    t = time.perf_counter()
    try:
        cli.main(args)
        code = 0
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else 1
    out.append([code, time.perf_counter() - t])
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"cases": out, "peak": peak}))
"""


def test_the_refusals_stay_within_memory_and_time(tmp_path):
    """The worst cases in one process under a 1.5 GB address-space limit (the import of
    Python, numpy and matplotlib takes about 0.25 GB of it): each ends in exit 2 (the
    chain imports) within 10 s, the whole process under 1 GB resident."""
    m = graph_map(tmp_path / "g.txt", "v 0 0 0 start=0", "v 1 1 0", "e 0 1 1000000000")
    c = config(tmp_path / "c.yaml")
    bomb = alias_bomb(tmp_path / "bomb.yaml", "record.watch", 9)
    png_header(tmp_path / "huge.png", 60_000, 60_000)
    huge = ros_yaml(tmp_path / "huge.yaml", "huge.png")
    zero = ros_yaml(tmp_path / "zero.yaml", "/dev/zero")
    (tmp_path / "tera.graph").write_text("1000000000000\n100 100\n0.05\n0 0\n\n0 1 1 0\n")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    fifo_img = ros_yaml(tmp_path / "fifo.yaml", "fifo")
    chain = chain_xml(tmp_path / "chain.xml", 15_000)
    cases = [
        (["maps", "check", str(m)], 2),
        (["train", str(c), "--set", f"map={m}", "--out", str(tmp_path / "run")], 2),
        (["train", str(bomb), "--out", str(tmp_path / "run")], 2),
        (["maps", "import", str(huge), "--cell", "0.2", "--out", "-"], 2),
        (["maps", "import", str(zero), "--cell", "0.2", "--out", "-"], 2),
        (["maps", "import", str(fifo_img), "--cell", "0.2", "--out", "-"], 2),
        (["maps", "import", str(tmp_path / "tera.graph"), "--out", "-"], 2),
        (["maps", "check", str(fifo)], 2),
        (["train", str(fifo)], 2),
        (["train", str(c), "--set", f"map={fifo}", "--out", str(tmp_path / "run")], 2),
        (["maps", "import", str(chain), "--out", str(tmp_path / "chain.txt")], 0),
    ]
    env = {**os.environ, "QPATROL_LOG_DIR": str(tmp_path / "crash-logs")}
    proc = subprocess.run(
        [sys.executable, "-c", _CHILD, str(1500 << 20), json.dumps([a for a, _ in cases])],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    errors = proc.stderr.strip().splitlines()
    assert len(errors) == len(cases) - 1, errors  # one line per refusal
    assert not any("internal error" in e for e in errors), errors
    for (args, code), (got, seconds) in zip(cases, report["cases"], strict=True):
        assert got == code, (args, errors)
        assert seconds < 10, (args, seconds)
    assert report["peak"] < 1 << 30, report["peak"]
    assert not (tmp_path / "run").exists() and not (tmp_path / "crash-logs").exists()
    assert (tmp_path / "chain.txt").is_file()
