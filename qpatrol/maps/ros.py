"""Read a ROS ``map_server`` map (a YAML file and its image) into an occupancy grid.

The YAML keys are map_server's: ``image`` (path, relative to the YAML's folder unless
absolute), ``resolution`` (metres per pixel), ``origin`` ([x, y, yaw] of the lower-left
pixel), ``negate`` (0/1), ``occupied_thresh``, ``free_thresh`` and the optional ``mode``
(``trinary``, the default, ``scale`` or ``raw``). Other keys are ignored, as
map_server does.

Pixel values follow map_server (ROS 1, ``image_loader.cpp``). A pixel's ``color_avg``
is the mean of its channels on a 0..255 scale; alpha is averaged in with the colours
in trinary mode and left out in the other modes, as map_server does. With ``negate``
it becomes ``255 - color_avg``. Then, with ``p = (255 - color_avg) / 255`` (the
occupancy probability):

- trinary: 100 (occupied) if ``p > occupied_thresh``, 0 (free) if ``p < free_thresh``,
  else -1 (unknown);
- scale: 100 and 0 as in trinary; in between ``1 + 98 (p - free) / (occ - free)``
  (truncated), or -1 on a fully transparent pixel;
- raw: ``floor(color_avg)`` itself, the occupancy in percent (``negate`` applies here
  too, as in map_server).

Where map_server's behaviour is an accident of its C types, this module differs: the
samples of 16-bit (or any non-8-bit) images are scaled by 255 / maxval; a pixel without
an alpha channel is opaque (map_server takes an RGB pixel's blue byte as its alpha);
raw values above 100 are -1, as in ROS 2's nav2_map_server (map_server writes them as
a byte, so 255 becomes -1 but 101..254 become other values).

A pixel is *free* for qpatrol when its occupancy probability is below ``free_thresh``:
value 0 in trinary and scale mode (scale's 1..99 lie between the thresholds), a value
``v`` with ``v / 100 < free_thresh`` in raw mode. Unknown (-1) is never free.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from qpatrol.maps.images import Image, ImageError, read_image
from qpatrol.util.inputs import (
    MAX_YAML_BYTES,
    BoundedLoader,
    InputError,
    YAMLRefused,
    read_text_capped,
    short_repr,
)

MODES = ("trinary", "scale", "raw")
UNKNOWN, FREE, OCCUPIED = -1, 0, 100


class RosMapError(ValueError):
    """A ROS map that cannot be read; the message is one line naming the file and key."""


@dataclass(frozen=True)
class RosMap:
    """An occupancy grid as map_server would publish it, but with row 0 at the top.

    Attributes:
        occ: int8 ``[height, width]``: -1 unknown, 0 free, 100 occupied, 1..99 partly
            occupied (scale mode) or the raw value (raw mode). Row 0 is the top (north)
            of the image; map_server stores the rows bottom-up.
        resolution: metres per pixel.
        origin: (x, y, yaw) of the lower-left pixel's corner in the map frame.
        mode: ``trinary``, ``scale`` or ``raw``.
        negate: the YAML's ``negate``.
        occupied_thresh: the YAML's ``occupied_thresh``.
        free_thresh: the YAML's ``free_thresh``.
        yaml_path: the YAML file read.
        image_path: the image it names.
    """

    occ: np.ndarray
    resolution: float
    origin: tuple[float, float, float]
    mode: str
    negate: bool
    occupied_thresh: float
    free_thresh: float
    yaml_path: Path
    image_path: Path

    @property
    def free_max(self) -> int:
        """Largest ``occ`` value counted as free: 0, in raw mode the last v < 100 free_thresh."""
        if self.mode != "raw":
            return FREE
        return max((v for v in range(101) if v / 100 < self.free_thresh), default=-1)

    def free(self) -> np.ndarray:
        """bool ``[height, width]``: True on free pixels (unknown is not free)."""
        return (self.occ >= 0) & (self.occ <= self.free_max)


def read_occupancy(yaml_path: str | Path) -> RosMap:
    """Read a map_server YAML and its image; raise :class:`RosMapError` on any problem."""
    path = Path(yaml_path)
    meta = read_metadata(path)
    image_path = Path(meta["image"])
    if not image_path.is_absolute():
        image_path = path.parent / image_path
    try:
        img = read_image(image_path)
    except ImageError as e:
        raise RosMapError(f"{path}: image: {e}") from None
    occ = occupancy(
        img,
        negate=meta["negate"],
        occupied_thresh=meta["occupied_thresh"],
        free_thresh=meta["free_thresh"],
        mode=meta["mode"],
    )
    return RosMap(
        occ=occ,
        resolution=meta["resolution"],
        origin=meta["origin"],
        mode=meta["mode"],
        negate=meta["negate"],
        occupied_thresh=meta["occupied_thresh"],
        free_thresh=meta["free_thresh"],
        yaml_path=path,
        image_path=image_path,
    )


def read_metadata(path: Path) -> dict[str, Any]:
    """The YAML's keys, checked and typed: image (str), resolution, origin (3 floats),
    negate (bool), occupied_thresh, free_thresh (floats) and mode (str)."""
    try:
        text = read_text_capped(path, MAX_YAML_BYTES, "a map YAML file")
    except FileNotFoundError:
        raise RosMapError(f"{path}: no such map YAML file") from None
    except InputError as e:
        raise RosMapError(str(e)) from None
    except (OSError, UnicodeDecodeError) as e:
        why = getattr(e, "strerror", None) or str(e)
        raise RosMapError(f"{path}: cannot read map YAML ({why})") from None
    try:
        doc = yaml.load(text, Loader=BoundedLoader)  # noqa: S506 (a SafeLoader)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(e, "problem", None) or "syntax error"
        kind = "refused YAML" if isinstance(e, YAMLRefused) else "not valid YAML"
        raise RosMapError(f"{path}: {kind}{where}: {problem}") from None
    if not isinstance(doc, dict):
        raise RosMapError(f"{path}: expected a mapping of map_server keys (image, resolution, ...)")

    def bad(key: str, allowed: str) -> RosMapError:
        if key not in doc:
            return RosMapError(f"{path}: {key}: missing; expected {allowed}")
        return RosMapError(f"{path}: {key}: {short_repr(doc[key])} is not {allowed}")

    image = doc.get("image")
    if not isinstance(image, str) or not image.strip():
        raise bad("image", "a file name (the map's PGM or PNG image)")
    resolution = _number(doc.get("resolution"))
    if resolution is None or resolution <= 0:
        raise bad("resolution", "a number > 0 (metres per pixel)")
    origin = doc.get("origin")
    if not isinstance(origin, list) or len(origin) != 3 or None in map(_number, origin):
        raise bad("origin", "a list [x, y, yaw] of three numbers")
    negate = doc.get("negate")
    if negate not in (0, 1):  # True and False compare equal to 1 and 0
        raise bad("negate", "0 or 1")
    thresholds = {}
    for key in ("occupied_thresh", "free_thresh"):
        value = _number(doc.get(key))
        if value is None or not 0 <= value <= 1:
            raise bad(key, "a number in [0, 1]")
        thresholds[key] = value
    if thresholds["free_thresh"] >= thresholds["occupied_thresh"]:
        raise RosMapError(
            f"{path}: free_thresh: {thresholds['free_thresh']} is not below occupied_thresh "
            f"({thresholds['occupied_thresh']})"
        )
    mode = doc.get("mode", "trinary")
    if mode not in MODES:
        raise bad("mode", "one of " + ", ".join(MODES))
    return {
        "image": image.strip(),
        "resolution": resolution,
        "origin": tuple(float(v) for v in origin),
        "negate": bool(negate),
        "mode": mode,
        **thresholds,
    }


def _number(value: Any) -> float | None:
    """A finite int or float as float; None for anything else (bools included)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def occupancy(
    img: Image,
    negate: bool = False,
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.196,
    mode: str = "trinary",
) -> np.ndarray:
    """int8 ``[height, width]``: map_server's occupancy value of each pixel (row 0 on top).

    See the module docstring for the rules; thresholds are fractions in [0, 1].
    """
    s = img.samples
    channels = s.shape[2]
    averaged = channels if (mode == "trinary" or not img.has_alpha) else channels - 1
    color_avg = s[:, :, :averaged].sum(axis=2) / float(averaged)
    if img.maxval != 255:
        color_avg = color_avg * (255.0 / img.maxval)
    if negate:
        color_avg = 255.0 - color_avg
    if mode == "raw":
        value = np.floor(color_avg)
        return np.where(value <= OCCUPIED, value, UNKNOWN).astype(np.int8)
    p = (255.0 - color_avg) / 255.0
    middle = np.full(p.shape, UNKNOWN, dtype=np.int64)
    if mode == "scale":
        ratio = (p - free_thresh) / (occupied_thresh - free_thresh)
        middle = np.trunc(1.0 + 98.0 * ratio).astype(np.int64)
        if img.has_alpha:
            alpha = s[:, :, -1] * (255.0 / img.maxval)
            middle[alpha < 1.0] = UNKNOWN
    out = np.where(p > occupied_thresh, OCCUPIED, np.where(p < free_thresh, FREE, middle))
    return out.astype(np.int8)
