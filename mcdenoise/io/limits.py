"""Size checks made on EXR headers before any pixel is allocated.

Three checks, each refusing with one line that names the file, the size and what to do:

* **pixels per part**: a part's data window holds more than ``max_pixels`` pixels (default:
  ``$MCDENOISE_MAX_PIXELS``, else 200 megapixels);
* **memory to read**: the pixels about to be read, over *every* part and channel read
  (width × height × channels × 4 bytes, as float32 after decoding), exceed ``max_read_bytes``
  (default: ``$MCDENOISE_MAX_READ_BYTES``, e.g. ``4G``, else 1 GiB);
* **plausibility**: the headers declare more pixel data than the file can hold. Every
  compression has a largest ratio (none 1, RLE 64, ZIP/ZIPS ~1032 as deflate's limit, PXR24
  4/3 of that, PIZ below ZIP's, B44/B44A 32/3), so a part of ``S`` uncompressed bytes needs at
  least ``S / ratio`` bytes of file; a header edited or damaged to claim, say, 100000x128
  pixels in a 500 KB file is refused at once. DWAA/DWAB and unknown compressions are not
  bounded (not checked).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping, Sequence
from typing import Any

from mcdenoise.errors import ExrError, InputError

# Parts are :class:`mcdenoise.io.exr.ExrPart` (not imported: exr imports this module).
ExrPart = Any

#: Environment variable holding the default pixel limit (per part).
MAX_PIXELS_ENV = "MCDENOISE_MAX_PIXELS"
#: Default pixel limit (data-window pixels of one part) when the variable is not set.
DEFAULT_MAX_PIXELS = 200_000_000
#: Environment variable holding the default limit on decoded bytes read from one file.
MAX_READ_BYTES_ENV = "MCDENOISE_MAX_READ_BYTES"
#: Default limit on the decoded (float32) bytes read from one file: 1 GiB.
DEFAULT_MAX_READ_BYTES = 2**30
#: Largest ratio of uncompressed to compressed bytes of each compression (with margin).
MAX_RATIO = {
    "none": 1.0,
    "rle": 70.0,  # runs of at most 128 bytes in 2: 64
    "zips": 1100.0,
    "zip": 1100.0,
    "pxr24": 1500.0,
    "piz": 1100.0,
    "b44": 11.0,
    "b44a": 11.0,
}
_TYPE_BYTES = {"half": 2, "float": 4, "uint": 4}
_UNITS = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}


def format_bytes(n: float) -> str:
    """``1288490188`` -> ``"1.2 GiB"`` (binary units, as the limit is written)."""
    for unit, size in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{int(n)} bytes"


def resolve_max_pixels(max_pixels: int | None = None) -> int:
    """The pixel limit to apply: ``max_pixels`` if given, else ``$MCDENOISE_MAX_PIXELS``,
    else :data:`DEFAULT_MAX_PIXELS`."""
    if max_pixels is not None:
        if isinstance(max_pixels, bool) or not isinstance(max_pixels, int) or max_pixels <= 0:
            raise InputError(f"max_pixels must be a positive integer, got {max_pixels!r}")
        return max_pixels
    env = os.environ.get(MAX_PIXELS_ENV)
    if env is None or not env.strip():
        return DEFAULT_MAX_PIXELS
    try:
        value = int(env.strip().replace("_", ""))
    except ValueError:
        value = 0
    if value <= 0:
        raise InputError(f"{MAX_PIXELS_ENV}={env!r} is not a positive integer")
    return value


def resolve_max_read_bytes(max_read_bytes: int | None = None) -> int:
    """The read limit in bytes: the argument, else ``$MCDENOISE_MAX_READ_BYTES`` (an integer
    with an optional K, M, G or T suffix, binary), else :data:`DEFAULT_MAX_READ_BYTES`."""
    if max_read_bytes is not None:
        ok = isinstance(max_read_bytes, int) and not isinstance(max_read_bytes, bool)
        if not ok or max_read_bytes <= 0:
            raise InputError(f"max_read_bytes must be a positive integer, got {max_read_bytes!r}")
        return max_read_bytes
    env = os.environ.get(MAX_READ_BYTES_ENV)
    if env is None or not env.strip():
        return DEFAULT_MAX_READ_BYTES
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([KMGT]?)i?B?\s*", env.replace("_", ""), re.I)
    value = int(float(m.group(1)) * _UNITS[m.group(2).upper()]) if m else 0
    if value <= 0:
        raise InputError(
            f"{MAX_READ_BYTES_ENV}={env!r} is not a size; write e.g. {MAX_READ_BYTES_ENV}=4G"
        )
    return value


def check_pixel_limit(part: ExrPart, path: str, max_pixels: int | None = None) -> None:
    """Raise ExrError if ``part``'s data window holds more than the pixel limit."""
    limit = resolve_max_pixels(max_pixels)
    n = part.num_pixels
    if n > limit:
        raise ExrError(
            f"{path}: data window of {part.width}x{part.height} = {n:,} pixels is over the "
            f"limit of {limit:,} pixels (a corrupt header?); if the file is genuine, raise the "
            f"limit with the environment variable {MAX_PIXELS_ENV}, e.g. "
            f"{MAX_PIXELS_ENV}={_round_up(n)}"
        )


def _round_up(n: int) -> int:
    """A round number at least ``n`` (for suggesting a limit)."""
    step = 10 ** max(len(str(n)) - 1, 0)
    return -(-n // step) * step


def check_read_size(
    path: str,
    parts: Sequence[ExrPart],
    reading: Mapping[int, Sequence[str]],
    *,
    max_read_bytes: int | None = None,
    file_size: int | None = None,
) -> None:
    """Refuse, before any allocation, a read the headers show to be impossible or too big.

    Args:
        path: the file (for messages; its size is taken from disk unless ``file_size``).
        parts: headers of every part of the file.
        reading: part index -> channel names about to be read.
        max_read_bytes: limit on the decoded bytes (see :func:`resolve_max_read_bytes`).
        file_size: the file's size in bytes (default: from disk).
    """
    if file_size is None:
        try:
            file_size = os.path.getsize(path)
        except OSError:
            file_size = None
    if file_size is not None:
        _check_plausible(path, parts, file_size)
    limit = resolve_max_read_bytes(max_read_bytes)
    by_index = {p.index: p for p in parts}
    need = 0
    pieces = []
    for index, names in reading.items():
        p = by_index[index]
        n = p.num_pixels * len(names) * 4
        need += n
        label = f"part {p.name!r}" if p.name else f"part {p.index}"
        pieces.append(f"{p.width}x{p.height} pixels x {len(names)} channels of {label}")
    if need > limit:
        suggest = max(1, math.ceil(need / 2**30))
        raise ExrError(
            f"{path}: reading {'; '.join(pieces)} needs {format_bytes(need)} of memory, over "
            f"the limit of {format_bytes(limit)} (a corrupt header?); if the file is genuine, "
            f"raise the limit with the environment variable {MAX_READ_BYTES_ENV}, e.g. "
            f"{MAX_READ_BYTES_ENV}={suggest}G"
        )


def _check_plausible(path: str, parts: Sequence[ExrPart], file_size: int) -> None:
    """ExrError when the file is too small to hold the pixel data its headers declare."""
    least = 0.0
    worst = None
    for p in parts:
        base = p.compression.split(":")[0]
        ratio = MAX_RATIO.get(base)
        if ratio is None or p.num_pixels == 0:
            continue
        stored = p.num_pixels * sum(_TYPE_BYTES.get(c.pixel_type, 2) for c in p.channels)
        least += stored / ratio
        if worst is None or stored > worst[0]:
            worst = (stored, p)
    if worst is not None and least > file_size:
        stored, p = worst
        label = f" (part {p.name!r})" if p.name else ""
        raise ExrError(
            f"{path}: the header declares {p.width}x{p.height} pixels x {len(p.channels)} "
            f"channels{label}, {format_bytes(stored)} of {p.compression}-compressed pixel data, "
            f"which needs at least {format_bytes(least)} of file, but the file has "
            f"{file_size:,} bytes: the header is corrupt or the file is truncated; write or "
            "copy the file again"
        )
