"""ROS occupancy maps -> qpatrol maps: pixel semantics, cells, regions, placement, CLI."""

from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image as PILImage
from typer.testing import CliRunner

from qpatrol.cli import app
from qpatrol.config import from_mapping
from qpatrol.maps import load_map, parse_map
from qpatrol.maps.images import parse_pgm, read_image
from qpatrol.maps.importer import (
    RosMapError,
    crop,
    default_stations,
    import_map,
    import_ros_map,
    largest_region,
    place,
    read_occupancy,
    to_cells,
)
from qpatrol.maps.ros import occupancy
from qpatrol.run import simulate

runner = CliRunner()
WHITE, GREY, BLACK = 254, 205, 0  # map_saver's free, unknown and occupied greys


# --- writing test images ---------------------------------------------------------------


def write_p5(path: Path, pixels: np.ndarray, maxval: int = 255) -> Path:
    h, w = pixels.shape
    dtype = np.uint8 if maxval < 256 else ">u2"
    head = f"P5\n# CREATOR: qpatrol test\n{w} {h}\n# a comment between fields\n{maxval}\n"
    path.write_bytes(head.encode() + pixels.astype(dtype).tobytes())
    return path


def write_p2(path: Path, pixels: np.ndarray, maxval: int = 255) -> Path:
    h, w = pixels.shape
    rows = "\n".join(" ".join(str(int(v)) for v in row) for row in pixels)
    path.write_text(f"P2\n# comment\n{w}\n# another\n{h} {maxval}\n{rows}\n")
    return path


def write_png(path: Path, pixels: np.ndarray) -> Path:
    PILImage.fromarray(pixels.astype(np.uint8)).save(path)  # L, RGB or RGBA from the shape
    return path


def write_yaml(path: Path, image: str, **keys) -> Path:
    doc = {
        "image": image,
        "resolution": 0.05,
        "origin": [-1.0, 2.0, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
    }
    doc.update(keys)
    path.write_text(yaml.safe_dump({k: v for k, v in doc.items() if v is not None}))
    return path


def floor_plan(layout: list[str], px: int) -> np.ndarray:
    """Pixels of a layout drawn ``px`` pixels per character: '#' black, '?' grey, else white."""
    grey = {"#": BLACK, "?": GREY}
    cells = np.array([[grey.get(ch, WHITE) for ch in row] for row in layout])
    return np.kron(cells, np.ones((px, px), dtype=np.int64))


def plain(text: str) -> list[str]:
    """Grid rows of a map text with digits and H shown as '.'."""
    rows = [r for r in text.splitlines() if not r.startswith(";")]
    return ["".join("." if ch != "#" else "#" for ch in r) for r in rows]


# --- pixel semantics (map_server) -------------------------------------------------------

# grey value -> p = (255 - v) / 255 -> trinary value with occupied 0.65, free 0.196:
#   0 -> 1.0 occ | 89 -> 0.6510 occ | 90 -> 0.6471 unk | 128 -> 0.4980 unk
#   205 -> 0.19608 unk (just above 0.196) | 206 -> 0.19216 free | 255 -> 0 free
ROW = np.array([[0, 89, 90, 128, 205, 206, 255]])
TRINARY = [100, 100, -1, -1, -1, 0, 0]
# negate 1: p = v / 255 -> 0 free, 0.349 .. 0.502 unknown, 0.804 .. 1 occupied
NEGATED = [0, -1, -1, -1, 100, 100, 100]


def test_trinary_thresholds_by_hand(tmp_path: Path):
    y = write_yaml(tmp_path / "m.yaml", "m.pgm")
    write_p5(tmp_path / "m.pgm", ROW)
    ros = read_occupancy(y)
    assert ros.occ.dtype == np.int8
    assert ros.occ.tolist() == [TRINARY]
    assert ros.free().tolist() == [[False] * 5 + [True, True]]
    assert ros.resolution == 0.05 and ros.origin == (-1.0, 2.0, 0.0) and ros.mode == "trinary"


def test_negate(tmp_path: Path):
    write_p5(tmp_path / "m.pgm", ROW)
    ros = read_occupancy(write_yaml(tmp_path / "m.yaml", "m.pgm", negate=1))
    assert ros.occ.tolist() == [NEGATED]
    # a floor plan drawn inverted (black free) imports to the same map as the original
    layout = ["#####", "#...#", "#.#.#", "#...#", "#####"]
    write_p5(tmp_path / "a.pgm", floor_plan(layout, 3))
    write_p5(tmp_path / "b.pgm", 255 - floor_plan(layout, 3))
    a = import_ros_map(write_yaml(tmp_path / "a.yaml", "a.pgm"), 0.15, agents=1, stations=1)
    b = import_ros_map(write_yaml(tmp_path / "b.yaml", "b.pgm", negate=1), 0.15, 1, 1)
    assert plain(a) == plain(b) == layout


def test_p2_p5_png_and_16_bit_read_alike(tmp_path: Path):
    pixels = np.array([[0, 89, 90], [205, 206, 255]])
    deep = np.minimum(pixels * 257 + 3, 65535)  # 16-bit values that are not 8-bit ones
    occs = []
    for name, writer, data, maxval in [
        ("a.pgm", write_p5, pixels, 255),
        ("b.pgm", write_p2, pixels, 255),
        ("c.pgm", write_p5, pixels * 257, 65535),
        ("d.pgm", write_p2, pixels * 257, 65535),
    ]:
        writer(tmp_path / name, data, maxval)
        img = read_image(tmp_path / name)
        assert img.maxval == maxval and img.samples.shape == (2, 3, 1)
        occs.append(occupancy(img).tolist())
    write_png(tmp_path / "e.png", pixels)
    occs.append(occupancy(read_image(tmp_path / "e.png")).tolist())
    PILImage.fromarray(deep.astype(np.uint16)).save(tmp_path / "f.png")
    img16 = read_image(tmp_path / "f.png")
    assert img16.maxval == 65535
    occs.append(occupancy(img16).tolist())
    assert all(o == [[100, 100, -1], [-1, 0, 0]] for o in occs)


def test_pgm_header_comments_and_bad_pgms():
    img = parse_pgm(b"P5#c\n2#w\n 1\n#m\n255\n\x00\xff")
    assert img.samples[:, :, 0].tolist() == [[0, 255]]
    for data, words in [
        (b"P5\n2 2\n255\n\x00", "truncated: 1 of 4"),
        (b"P5\n2 x\n255\n", "height b'x' is not a number"),
        (b"P2\n2 1\n255\n0 300\n", "exceeds maxval"),
        (b"P5\n0 1\n255\n", "empty image"),
        (b"P2\n2 1\n", "ends before its maxval"),
        (b"P5\n1 1\n70000\n\x00\x00", "outside 1..65535"),
    ]:
        with pytest.raises(ValueError, match="x.pgm: PGM") as e:
            parse_pgm(data, "x.pgm")
        assert words in str(e.value)


def test_png_colour_and_alpha(tmp_path: Path):
    # RGB: the mean of the channels, as map_server: (255, 255, 0) -> 170 -> p 0.33 unknown
    rgb = np.array([[[255, 255, 255], [255, 255, 0], [0, 0, 30]]])
    assert occupancy(read_image(write_png(tmp_path / "c.png", rgb))).tolist() == [[0, -1, 100]]
    # RGBA: trinary averages alpha in, as map_server does (white transparent -> 191.25 ->
    # p 0.25: unknown; opaque (40, 40, 40) -> 93.75 -> p 0.63: unknown too); scale leaves
    # alpha out of the mean and marks transparent in-between pixels unknown
    rgba = np.array([[[255, 255, 255, 255], [255, 255, 255, 0], [128, 128, 128, 255]]])
    rgba2 = np.array([[[128, 128, 128, 0], [0, 0, 0, 0], [40, 40, 40, 255]]])
    img = read_image(write_png(tmp_path / "a.png", np.concatenate([rgba, rgba2])))
    assert img.has_alpha
    assert occupancy(img).tolist() == [[0, -1, -1], [-1, 100, -1]]
    # scale: 128 -> p 0.498 -> 1 + 98 (0.498 - 0.196) / (0.65 - 0.196) = 66.2 -> 66
    assert occupancy(img, mode="scale").tolist() == [[0, 0, 66], [-1, 100, 100]]


def test_raw_mode(tmp_path: Path):
    # raw: the grey value is the occupancy in percent; above 100 (255 = -1) unknown
    write_p5(tmp_path / "r.pgm", np.array([[0, 10, 19, 20, 100, 101, 255]]))
    ros = read_occupancy(write_yaml(tmp_path / "r.yaml", "r.pgm", mode="raw"))
    assert ros.occ.tolist() == [[0, 10, 19, 20, 100, -1, -1]]
    assert ros.free_max == 19  # 19 / 100 < free_thresh 0.196 <= 20 / 100
    assert ros.free().tolist() == [[True, True, True, False, False, False, False]]


# --- cells, regions, crop ----------------------------------------------------------------


def test_to_cells_integer_ratio_and_partial_border():
    # 5 x 7 pixels, cells of 2 px anchored at the bottom-left corner (the ROS origin):
    # 2 rows x 3 cols of whole cells; the top pixel row and the right column are left out
    occ = np.zeros((5, 7), dtype=np.int8)
    occ[0, :] = 100  # the partial top row: no effect
    occ[:, 6] = -1  # the partial right column: no effect
    assert to_cells(occ, 0.1, 0.2).tolist() == [[True] * 3, [True] * 3]
    occ[1, 0] = 100  # a wall pixel in the top-left whole cell
    occ[4, 5] = -1  # an unknown pixel in the bottom-right cell
    assert to_cells(occ, 0.1, 0.2).tolist() == [[False, True, True], [True, True, False]]


def test_to_cells_non_integer_ratio_uses_metric_boundaries():
    # 1.5 px per cell: cell 0 covers pixels [0, 1.5), cell 1 [1.5, 3); pixel 1 is in both
    occ = np.zeros((3, 3), dtype=np.int8)
    assert to_cells(occ, 1.0, 1.5).shape == (2, 2)
    occ[:, 1] = 100
    assert to_cells(occ, 1.0, 1.5).tolist() == [[False, False], [False, False]]
    occ[:, 1] = 0
    occ[:, 2] = 100
    assert to_cells(occ, 1.0, 1.5).tolist() == [[True, False], [True, False]]


def test_cell_smaller_than_a_pixel():
    with pytest.raises(RosMapError, match="smaller than one pixel"):
        to_cells(np.zeros((4, 4), dtype=np.int8), 0.05, 0.04)
    assert to_cells(np.zeros((4, 4), dtype=np.int8), 0.05, 0.05).shape == (4, 4)


def test_largest_region_and_crop():
    free = np.array(
        [
            [1, 1, 0, 0, 0, 0],
            [0, 0, 0, 1, 1, 0],
            [0, 0, 0, 1, 1, 1],
            [1, 0, 0, 0, 0, 0],
        ],
        dtype=bool,
    )
    region, n = largest_region(free)
    assert n == 3
    assert region.sum() == 5 and region[1, 3] and not region[0, 0]
    grid, offset = crop(region)
    assert offset == (0, 2)
    assert grid.astype(int).tolist() == [
        [0, 0, 0, 0, 0],
        [0, 1, 1, 0, 0],
        [0, 1, 1, 1, 0],
        [0, 0, 0, 0, 0],
    ]
    assert largest_region(np.zeros((2, 2), dtype=bool))[1] == 0


def test_unknown_pixels_are_walls_and_split_regions(tmp_path: Path):
    # a corridor of five cells whose second cell holds one grey (unknown) pixel
    layout = ["#######", "#.....#", "#######"]
    pixels = floor_plan(layout, 4)
    pixels[4 + 1, 8 + 2] = GREY
    write_p5(tmp_path / "c.pgm", pixels)
    y = write_yaml(tmp_path / "c.yaml", "c.pgm")
    result = import_map(y, 0.2, agents=1, stations=1)
    assert result.regions == 2 and result.free_cells == 4
    assert plain(result.text) == ["#####", "#...#", "#####"]


# --- placement ---------------------------------------------------------------------------


def test_farthest_point_placement_on_a_corridor():
    free = np.ones((1, 21), dtype=bool)
    starts, homes = place(free, agents=2, stations=2)
    # start 0 in the middle (10), start 1 at the farther end, lowest index on a tie (0);
    # stations: not on starts nor dead ends, first nearest the middle (9 before 11),
    # then farthest from it (19)
    assert starts[:, 1].tolist() == [10, 0]
    assert homes[:, 1].tolist() == [9, 19]


def test_default_stations():
    assert [default_stations(n) for n in (1, 150, 151, 695, 1105)] == [1, 1, 2, 5, 8]


def test_placement_errors():
    free = np.ones((1, 4), dtype=bool)
    with pytest.raises(RosMapError, match="4 free cells cannot hold 3 starts, 2 charging"):
        place(free, 3, 2)
    with pytest.raises(RosMapError, match="agents: 11 start digits"):
        place(np.ones((5, 5), dtype=bool), 11, 1)


# --- end to end ----------------------------------------------------------------------------

LAYOUT = [
    "############",
    "#....#...#.#",
    "#.##.#.#.#.#",
    "#.#......###",
    "#...##.#.#.#",
    "############",
]
#: the main region of LAYOUT, cropped (the pockets at the right are dropped)
EXPECTED = [
    "##########",
    "#....#...#",
    "#.##.#.#.#",
    "#.#......#",
    "#...##.#.#",
    "##########",
]


def make_floor(tmp_path: Path, fmt: str = "pgm") -> Path:
    """LAYOUT at 4 px per cell, with a 2 px strip on top and 3 px on the right (partial cells)."""
    body = floor_plan(LAYOUT, 4)
    pixels = np.full((body.shape[0] + 2, body.shape[1] + 3), WHITE)
    pixels[2:, : body.shape[1]] = body
    image = tmp_path / f"floor.{fmt}"
    if fmt == "png":
        write_png(image, np.stack([pixels] * 3, axis=2))
    else:
        write_p5(image, pixels)
    return write_yaml(tmp_path / "floor.yaml", image.name)


@pytest.mark.parametrize("fmt", ["pgm", "png"])
def test_import_end_to_end(tmp_path: Path, fmt: str):
    y = make_floor(tmp_path, fmt)
    result = import_map(y, 0.2, agents=3, stations=2)
    m = parse_map(result.text)
    assert plain(result.text) == EXPECTED
    assert result.regions == 3 and result.cell_pixels == pytest.approx(4)
    assert len(m.starts) == 3 and len(m.homes) == 2
    assert not set(m.homes.tolist()) & set(m.starts.tolist())
    assert (m.degree[m.homes] >= 2).all()
    assert m.name == "floor"
    assert "floor.yaml" in m.description and f"floor.{fmt}" in m.description
    for words in ("resolution 0.05 m/px", "origin [-1, 2, 0]", "0.2 m cells (4 px)"):
        assert words in m.description
    # the grid's top-left corner: x = -1 + (1 - 1) * 0.2 (column 1 of cells is the first
    # free one, minus the border), y = 2 + 6 * 0.2 (six whole rows of cells up from the origin)
    assert "X0 = -1, Y0 = 3.2" in result.text
    assert import_ros_map(y, 0.2, 3, 2) == result.text  # deterministic


def test_imported_map_trains_with_battery(tmp_path: Path):
    y = make_floor(tmp_path)
    path = tmp_path / "floor.txt"
    path.write_text(import_ros_map(y, 0.2, agents=2))
    m = load_map(path)
    assert len(m.homes) == 1 and len(m.starts) == 2
    cfg = from_mapping(
        {
            "map": str(path),
            "agents": 2,
            "runs": 2,
            "steps": 300,
            "battery": {"enabled": True, "capacity": 30, "margin": 2, "charge_steps": 3},
            "record": {"watch": []},
        }
    )
    result = simulate(cfg)
    assert result.map.n_cells == m.n_cells == 23
    moves = result.measures.visits.sum(axis=2)
    assert (moves > 30).all()  # more moves than one charge: every agent has recharged
    assert min(s["coverage"] for s in result.summary) > 0.5


# --- CLI -------------------------------------------------------------------------------


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def test_cli_import_check_show_and_train(tmp_path: Path, monkeypatch):
    y = make_floor(tmp_path)
    monkeypatch.chdir(tmp_path)
    res = invoke("maps", "import", y, "--cell", 0.2, "--agents", 2)
    assert res.exit_code == 0, res.output
    target = tmp_path / "maps" / "floor.txt"
    assert "wrote maps/floor.txt: 10 x 6 grid, 23 free cells" in res.stdout
    assert "kept the largest of 3 free regions (23 of 26 free cells)" in res.stdout
    assert invoke("maps", "check", target).exit_code == 0
    assert "floor: imported from ROS map floor.yaml" in invoke("maps", "show", "floor").stdout
    res = invoke("maps", "import", y, "--cell", 0.2)
    assert res.exit_code == 2 and "already exists; pass --force" in res.stderr
    assert invoke("maps", "import", y, "--cell", 0.2, "--force").exit_code == 0
    res = invoke("maps", "import", y, "--cell", 0.2, "--out", "-", "--stations", 3)
    assert res.exit_code == 0
    assert res.stdout.startswith("; name: floor\n")
    assert sum(row.count("H") for row in res.stdout.splitlines() if row[0] == "#") == 3
    assert "23 free cells" in res.stderr
    config = Path(__file__).resolve().parent.parent / "configs" / "paper.yaml"
    sets = ["--set", f"map={target}", "--set", "steps=200", "--set", "record.watch=[]"]
    res = invoke("train", config, *sets, "--out", tmp_path / "run", "--quiet")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "run" / "summary.json").exists()


def _errors(tmp_path: Path) -> list[tuple[list, str]]:
    """(arguments after ``maps import``, words of the one-line error) for each bad input."""
    write_p5(tmp_path / "ok.pgm", np.full((8, 8), WHITE))
    write_p5(tmp_path / "black.pgm", np.zeros((8, 8)))
    (tmp_path / "pic.jpg").write_bytes(b"\xff\xd8\xff\xe0 not really a jpeg")
    (tmp_path / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    (tmp_path / "c.ppm").write_bytes(b"P6\n1 1\n255\n\x00\x00\x00")
    (tmp_path / "junk.pgm").write_bytes(b"\x00\x01 junk")
    (tmp_path / "syntax.yaml").write_text("image: [ok.pgm\n")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    cell = ["--cell", "0.05"]

    def y(name: str, image: str = "ok.pgm", **keys) -> Path:
        return write_yaml(tmp_path / f"{name}.yaml", image, **keys)

    return [
        ([tmp_path / "nope.yaml", *cell], "nope.yaml: no such map YAML file"),
        ([y("noimg", "gone.pgm"), *cell], "gone.pgm: no such image file"),
        ([y("res", resolution=-1), *cell], "resolution: -1 is not a number > 0"),
        ([y("res2", resolution=None), *cell], "resolution: missing; expected a number > 0"),
        ([y("neg", negate=2), *cell], "negate: 2 is not 0 or 1"),
        ([y("mode", mode="fancy"), *cell], "mode: 'fancy' is not one of trinary, scale, raw"),
        ([y("orig", origin=[0, 0]), *cell], "origin: [0, 0] is not a list [x, y, yaw]"),
        ([y("thr", occupied_thresh=1.5), *cell], "occupied_thresh: 1.5 is not a number in [0, 1]"),
        ([y("thr2", free_thresh=0.7), *cell], "free_thresh: 0.7 is not below occupied_thresh"),
        ([tmp_path / "syntax.yaml", *cell], "not valid YAML at line 2"),
        ([tmp_path / "list.yaml", *cell], "expected a mapping of map_server keys"),
        ([y("jpg", "pic.jpg"), *cell], "unsupported image format (JPEG)"),
        ([y("png", "bad.png"), *cell], "bad.png: cannot read PNG"),
        ([y("ppm", "c.ppm"), *cell], "unsupported image format (netpbm P6)"),
        ([y("junk", "junk.pgm"), *cell], "unsupported image format (unrecognised content"),
        ([y("black", "black.pgm"), *cell], "no free cell of 0.05 m (0 of 64 pixels free)"),
        ([y("small"), "--cell", "0.01"], "cell: 0.01 m is smaller than one pixel"),
        ([y("zero"), "--cell", "0"], "cell: 0.0 is not a size in metres"),
        ([y("big"), "--cell", "1"], "no free cell of 1 m"),
        ([y("agents"), *cell, "--agents", "11"], "agents: 11 start digits; allowed: 0 to 10"),
        ([y("nocell")], "--cell METRES is required"),
    ]


def test_cli_errors_exit_2_with_one_line(tmp_path: Path):
    out = tmp_path / "out.txt"
    for args, words in _errors(tmp_path):
        res = invoke("maps", "import", *args, "--out", out)
        assert res.exit_code == 2, (args, res.output)
        assert words in res.stderr, (words, res.stderr)
        assert len(res.stderr.strip().splitlines()) == 1
        assert "Traceback" not in res.output
        assert not out.exists()
