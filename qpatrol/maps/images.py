"""Decode the images ROS occupancy maps come in: PGM (P2 and P5) and PNG.

Both readers give the pixel samples as integers together with their maximum value
(255 for 8-bit, 65535 for 16-bit), so that the occupancy arithmetic downstream is
exact. The format is recognised from the file's first bytes, not its name.

The size is checked before the pixels are decoded: the PGM header or the PNG ``IHDR``
chunk is read first, and an image of more than :data:`MAX_IMAGE_SAMPLES` samples (pixels
x channels; decoding takes about 55 bytes a sample), a text (P2) PGM of more than
:data:`MAX_P2_SAMPLES`, or a file of more than :data:`MAX_IMAGE_BYTES` is refused. Only
regular files are read (``/dev/zero`` never ends).
"""

from __future__ import annotations

import os
import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from qpatrol.util.inputs import not_a_file, size_text

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
#: Most samples (pixels x channels) of an image read: a 4096 x 4096 grey image, about
#: 0.9 GiB while it is decoded and turned into cells (55 bytes a sample). gmapping's
#: default 4000 x 4000 grey map fits; an RGBA image may have a quarter as many pixels.
MAX_IMAGE_SAMPLES = 1 << 24
#: Most samples of a text (P2) PGM, whose decoding makes a Python object per sample.
MAX_P2_SAMPLES = 1 << 22
#: Largest image file read.
MAX_IMAGE_BYTES = 64 << 20
#: Bytes read first, for the header (a PGM header's comments may be long).
_HEAD_BYTES = 64 << 10
#: Channels of a decoded PNG by IHDR colour type (matplotlib gives palette and grey +
#: alpha images as RGBA).
_PNG_CHANNELS = {0: 1, 2: 3, 3: 4, 4: 4, 6: 4}
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
    """Read a PGM (P2, P5; 8 or 16 bits) or PNG file; raise :class:`ImageError` otherwise.

    The header is read first and the size checked (module doc) before any pixel is."""
    p = Path(path)
    kind = not_a_file(p)
    if kind is not None:
        raise ImageError(f"{p}: is {kind}, not an image file")
    try:
        with open(p, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            head = f.read(_HEAD_BYTES)
            if size > MAX_IMAGE_BYTES:
                raise ImageError(
                    f"{p}: {size_text(size)}, more than the {size_text(MAX_IMAGE_BYTES)} "
                    "qpatrol reads of an image file"
                )
            if head[:2] in (b"P2", b"P5"):
                data = _read_pgm(f, head, size, str(p))
                return parse_pgm(data, str(p))
            if head.startswith(PNG_MAGIC):
                _check_png_header(head, str(p))
                return _read_png(p)
    except FileNotFoundError:
        raise ImageError(f"{p}: no such image file") from None
    except OSError as e:
        raise ImageError(f"{p}: cannot read image ({e.strerror or e})") from None
    if re.match(rb"P[1-7]\s", head[:3]):
        kind = f"netpbm {head[:2].decode()}"
    else:
        kind = next((k for magic, k in _OTHER_FORMATS if head.startswith(magic)), "")
        kind = kind or f"unrecognised content {head[:4]!r}"
    raise ImageError(
        f"{p}: unsupported image format ({kind}); qpatrol reads greyscale PGM (P2, P5) and PNG"
    )


def _check_samples(width: int, height: int, channels: int, source: str, what: str) -> None:
    """Refuse an image of more samples than it may have, before decoding it."""
    limit = MAX_P2_SAMPLES if what == "text (P2) PGM" else MAX_IMAGE_SAMPLES
    if width * height * channels > limit:
        per = f" x {channels} channels" if channels > 1 else ""
        raise ImageError(
            f"{source}: {what} of {width:,} x {height:,} pixels{per} "
            f"({width * height * channels:,} samples); allowed: at most {limit:,} samples "
            "(decoding takes about 55 bytes each; refused before decoding it)"
        )


def _check_png_header(head: bytes, source: str) -> None:
    """The PNG's size from its IHDR chunk, refused if too large (a broken header is left
    to the decoder to report)."""
    if len(head) < 33 or head[12:16] != b"IHDR":
        return
    width, height, _depth, colour = struct.unpack(">IIBB", head[16:26])
    _check_samples(width, height, _PNG_CHANNELS.get(colour, 4), source, "PNG")


def _read_pgm(f: BinaryIO, head: bytes, size: int, source: str) -> bytes:
    """The bytes of a PGM that its header says it needs: the header is read from
    ``head``, the size checked, then at most the raster (P5) or the file (P2) is read."""
    try:
        magic, width, height, maxval, pos = _pgm_header(head, source)
    except ImageError:
        if size > len(head):
            raise ImageError(
                f"{source}: PGM header not complete within its first {size_text(len(head))}"
            ) from None
        raise
    if magic == b"P5":
        _check_samples(width, height, 1, source, "PGM")
        need = pos + 1 + width * height * (1 if maxval < 256 else 2)
        return head[:need] + (f.read(need - len(head)) if need > len(head) else b"")
    _check_samples(width, height, 1, source, "text (P2) PGM")
    return head + f.read(MAX_IMAGE_BYTES)


def parse_pgm(data: bytes, source: str = "<pgm>") -> Image:
    """Decode PGM bytes: ``P2`` (text) or ``P5`` (binary, 16-bit samples big-endian).

    Comments (``#`` to the end of the line) may appear anywhere in the header. Bytes
    after the first image are ignored.
    """
    magic, width, height, maxval, pos = _pgm_header(data, source)
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
        tokens = text.split(maxsplit=n)[:n]
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


def _pgm_header(data: bytes, source: str) -> tuple[bytes, int, int, int, int]:
    """(magic, width, height, maxval, position after maxval) of a PGM's header."""
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
        if len(token) > 12:
            raise ImageError(f"{source}: PGM header: {name} of {len(token)} digits is too large")
        fields.append(int(token))
    width, height, maxval = fields
    if width < 1 or height < 1:
        raise ImageError(f"{source}: PGM header: empty image ({width} x {height} pixels)")
    if not 1 <= maxval <= 65535:
        raise ImageError(f"{source}: PGM header: maxval {maxval} is outside 1..65535")
    return magic, width, height, maxval, pos


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
