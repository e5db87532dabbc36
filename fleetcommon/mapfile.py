"""Occupancy maps in the ROS map_server format: a YAML file beside a PGM (or PNG) image.

The format nav2_map_server loads and its map saver writes (nav2_map_server's ``map_io``):

    image: map.pgm            # relative to the YAML file
    mode: trinary             # trinary | scale | raw
    resolution: 0.05          # metres per pixel
    origin: [-10.0, -10.0, 0] # the lower-left pixel's pose (x, y, yaw) in the map frame
    negate: 0
    occupied_thresh: 0.65
    free_thresh: 0.25

A pixel's occupancy probability is ``(255 - v) / 255`` (``v / 255`` with ``negate: 1``): above
``occupied_thresh`` it is occupied (100), below ``free_thresh`` free (0), else unknown (-1) in
trinary mode; ``scale`` keeps the probability in between as 0..100, ``raw`` takes the value as it
is. The image's first row is the top of the map (largest y). The saver writes trinary maps with
occupied 0, free 254 and unknown 205, and so does :func:`write_map` (with ``free_thresh: 0.196``,
see :data:`FREE_THRESH`).

Both the daemon (a map as a world) and ``fleet-map`` (writing one) use this module, so it lives
with the other file contracts. A map file is untrusted input: every problem is a
:class:`MapFileError` naming the file and the field, and writing never leaves half a map behind.
"""

from __future__ import annotations

import math
import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml

from fleetcommon.files import FileFormatError

#: the largest image read or written (a 100 m x 100 m world at 2.5 cm is 16 megapixels)
MAX_PIXELS = 16_000_000
MODES = ("trinary", "scale", "raw")
OCCUPIED, FREE, UNKNOWN = 100, 0, -1
#: what the map saver writes for each
PIXEL_OCCUPIED, PIXEL_FREE, PIXEL_UNKNOWN = 0, 254, 205

I8 = npt.NDArray[np.int8]


class MapFileError(FileFormatError):
    """A map that cannot be used, with where (file, field) and why."""


@dataclass(frozen=True, eq=False)
class OccupancyMap:
    """A grid as nav_msgs/OccupancyGrid holds it: ``cells[row, col]`` with row 0 at the
    *bottom* (smallest y), values 100 occupied, 0 free, -1 unknown (0..100 in between with
    ``scale`` mode); ``origin`` is the pose of cell (0, 0)'s lower-left corner."""

    cells: I8
    resolution: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def height(self) -> int:
        return int(self.cells.shape[0])

    @property
    def width(self) -> int:
        return int(self.cells.shape[1])

    def bounds(self) -> tuple[float, float, float, float]:
        """x_min, x_max, y_min, y_max of the grid (yaw 0 maps only)."""
        x0, y0, _ = self.origin
        return x0, x0 + self.width * self.resolution, y0, y0 + self.height * self.resolution


# --- reading ----------------------------------------------------------------------------------


def read_map(yaml_path: str | os.PathLike[str]) -> OccupancyMap:
    """Load a map_server map (YAML and its image)."""
    path = Path(yaml_path)
    source = str(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise MapFileError(source, f"cannot read it: {e.strerror or e}") from None
    try:
        meta = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise MapFileError(source, f"YAML syntax error: {' '.join(str(e).split())}") from None
    except RecursionError:
        raise MapFileError(source, "YAML syntax error: nested too deep") from None
    if not isinstance(meta, dict):
        raise MapFileError(source, "expected a mapping with image, resolution, origin, ...")
    image_name = _field(meta, "image", str, source)
    resolution = _number(meta, "resolution", source)
    if not resolution > 0:
        raise MapFileError(source, f"must be > 0, got {_shown(resolution)}", "resolution")
    origin = meta.get("origin")
    if (
        not isinstance(origin, list)
        or len(origin) != 3
        or not all(isinstance(v, int | float) and math.isfinite(v) for v in origin)
    ):
        raise MapFileError(source, f"must be [x, y, yaw] in numbers, got {_shown(origin)}", "origin")
    mode = meta.get("mode", "trinary")
    if mode not in MODES:
        raise MapFileError(source, f"unknown mode {_shown(mode)}; one of {', '.join(MODES)}", "mode")
    negate = meta.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise MapFileError(source, f"must be 0 or 1, got {_shown(negate)}", "negate")
    occupied = _number(meta, "occupied_thresh", source, 0.65)
    free = _number(meta, "free_thresh", source, 0.25)
    if not 0 <= free <= occupied <= 1:
        raise MapFileError(source, f"need 0 <= free_thresh ({free}) <= occupied_thresh ({occupied}) <= 1")
    unknown = set(meta) - {"image", "resolution", "origin", "mode", "negate", "occupied_thresh", "free_thresh"}
    if unknown:
        raise MapFileError(source, f"unknown field(s) {', '.join(sorted(map(str, unknown)))}")
    image_path = (path.parent / image_name) if not os.path.isabs(image_name) else Path(image_name)
    pixels = read_image(image_path)
    cells = _occupancy(pixels, mode, bool(negate), occupied, free)
    return OccupancyMap(
        np.flipud(cells).copy(), float(resolution), (float(origin[0]), float(origin[1]), float(origin[2]))
    )


def _field(meta: dict[str, Any], name: str, kind: type, source: str) -> Any:
    if name not in meta:
        raise MapFileError(source, "missing", name)
    value = meta[name]
    if not isinstance(value, kind):
        raise MapFileError(source, f"must be a {kind.__name__}, got {_shown(value)}", name)
    return value


def _number(meta: dict[str, Any], name: str, source: str, default: float | None = None) -> float:
    if name not in meta and default is not None:
        return default
    if name not in meta:
        raise MapFileError(source, "missing", name)
    value = meta[name]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise MapFileError(source, f"must be a number, got {_shown(value)}", name)
    return float(value)


def _occupancy(pixels: npt.NDArray[np.uint8], mode: str, negate: bool, occupied: float, free: float) -> I8:
    """map_server's rule, pixel by pixel (image rows, top first)."""
    if mode == "raw":
        return pixels.astype(np.int16).clip(-1, 100).astype(np.int8)
    value = pixels.astype(np.float64)
    p = value / 255.0 if negate else (255.0 - value) / 255.0
    out = np.full(pixels.shape, UNKNOWN, dtype=np.int8)
    out[p > occupied] = OCCUPIED
    out[p < free] = FREE
    if mode == "scale":
        between = (p >= free) & (p <= occupied)
        out[between] = np.rint(99 * (p[between] - free) / (occupied - free)).astype(np.int8)
    return out


def read_image(path: Path) -> npt.NDArray[np.uint8]:
    """A greyscale image as rows of 0..255: PGM (P5, P2) here, anything else through Pillow."""
    source = str(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise MapFileError(source, f"cannot read the map image: {e.strerror or e}") from None
    if data[:2] in (b"P5", b"P2"):
        return _read_pgm(data, source)
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - Pillow is a dependency; a trimmed install may lack it
        raise MapFileError(source, "only PGM images can be read without Pillow (pip install pillow)") from None
    try:
        with Image.open(path) as im:
            if im.width * im.height > MAX_PIXELS:
                raise MapFileError(source, f"image of {im.width}x{im.height} pixels is larger than {MAX_PIXELS}")
            grey = im.convert("L")
            return np.asarray(grey, dtype=np.uint8).copy()
    except MapFileError:
        raise
    except Exception as e:  # Pillow raises several kinds for files that are not images
        raise MapFileError(source, f"not an image Pillow can read: {e}") from None


_PGM_HEADER = re.compile(rb"^(P[25])\s+(?:#[^\n]*\n\s*)*(\d+)\s+(?:#[^\n]*\n\s*)*(\d+)\s+(?:#[^\n]*\n\s*)*(\d+)\s")


def _read_pgm(data: bytes, source: str) -> npt.NDArray[np.uint8]:
    m = _PGM_HEADER.match(data)
    if m is None:
        raise MapFileError(source, "malformed PGM header")
    kind, width, height, maxval = m.group(1), int(m.group(2)), int(m.group(3)), int(m.group(4))
    if width < 1 or height < 1 or width * height > MAX_PIXELS:
        raise MapFileError(source, f"image of {width}x{height} pixels: empty, or larger than {MAX_PIXELS}")
    if not 0 < maxval < 256:
        raise MapFileError(source, f"PGM maxval {maxval}: only 8-bit images are supported")
    body = data[m.end() :]
    if kind == b"P5":
        if len(body) < width * height:
            raise MapFileError(source, f"PGM has {len(body)} bytes of pixels, needs {width * height}")
        pixels = np.frombuffer(body[: width * height], dtype=np.uint8).reshape(height, width)
    else:
        try:
            values = np.array(body.split(), dtype=np.int64)
        except ValueError:
            raise MapFileError(source, "PGM (P2) pixels are not numbers") from None
        if values.size < width * height:
            raise MapFileError(source, f"PGM has {values.size} pixels, needs {width * height}")
        pixels = values[: width * height].reshape(height, width).clip(0, 255).astype(np.uint8)
    if maxval != 255:
        pixels = np.rint(pixels.astype(np.float64) * 255.0 / maxval).astype(np.uint8)
    return pixels.copy()


# --- writing ----------------------------------------------------------------------------------


def pixels_of(grid: OccupancyMap) -> npt.NDArray[np.uint8]:
    """The map saver's trinary image of a grid (rows top first)."""
    cells = np.flipud(grid.cells)
    out = np.full(cells.shape, PIXEL_UNKNOWN, dtype=np.uint8)
    out[cells == FREE] = PIXEL_FREE
    out[cells >= 65] = PIXEL_OCCUPIED
    return out


#: written as ROS 1's map saver did (the TurtleBot3 maps carry it): the unknown grey, 205, has a
#: probability of exactly 0.196, so a reader that tests ``p < free_thresh`` keeps it unknown;
#: with 0.25 (nav2's saver default) it would load as free
FREE_THRESH = 0.196


def write_map(stem: str | os.PathLike[str], grid: OccupancyMap, *, force: bool = False) -> tuple[Path, Path]:
    """Write ``STEM.pgm`` and ``STEM.yaml`` as the map saver does (trinary, 0.65 / 0.196).

    Each file is written to a temporary name and renamed into place, so a failure leaves no half
    map; without ``force`` an existing file is refused (MapFileError) and nothing is written."""
    stem = Path(stem)
    pgm, meta = stem.with_name(stem.name + ".pgm"), stem.with_name(stem.name + ".yaml")
    if not stem.parent.is_dir():
        raise MapFileError(str(stem.parent), "no such directory: create it first")
    if not force:
        taken = [str(p) for p in (pgm, meta) if p.exists()]
        if taken:
            raise MapFileError(taken[0], "already exists: choose another name, or --force to replace it")
    if grid.width * grid.height > MAX_PIXELS:
        raise MapFileError(str(pgm), f"a map of {grid.width}x{grid.height} cells is larger than {MAX_PIXELS}")
    pixels = pixels_of(grid)
    header = f"P5\n# fleetsim map, {grid.resolution:g} m/pixel\n{grid.width} {grid.height}\n255\n".encode()
    x, y, yaw = grid.origin
    text = (
        f"image: {pgm.name}\nmode: trinary\nresolution: {grid.resolution:g}\n"
        f"origin: [{x:.6g}, {y:.6g}, {yaw:.6g}]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: {FREE_THRESH}\n"
    )
    _atomic_write(pgm, header + pixels.tobytes())
    _atomic_write(meta, text.encode())
    return pgm, meta


def _atomic_write(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o644)  # as any file the user writes (mkstemp makes it private)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _shown(value: object, most: int = 60) -> str:
    """A value as a message quotes it: its repr, cut to ``most`` characters (a file's value
    may be a megabyte of text)."""
    text = repr(value)
    return text if len(text) <= most else text[: most - 3] + "..."
