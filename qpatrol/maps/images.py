"""Decode the images ROS occupancy maps come in: PGM (P2 and P5) and PNG.

Both readers give the pixel samples as integers together with their maximum value
(255 for 8-bit, 65535 for 16-bit), so that the occupancy arithmetic downstream is
exact. The format is recognised from the file's first bytes, not its name.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_WHITESPACE = b" \t\r\n\v\f"
#: Formats map_server may read but qpatrol does not, by their first bytes (for messages).
_OTHER_FORMATS = (
    (b"\xff\xd8\xff", "JPEG"),
    (b"BM", "BMP"),
    (b"GIF8", "GIF"),
    (b"II*\x00", "TIFF"),
    (b"MM\x00*", "TIFF"),
    (b"RIFF", "RIFF/WebP"),
)


class ImageError(ValueError):
    """An image that cannot be read; the message is one line naming the file."""


@dataclass(frozen=True)
class Image:
    """Decoded pixels, row 0 at the top of the picture.

    Attributes:
        samples: int64 ``[height, width, channels]``; 1 channel (grey), 3 (RGB) or 4
            (RGBA), each in ``0..maxval``.
        maxval: the value of full intensity (255 for 8-bit images, 65535 for 16-bit).
        has_alpha: the last channel is opacity (``maxval`` = opaque).
    """

    samples: np.ndarray
    maxval: int
    has_alpha: bool

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) in pixels."""
        return int(self.samples.shape[0]), int(self.samples.shape[1])


def read_image(path: str | Path) -> Image:
    """Read a PGM (P2, P5; 8 or 16 bits) or PNG file; raise :class:`ImageError` otherwise."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise ImageError(f"{p}: no such image file") from None
    except OSError as e:
        raise ImageError(f"{p}: cannot read image ({e.strerror or e})") from None
    if data[:2] in (b"P2", b"P5"):
        return parse_pgm(data, str(p))
    if data.startswith(PNG_MAGIC):
        return _read_png(p)
    if re.match(rb"P[1-7]\s", data[:3]):
        kind = f"netpbm {data[:2].decode()}"
    else:
        kind = next((k for magic, k in _OTHER_FORMATS if data.startswith(magic)), "")
        kind = kind or f"unrecognised content {data[:4]!r}"
    raise ImageError(
        f"{p}: unsupported image format ({kind}); qpatrol reads greyscale PGM (P2, P5) and PNG"
    )


def parse_pgm(data: bytes, source: str = "<pgm>") -> Image:
    """Decode PGM bytes: ``P2`` (text) or ``P5`` (binary, 16-bit samples big-endian).

    Comments (``#`` to the end of the line) may appear anywhere in the header. Bytes
    after the first image are ignored.
    """
    magic = data[:2]
    if magic not in (b"P2", b"P5"):
        raise ImageError(f"{source}: not a PGM file (starts with {data[:2]!r})")
    pos = 2
    fields: list[int] = []
    names = ("width", "height", "maxval")
    while len(fields) < 3:
        pos = _skip_space_and_comments(data, pos)
        start = pos
        while pos < len(data) and data[pos] not in _WHITESPACE and data[pos] != ord("#"):
            pos += 1
        token = data[start:pos]
        name = names[len(fields)]
        if not token:
            raise ImageError(f"{source}: PGM header ends before its {name}")
        if not token.isdigit():
            raise ImageError(f"{source}: PGM header: {name} {token[:20]!r} is not a number")
        fields.append(int(token))
    width, height, maxval = fields
    if width < 1 or height < 1:
        raise ImageError(f"{source}: PGM header: empty image ({width} x {height} pixels)")
    if not 1 <= maxval <= 65535:
        raise ImageError(f"{source}: PGM header: maxval {maxval} is outside 1..65535")
    n = width * height
    if magic == b"P5":
        if pos >= len(data) or data[pos] not in _WHITESPACE:
            raise ImageError(f"{source}: PGM header: no whitespace after maxval")
        raster = data[pos + 1 :]
        size = 1 if maxval < 256 else 2
        if len(raster) < n * size:
            raise ImageError(
                f"{source}: PGM data truncated: {len(raster) // size} of {n} samples "
                f"({width} x {height})"
            )
        values = np.frombuffer(raster, dtype=np.uint8 if size == 1 else ">u2", count=n)
    else:
        text = re.sub(rb"#[^\n]*", b" ", data[pos:])
        tokens = text.split()
        if len(tokens) < n:
            raise ImageError(
                f"{source}: PGM data truncated: {len(tokens)} of {n} samples ({width} x {height})"
            )
        bad = next((t for t in tokens[:n] if not t.isdigit()), None)
        if bad is not None:
            raise ImageError(f"{source}: PGM data: sample {bad[:20]!r} is not a number")
        values = np.array([int(t) for t in tokens[:n]], dtype=np.int64)
    values = values.astype(np.int64)
    if values.max() > maxval:
        raise ImageError(f"{source}: PGM data: sample {int(values.max())} exceeds maxval {maxval}")
    return Image(samples=values.reshape(height, width, 1), maxval=maxval, has_alpha=False)


def _skip_space_and_comments(data: bytes, pos: int) -> int:
    while pos < len(data):
        if data[pos] in _WHITESPACE:
            pos += 1
        elif data[pos] == ord("#"):
            end = data.find(b"\n", pos)
            pos = len(data) if end < 0 else end + 1
        else:
            break
    return pos


def _read_png(path: Path) -> Image:
    """Read a PNG with matplotlib; grey, grey+alpha, RGB, RGBA or palette, 8 or 16 bits."""
    from matplotlib import image as mpimg

    try:
        x = np.asarray(mpimg.imread(path))
    except Exception as e:  # a corrupt PNG raises from deep inside Pillow
        detail = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ImageError(f"{path}: cannot read PNG ({detail})") from None
    if x.ndim == 2:
        x = x[:, :, None]
    if x.ndim != 3 or x.shape[2] not in (1, 3, 4) or x.size == 0:
        raise ImageError(f"{path}: unsupported PNG layout (array shape {x.shape})")
    samples, maxval = _quantize(x.astype(np.float64))
    return Image(samples=samples, maxval=maxval, has_alpha=x.shape[2] == 4)


def _quantize(x: np.ndarray) -> tuple[np.ndarray, int]:
    """Integers and maxval behind matplotlib's 0..1 floats (8-bit if they fit, else 16-bit).

    matplotlib divides 8-bit (and 1-, 2-, 4-bit) samples by 255 or 2**k - 1, 16-bit grey by
    65535; both scales are tried, the first that gives whole numbers wins.
    """
    for maxval in (255, 65535):
        scaled = x * maxval
        whole = np.round(scaled)
        if np.abs(scaled - whole).max(initial=0.0) < 1e-2:
            return whole.astype(np.int64), maxval
    return np.round(x * 65535).astype(np.int64), 65535
