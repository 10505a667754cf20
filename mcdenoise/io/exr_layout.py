"""The byte layout of an OpenEXR file, read directly: header attributes and chunk offsets.

Two cheap questions that need no image library and no pixel:

* :func:`header_strings`: the string attributes of each part's header (e.g. whether a file
  carries ``mcdenoise:method``, i.e. was written by ``mcdenoise denoise``), reading only the
  header bytes;
* :func:`check_complete`: whether a file holds every chunk its offset tables point to, down
  to the last byte of the last chunk. OpenImageIO's ``close()`` can return true after the
  final flush failed (a full disk), leaving a file cut inside its pixel data; this check,
  run on every EXR the tool writes before it is renamed into place, reads the headers, the
  offset tables and one chunk header (a few KiB whatever the image size).

The layout (openexr.com, "OpenEXR File Layout"): magic, version word (flags: tiled ``0x200``,
long names ``0x400``, deep ``0x800``, multi-part ``0x1000``), the headers (attributes ``name\\0
type\\0 int32 size, value``, each header ended by an empty name, a multi-part list by an empty
header), one offset table per part (``uint64`` per chunk), then the chunks (multi-part: an
``int32`` part number first; scan lines: ``int32 y, int32 size``; tiles: four ``int32`` tile
coordinates, ``int32 size``; then ``size`` bytes).
"""

from __future__ import annotations

import math
import os
import struct
from dataclasses import dataclass
from pathlib import Path

from mcdenoise.errors import ExrError

_MAGIC = b"\x76\x2f\x31\x01"
_TILED, _LONG_NAMES, _DEEP, _MULTIPART = 0x200, 0x400, 0x800, 0x1000
#: Scan lines per chunk of each compression code (none, rle, zips, zip, piz, pxr24, b44, b44a,
#: dwaa, dwab).
_LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}
_READ = 4096  # bytes fetched at a time: most headers fit in one read


@dataclass(frozen=True)
class _Part:
    attrs: dict[str, tuple[str, bytes]]  # name -> (type, raw value)

    def box(self) -> tuple[int, int, int, int]:
        return struct.unpack("<4i", self.attrs["dataWindow"][1][:16])

    def string(self, name: str) -> str | None:
        kind, raw = self.attrs.get(name, ("", b""))
        return raw.decode("utf-8", "replace") if kind == "string" else None


class _Reader:
    """Sequential reads from the start of a file, fetching more bytes as needed."""

    def __init__(self, f: object) -> None:
        self.f = f
        self.buf = b""
        self.pos = 0

    def need(self, n: int) -> None:
        while len(self.buf) < self.pos + n:
            more = self.f.read(max(_READ, self.pos + n - len(self.buf)))  # type: ignore[attr-defined]
            if not more:
                raise EOFError
            self.buf += more

    def take(self, n: int) -> bytes:
        self.need(n)
        out = self.buf[self.pos : self.pos + n]
        self.pos += n
        return out

    def cstring(self) -> bytes:
        while (end := self.buf.find(b"\0", self.pos)) < 0:
            self.need(len(self.buf) - self.pos + 1)
        out = self.buf[self.pos : end]
        self.pos = end + 1
        return out


def _headers(r: _Reader) -> tuple[int, list[_Part]]:
    """The version word and each part's attributes; ``r`` is left after the headers."""
    if r.take(4) != _MAGIC:
        raise ValueError("not an OpenEXR file")
    (version,) = struct.unpack("<i", r.take(4))
    parts: list[_Part] = []
    while True:
        attrs: dict[str, tuple[str, bytes]] = {}
        while name := r.cstring():
            kind = r.cstring()
            (size,) = struct.unpack("<i", r.take(4))
            if size < 0:
                raise ValueError(f"attribute {name!r} has a negative size")
            attrs[name.decode("utf-8", "replace")] = (kind.decode("utf-8", "replace"), r.take(size))
        if not attrs:  # the empty header ending a multi-part list
            break
        parts.append(_Part(attrs))
        if not version & _MULTIPART:
            break
    if not parts:
        raise ValueError("holds no header")
    return version, parts


def header_strings(path: str | os.PathLike[str]) -> list[dict[str, str]]:
    """The string attributes of each part's header, by name; only header bytes are read.

    Raises:
        ExrError: not an EXR file, or its header is cut or damaged.
    """
    p = Path(path)
    try:
        with open(p, "rb") as f:
            _, parts = _headers(_Reader(f))
    except (OSError, EOFError, ValueError, struct.error) as err:
        raise ExrError(f"{p}: cannot read the header ({_why(err)})") from None
    return [{k: s for k in part.attrs if (s := part.string(k)) is not None} for part in parts]


def _levels(size: int, rounding_up: bool) -> int:
    """Number of mip levels of a side ``size`` (OpenEXR's ``roundLog2 + 1``)."""
    log = math.log2(size) if size > 0 else 0
    return (math.ceil(log) if rounding_up else math.floor(log)) + 1


def _level_size(size: int, level: int, rounding_up: bool) -> int:
    q = -(-size // (1 << level)) if rounding_up else size // (1 << level)
    return max(q, 1)


def _chunk_count(version: int, part: _Part) -> int | None:
    """Chunks of one part: its ``chunkCount`` attribute, else computed from its data window,
    compression and tiling; ``None`` for an unknown compression or tiling."""
    if "chunkCount" in part.attrs:
        return struct.unpack("<i", part.attrs["chunkCount"][1][:4])[0]
    x0, y0, x1, y1 = part.box()
    w, h = x1 - x0 + 1, y1 - y0 + 1
    tiled = "tiles" in part.attrs and (
        version & _TILED or part.string("type") in ("tiledimage", "deeptile")
    )
    if not tiled:
        lines = _LINES_PER_CHUNK.get(part.attrs.get("compression", ("", b"\0"))[1][0])
        return None if lines is None else -(-h // lines)
    tw, th, mode = struct.unpack("<IIB", part.attrs["tiles"][1][:9])
    level_mode, up = mode & 0x0F, bool(mode >> 4 & 1)
    if tw <= 0 or th <= 0 or level_mode > 2:
        return None
    if level_mode == 0:
        return -(-w // tw) * -(-h // th)
    if level_mode == 1:  # mipmap: both sides shrink together
        n = _levels(max(w, h), up)
        return sum(
            -(-_level_size(w, k, up) // tw) * -(-_level_size(h, k, up) // th) for k in range(n)
        )
    xs = [-(-_level_size(w, k, up) // tw) for k in range(_levels(w, up))]
    ys = [-(-_level_size(h, k, up) // th) for k in range(_levels(h, up))]
    return sum(x * y for x in xs for y in ys)  # ripmap: every pair of levels


def check_complete(path: str | os.PathLike[str]) -> None:
    """Raise :class:`~mcdenoise.errors.ExrError` unless ``path`` holds every chunk its offset
    tables declare, the last one to its final byte (see the module docstring).

    Deep files and compressions this module does not know are checked as far as their offset
    tables (every offset inside the file).

    Raises:
        ExrError: one line naming the file: how many bytes it has and how many it needs.
    """
    p = Path(path)
    try:
        size = p.stat().st_size
        with open(p, "rb") as f:
            r = _Reader(f)
            version, parts = _headers(r)
            counts = [_chunk_count(version, part) for part in parts]
            if any(c is None or c < 0 for c in counts):
                return  # an unknown layout: nothing more to check without a decoder
            table = r.pos
            total = sum(c for c in counts if c is not None)
            offsets = struct.unpack(f"<{total}Q", r.take(8 * total)) if total else ()
            if not offsets:
                return
            if min(offsets) < table + 8 * total or max(offsets) >= size:
                raise _cut(p, size, None)
            if version & _DEEP:
                return
            last = max(offsets)
            part = 0
            f.seek(last)
            if version & _MULTIPART:
                (part,) = struct.unpack("<i", _exactly(f, 4, p, size, last + 4))
            tiled = "tiles" in parts[part].attrs if 0 <= part < len(parts) else False
            head = 20 if tiled else 8
            start = f.tell()
            (n,) = struct.unpack("<i", _exactly(f, head, p, size, start + head)[-4:])
            end = start + head + n
            if n < 0 or end > size:
                raise _cut(p, size, end)
    except ExrError:
        raise
    except EOFError:
        raise ExrError(
            f"{p}: the file written is incomplete ({size} bytes; it ends before its offset "
            "table does)"
        ) from None
    except (OSError, ValueError, struct.error) as err:
        raise ExrError(f"{p}: the file written is unreadable ({_why(err)})") from None


def _exactly(f: object, n: int, p: Path, size: int, needed: int) -> bytes:
    data = f.read(n)  # type: ignore[attr-defined]
    if len(data) != n:
        raise _cut(p, size, needed)
    return data


def _cut(p: Path, size: int, needed: int | None) -> ExrError:
    """The error for a file cut short: ``needed`` bytes (``None``: its offset table, written
    last, points outside the file or was never filled in)."""
    what = f"its last chunk ends at byte {needed}" if needed else "its offset table is unfilled"
    return ExrError(f"{p}: the file written is incomplete ({size} bytes; {what})")


def _why(err: BaseException) -> str:
    if isinstance(err, EOFError):
        return "it ends inside its header"
    if isinstance(err, OSError):
        return err.strerror or str(err)
    return str(err)
