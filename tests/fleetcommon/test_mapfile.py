"""The map_server format: round trips, the format's documented rules, and every bad file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from fleetcommon.mapfile import MapFileError, OccupancyMap, read_map, write_map


def _grid() -> OccupancyMap:
    cells = np.full((4, 6), -1, dtype=np.int8)
    cells[0, :] = 100  # the bottom row: a wall
    cells[1:3, 1:5] = 0
    cells[3, 5] = 100  # top right
    return OccupancyMap(cells, 0.05, (-1.5, 2.0, 0.0))


def test_write_then_read_gives_the_same_grid(tmp_path: Path) -> None:
    pgm, meta = write_map(tmp_path / "map", _grid())
    back = read_map(meta)
    assert np.array_equal(back.cells, _grid().cells)
    assert (back.resolution, back.origin) == (0.05, (-1.5, 2.0, 0.0))
    assert pgm.read_bytes().startswith(b"P5")
    assert [p.name for p in sorted(tmp_path.iterdir())] == ["map.pgm", "map.yaml"]  # no temporary files left
    # the image's first row is the map's top: the top-right occupied cell is black at row 0
    pixels = np.asarray(Image.open(pgm))
    assert pixels[0, 5] == 0 and pixels[3, 0] == 0 and pixels[1, 1] == 254 and pixels[0, 0] == 205
    text = meta.read_text()
    for line in ("image: map.pgm", "mode: trinary", "resolution: 0.05", "negate: 0", "occupied_thresh: 0.65",
                 "free_thresh: 0.196"):  # fmt: skip
        assert line in text


def test_the_documented_thresholds(tmp_path: Path) -> None:
    """nav2_map_server's example: p = (255 - v) / 255, occupied above 0.65, free below 0.196."""
    Image.fromarray(np.array([[0, 254, 205, 100, 180]], dtype=np.uint8)).save(tmp_path / "t.png")
    (tmp_path / "t.yaml").write_text(
        "image: t.png\nresolution: 0.1\norigin: [2.0, 3.0, 1.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    m = read_map(tmp_path / "t.yaml")
    # v=0: p=1 occupied; 254: free; 205: p=0.196, not below: unknown; 100: p=0.61 unknown; 180: p=0.29 unknown
    assert m.cells.tolist() == [[100, 0, -1, -1, -1]]
    assert m.origin == (2.0, 3.0, 1.0)
    (tmp_path / "n.yaml").write_text("image: t.png\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 1\n")
    assert read_map(tmp_path / "n.yaml").cells.tolist() == [[0, 100, 100, -1, 100]]
    (tmp_path / "s.yaml").write_text("image: t.png\nresolution: 0.1\norigin: [0, 0, 0]\nmode: scale\n")
    scaled = read_map(tmp_path / "s.yaml").cells.tolist()[0]
    assert scaled[0] == 100 and scaled[1] == 0 and 0 < scaled[4] < scaled[3] < 100


def test_ascii_pgm(tmp_path: Path) -> None:
    (tmp_path / "a.pgm").write_text("P2\n# a comment\n3 2\n255\n0 254 205\n254 254 0\n")
    (tmp_path / "a.yaml").write_text("image: a.pgm\nresolution: 0.5\norigin: [0, 0, 0]\n")
    # bottom row first; without thresholds in the file, 0.65 / 0.25: 205 reads as free
    assert read_map(tmp_path / "a.yaml").cells.tolist() == [[0, 0, 100], [100, 0, 0]]


@pytest.mark.parametrize(
    ("yaml_text", "where"),
    [
        ("image: missing.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", "cannot read the map image"),
        ("image: ok.pgm\nresolution: -0.05\norigin: [0, 0, 0]\n", "resolution: must be > 0"),
        ("image: ok.pgm\norigin: [0, 0, 0]\n", "resolution: missing"),
        ("resolution: 0.05\norigin: [0, 0, 0]\n", "image: missing"),
        ("image: ok.pgm\nresolution: 0.05\norigin: [0, 0]\n", "origin: must be [x, y, yaw]"),
        ("image: ok.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nmode: fancy\n", "mode: unknown mode"),
        ("image: ok.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nfree_thresh: 0.9\n", "free_thresh"),
        ("image: ok.pgm\nresolution: 0.05\norigin: [0, 0, 0]\ncolour: red\n", "unknown field(s) colour"),
        ("image: big.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", "larger than"),
        ("image: bad.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n", "PGM has"),
        ("image: ok.pgm\nresolution: [\n", "YAML syntax error"),
        ("- just\n- a list\n", "expected a mapping"),
    ],
)
def test_bad_maps_say_what_is_wrong(tmp_path: Path, yaml_text: str, where: str) -> None:
    (tmp_path / "ok.pgm").write_bytes(b"P5\n2 1\n255\n\x00\xfe")
    (tmp_path / "big.pgm").write_bytes(b"P5\n5000 5000\n255\n")
    (tmp_path / "bad.pgm").write_bytes(b"P5\n4 4\n255\n\x00\x00")
    (tmp_path / "m.yaml").write_text(yaml_text)
    with pytest.raises(MapFileError) as e:
        read_map(tmp_path / "m.yaml")
    assert where in str(e.value) and str(tmp_path) in str(e.value)


def test_writing_refuses_to_overwrite_and_needs_the_directory(tmp_path: Path) -> None:
    (tmp_path / "map.yaml").write_text("mine")
    with pytest.raises(MapFileError, match="already exists"):
        write_map(tmp_path / "map", _grid())
    assert (tmp_path / "map.yaml").read_text() == "mine" and not (tmp_path / "map.pgm").exists()
    write_map(tmp_path / "map", _grid(), force=True)
    assert read_map(tmp_path / "map.yaml").cells.shape == (4, 6)
    with pytest.raises(MapFileError, match="no such directory"):
        write_map(tmp_path / "nowhere" / "map", _grid())
