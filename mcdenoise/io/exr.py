"""Low-level OpenEXR reading and writing (OpenImageIO), by channel *name*.

This module knows files, parts, windows and channels; it knows nothing about renderers or
feature buffers (see :mod:`mcdenoise.io.profiles` and :mod:`mcdenoise.io.buffer_files`).

Arrays
    Every channel is a separate ``numpy.ndarray`` of shape ``(H, W)`` and dtype float32, where
    ``H, W`` are the height and width of the part's *data window* (the pixels actually stored).
    Values are whatever the file holds: linear, unclamped, NaN/Inf and negatives included.
    Half channels come back as the float32 values exactly equal to the stored halves; ``uint``
    channels (ids) are converted to float32 by value, not normalised (exact up to 2**24).

Windows
    ``data_window`` and ``display_window`` are ``(xmin, ymin, xmax, ymax)`` with *inclusive*
    maxima, exactly as in the OpenEXR header; origins may be negative.

Safety
    * :func:`probe_exr` reads headers only. :func:`read_exr` refuses, before any pixel is
      allocated, a part whose data window holds more than ``max_pixels`` pixels (default:
      the ``MCDENOISE_MAX_PIXELS`` environment variable, else 200 megapixels), a read
      needing more than ``max_read_bytes`` (``MCDENOISE_MAX_READ_BYTES``, else 1 GiB), and a
      file too small for the pixel data its headers declare (:mod:`mcdenoise.io.limits`).
    * Messages say what is wrong in a user's terms (:mod:`mcdenoise.io.exr_messages`
      translates OpenEXR's texts, whatever bytes they hold) and what to do.
    * Every failure (missing file, folder, empty file, not an EXR, corrupt or truncated data,
      unknown part or channel, unwritable destination) raises :class:`~mcdenoise.errors.ExrError`
      with a one-line message naming the file. A truncated or corrupt file never yields partial
      arrays: OpenImageIO's error state is checked after every read and the data discarded.
    * :func:`write_exr` (one part) and :func:`write_exr_parts` (several named parts, e.g. the
      spp levels of one render) write atomically (temporary file, fsync, checked down to its
      last chunk, then ``os.replace``): a crash or a full disk leaves the old file or the new one.
    * float32 channels written with a lossless compression (``none``, ``rle``, ``zips``,
      ``zip``, ``piz``, ``b44``, ``b44a``) read back bit-exact; ``pxr24`` rounds float32 to
      24 bits and ``dwaa``/``dwab`` are lossy on channels named R, G, B, Y of any type. Half output clamps finite values beyond
      +/-65504 to +/-65504 and counts them in :class:`WriteReport` instead of turning them into
      Inf.
    * Output bytes are deterministic: OpenImageIO's automatic ``capDate`` stamp is suppressed
      unless the caller passes ``DateTime``/``capDate`` in ``attributes``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from mcdenoise.errors import ExrError, InputError, McdenoiseError
from mcdenoise.io.atomic import atomic_path
from mcdenoise.io.exr_messages import error_text as _error_text
from mcdenoise.io.exr_messages import explain, readable_name, special_file_kind
from mcdenoise.io.limits import (  # noqa: F401  (re-exported: the limits' historic home)
    DEFAULT_MAX_PIXELS,
    MAX_PIXELS_ENV,
    check_pixel_limit,
    check_read_size,
    resolve_max_pixels,
)

#: Largest finite half-float value.
HALF_MAX = 65504.0
#: Compression names accepted by :func:`write_exr` (an optional ``:level`` may follow
#: ``zip``, ``zips``, ``dwaa`` and ``dwab``).
COMPRESSIONS = ("none", "rle", "zips", "zip", "piz", "pxr24", "b44", "b44a", "dwaa", "dwab")
_LEVELLED = ("zip", "zips", "dwaa", "dwab")

PixelType = Literal["half", "float", "uint", "unknown"]
Window = tuple[int, int, int, int]

_EXR_MAGIC = b"\x76\x2f\x31\x01"
_OTHER_FORMATS = (
    (b"\x89PNG", "a PNG image"),
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"II*\x00", "a TIFF image"),
    (b"MM\x00*", "a TIFF image"),
    (b"#?", "a Radiance HDR image"),
    (b"PF\n", "a PFM image"),
    (b"Pf\n", "a PFM image"),
    (b"GIF8", "a GIF image"),
    (b"BM", "a BMP image"),
)
_PIXEL_TYPES = {"half": "half", "float": "float", "uint": "uint", "uint32": "uint"}
_LINE_ORDERS = {"increasingY": "increasing", "decreasingY": "decreasing", "randomY": "random"}
# OpenEXR attribute names that OpenImageIO renames (used by the OpenEXR fallback probe).
_OPENEXR_ATTR_NAMES = {
    "capDate": "DateTime",
    "pixelAspectRatio": "PixelAspectRatio",
    "owner": "Copyright",
    "comments": "ImageDescription",
}
# Header fields exposed as ExrPart fields, or OpenImageIO bookkeeping: not repeated in attributes.
_STRUCTURAL_ATTRS = {"compression", "name", "openexr:lineOrder", "openexr:chunkCount"}


# --- data types ---------------------------------------------------------------------------
@dataclass(frozen=True)
class ExrChannel:
    """One channel of a part: its full name (``layer.channel``) and stored pixel type.

    ``pixel_type`` is ``"unknown"`` only for files OpenImageIO refuses to open (see
    :func:`probe_exr`).
    """

    name: str
    pixel_type: PixelType


@dataclass(frozen=True)
class ExrPart:
    """Header of one part (OpenImageIO "subimage") of an EXR file.

    Attributes:
        index: position of the part in the file (0-based).
        name: the part's ``name`` attribute (``""`` for single-part files without one).
        data_window: ``(xmin, ymin, xmax, ymax)`` inclusive, of the stored pixels.
        display_window: ``(xmin, ymin, xmax, ymax)`` inclusive, of the intended image.
        channels: the channels, in OpenImageIO's order (R, G, B, A first within a layer).
        compression: e.g. ``"zip"``, ``"piz"``, ``"dwaa:45"``.
        tiled: whether the part is tiled; ``tile_size`` is ``(width, height)`` then.
        line_order: ``"increasing"``, ``"decreasing"`` or ``"random"``.
        attributes: remaining header attributes by OpenImageIO name (custom names such as
            ``mcdenoise:spp`` are kept verbatim); values are str, int, float or tuples.
    """

    index: int
    name: str
    data_window: Window
    display_window: Window
    channels: tuple[ExrChannel, ...]
    compression: str
    tiled: bool
    tile_size: tuple[int, int] | None
    line_order: str
    attributes: dict[str, Any] = field(default_factory=dict)

    @property
    def width(self) -> int:
        return self.data_window[2] - self.data_window[0] + 1

    @property
    def height(self) -> int:
        return self.data_window[3] - self.data_window[1] + 1

    @property
    def num_pixels(self) -> int:
        """Pixels in the data window (0 for an empty or inverted window)."""
        return max(self.width, 0) * max(self.height, 0)

    @property
    def channel_names(self) -> list[str]:
        return [c.name for c in self.channels]

    def pixel_type(self, channel: str) -> PixelType:
        """Stored pixel type of ``channel`` (KeyError if absent)."""
        for c in self.channels:
            if c.name == channel:
                return c.pixel_type
        raise KeyError(channel)


@dataclass
class ExrImage:
    """Pixels read from one part.

    Attributes:
        path: the file read.
        part: header of the part the pixels come from.
        pixels: channel name -> float32 array ``(H, W)`` over the data window.
    """

    path: str
    part: ExrPart
    pixels: dict[str, np.ndarray]

    @property
    def width(self) -> int:
        return self.part.width

    @property
    def height(self) -> int:
        return self.part.height

    @property
    def data_window(self) -> Window:
        return self.part.data_window

    @property
    def display_window(self) -> Window:
        return self.part.display_window


@dataclass
class WriteReport:
    """What :func:`write_exr` wrote.

    Attributes:
        path: the file written.
        channels: channel name -> stored pixel type (``"half"`` or ``"float"``), in write order.
        compression: compression used.
        clamped: for half channels, the number of finite values beyond +/-65504 that were
            clamped to +/-65504 (channels with none clamped are omitted).
    """

    path: str
    channels: dict[str, str]
    compression: str
    clamped: dict[str, int] = field(default_factory=dict)

    @property
    def total_clamped(self) -> int:
        return sum(self.clamped.values())


# --- helpers -------------------------------------------------------------------------------
def _oiio():
    import OpenImageIO

    return OpenImageIO


def _clear_global_error() -> None:
    # OpenImageIO prints pending global errors at interpreter exit: always drain them.
    _error_text(_oiio())


def _check_readable(path: Path) -> None:
    """Raise ExrError unless ``path`` is a non-empty regular file that starts with the EXR magic.

    A named pipe, a device or a socket is refused before a byte is read (opening a FIFO waits
    for a writer: ``info``, ``eval`` and ``denoise`` hung); it is opened non-blocking and
    checked on the open descriptor, so it cannot be swapped in between check and read.
    """
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as e:
        if not path.exists():
            raise ExrError(f"{path}: no such file") from None
        if path.is_dir():
            raise ExrError(f"{path}: is a folder, not an EXR file") from None
        raise ExrError(f"{path}: cannot be read ({e.strerror or e})") from None
    kind = special_file_kind(os.fstat(fd).st_mode)
    if kind is not None:
        os.close(fd)
        if kind == "a folder":
            raise ExrError(f"{path}: is a folder, not an EXR file")
        raise ExrError(f"{path}: is {kind}, not a regular file; refused (reading could block)")
    with os.fdopen(fd, "rb") as f:
        try:
            head = f.read(4)
        except OSError as e:
            raise ExrError(f"{path}: cannot be read ({e.strerror or e})") from None
    if not head:
        raise ExrError(f"{path}: is empty (0 bytes), not an EXR file")
    if head != _EXR_MAGIC:
        what = next((desc for magic, desc in _OTHER_FORMATS if head.startswith(magic)), None)
        hint = f" (it looks like {what})" if what else ""
        raise ExrError(f"{path}: is not an OpenEXR file{hint}")


def _py_value(value: Any) -> Any:
    if isinstance(value, str):
        return readable_name(value)  # bytes of a damaged header that are not UTF-8 -> \xNN
    if isinstance(value, (int, float)):
        return value
    if isinstance(value, (tuple, list)):
        return tuple(_py_value(v) for v in value)
    if isinstance(value, np.ndarray):
        return tuple(_py_value(v) for v in value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return str(value)


def _part_from_spec(index: int, spec: Any) -> ExrPart:
    names = [readable_name(n) for n in spec.channelnames]
    formats = list(spec.channelformats) or [spec.format] * len(names)
    channels = tuple(
        ExrChannel(n, _PIXEL_TYPES.get(str(fmt), "unknown"))  # type: ignore[arg-type]
        for n, fmt in zip(names, formats)
    )
    attrs: dict[str, Any] = {}
    for a in spec.extra_attribs:
        try:
            name = a.name
            if name.startswith("oiio:") or name in _STRUCTURAL_ATTRS:
                continue
            attrs[name] = _py_value(a.value)
        except Exception:  # an undecodable attribute of a damaged header: skip it
            continue
    tiled = spec.tile_width > 0
    return ExrPart(
        index=index,
        name=str(spec.getattribute("name") or ""),
        data_window=(spec.x, spec.y, spec.x + spec.width - 1, spec.y + spec.height - 1),
        display_window=(
            spec.full_x,
            spec.full_y,
            spec.full_x + spec.full_width - 1,
            spec.full_y + spec.full_height - 1,
        ),
        channels=channels,
        compression=str(spec.getattribute("compression") or "none"),
        tiled=tiled,
        tile_size=(spec.tile_width, spec.tile_height) if tiled else None,
        line_order=_LINE_ORDERS.get(
            str(spec.getattribute("openexr:lineOrder") or "increasingY"), "increasing"
        ),
        attributes=attrs,
    )


def _probe_with_openexr(path: Path) -> list[ExrPart] | None:
    """Headers through the OpenEXR module; used only when OpenImageIO refuses to open a file
    (it rejects headers declaring more pixels than its ``limits:imagesize_MB``), so that the
    pixel limit can still report the declared size. Pixel types are ``"unknown"`` here: the
    module cannot report them without reading pixels."""
    try:
        import OpenEXR

        f = OpenEXR.File(str(path), header_only=True)
        parts = []
        for i, p in enumerate(f.parts):
            h = dict(p.header)
            (dx0, dy0), (dx1, dy1) = (tuple(int(v) for v in a) for a in h["dataWindow"])
            (vx0, vy0), (vx1, vy1) = (tuple(int(v) for v in a) for a in h["displayWindow"])
            comp = str(h.get("compression", "")).split(".")[-1].removesuffix("_COMPRESSION")
            order = str(h.get("lineOrder", "")).split(".")[-1]
            tiles = h.get("tiles")
            attrs = {
                _OPENEXR_ATTR_NAMES.get(k, k): _py_value(v)
                for k, v in h.items()
                if k
                not in {
                    "channels",
                    "dataWindow",
                    "displayWindow",
                    "compression",
                    "lineOrder",
                    "name",
                    "type",
                    "tiles",
                    "chunkCount",
                }
            }
            parts.append(
                ExrPart(
                    index=i,
                    name=str(h.get("name", "") or ""),
                    data_window=(dx0, dy0, dx1, dy1),
                    display_window=(vx0, vy0, vx1, vy1),
                    channels=tuple(ExrChannel(c.name, "unknown") for c in h.get("channels", [])),
                    compression=comp.lower() or "none",
                    tiled=tiles is not None,
                    tile_size=None,
                    line_order={"INCREASING_Y": "increasing", "DECREASING_Y": "decreasing"}.get(
                        order, "random" if order == "RANDOM_Y" else "increasing"
                    ),
                    attributes=attrs,
                )
            )
        return parts or None
    except Exception:  # any failure: the caller reports OpenImageIO's message
        return None


def _open_input(path: Path) -> Any:
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        msg = _error_text(oiio)
        raise ExrError(f"{path}: {explain(msg, str(path), 'the header')}")
    if inp.format_name() != "openexr":
        fmt = inp.format_name()
        inp.close()
        raise ExrError(f"{path}: is not an OpenEXR file (OpenImageIO reads it as {fmt})")
    return inp


# --- public API -----------------------------------------------------------------------------
def probe_exr(path: str | os.PathLike[str]) -> list[ExrPart]:
    """Read the headers of every part of an EXR file; no pixel data is read or allocated.

    Args:
        path: the EXR file.

    Returns:
        One :class:`ExrPart` per part, in file order.

    Raises:
        ExrError: missing file, folder, empty file, not an EXR, unreadable or corrupt header,
            deep data (unsupported).
    """
    p = Path(path)
    _check_readable(p)
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(p))
    if inp is None:
        msg = _error_text(oiio)
        parts = _probe_with_openexr(p)
        if parts is not None:
            return parts
        raise ExrError(f"{p}: {explain(msg, str(p), 'the header')}")
    try:
        if inp.format_name() != "openexr":
            raise ExrError(f"{p}: is not an OpenEXR file (read as {inp.format_name()})")
        parts = []
        index = 0
        while inp.seek_subimage(index, 0):
            spec = inp.spec()
            if spec.deep:
                raise ExrError(f"{p}: part {index} holds deep data, which is not supported")
            try:
                parts.append(_part_from_spec(index, spec))
            except UnicodeDecodeError:
                raise ExrError(
                    f"{p}: cannot read the header: a name in part {index} is not valid text "
                    "(the header is damaged); write or copy the file again"
                ) from None
            index += 1
        if inp.has_error:
            raise ExrError(f"{p}: {explain(_error_text(inp), str(p), 'the header')}")
        if not parts:
            raise ExrError(f"{p}: holds no image part")
        return parts
    finally:
        inp.close()
        _clear_global_error()


def select_part(parts: Sequence[ExrPart], part: str | int | None, path: str = "") -> ExrPart:
    """The part named or indexed by ``part`` (``None``: the first); ExrError if absent."""
    where = f"{path}: " if path else ""
    if part is None:
        return parts[0]
    if isinstance(part, bool) or not isinstance(part, (int, str)):
        raise InputError(f"part must be a name or an index, got {part!r}")
    if isinstance(part, int):
        if -len(parts) <= part < len(parts):
            return parts[part]
        raise ExrError(f"{where}no part {part}: the file has {len(parts)} part(s)")
    for p in parts:
        if p.name == part:
            return p
    names = ", ".join(repr(p.name) for p in parts)
    raise ExrError(f"{where}no part named {part!r}; the file has parts: {names}")


def read_exr(
    path: str | os.PathLike[str],
    *,
    part: str | int | None = None,
    channels: Sequence[str] | None = None,
    max_pixels: int | None = None,
    max_read_bytes: int | None = None,
) -> ExrImage:
    """Read channels of one part of an EXR file by name.

    Args:
        path: the EXR file.
        part: part name or index (``None``: the first part).
        channels: channel names to read (e.g. ``["albedo.R", "albedo.G", "albedo.B"]``);
            ``None`` reads all channels of the part. Order and position in the file do not
            matter.
        max_pixels: refuse a data window with more pixels (default: ``$MCDENOISE_MAX_PIXELS``
            or 200 megapixels); checked on the header before anything is allocated.
        max_read_bytes: refuse a read needing more memory (channels read x pixels x 4
            bytes; default ``$MCDENOISE_MAX_READ_BYTES`` or 1 GiB), and any file too small
            to hold what its headers declare (see :mod:`mcdenoise.io.limits`).

    Returns:
        An :class:`ExrImage` whose ``pixels`` maps each requested channel to a float32
        ``(H, W)`` array over the data window (values as stored: NaN/Inf/negative kept).

    Raises:
        ExrError: see the module docstring; never returns partial data.
    """
    p = Path(path)
    parts = probe_exr(p)
    chosen = select_part(parts, part, str(p))
    check_pixel_limit(chosen, str(p), max_pixels)
    names = chosen.channel_names
    if channels is None:
        wanted = list(names)
    else:
        if isinstance(channels, str):
            raise InputError(f"channels must be a sequence of names, got the string {channels!r}")
        wanted = list(dict.fromkeys(channels))
        missing = [c for c in wanted if c not in names]
        if missing:
            shown = ", ".join(names[:40]) + (
                f", ... ({len(names) - 40} more)" if len(names) > 40 else ""
            )
            label = f"part {chosen.name!r}" if chosen.name else f"part {chosen.index}"
            raise ExrError(
                f"{p}: {label} has no channel(s) {', '.join(missing)}; it has {shown or 'none'}"
            )
    if not wanted:
        return ExrImage(str(p), chosen, {})
    if chosen.num_pixels == 0:
        raise ExrError(f"{p}: empty data window {chosen.data_window}")
    check_read_size(str(p), parts, {chosen.index: wanted}, max_read_bytes=max_read_bytes)

    index = {n: i for i, n in enumerate(names)}
    idx = sorted(index[c] for c in wanted)
    lo, hi = idx[0], idx[-1] + 1
    inp = _open_input(p)
    try:
        if not inp.seek_subimage(chosen.index, 0):
            what = f"part {chosen.index}"
            raise ExrError(f"{p}: {explain(_error_text(inp), str(p), what)}")
        data = _read_range(inp, p, chosen, lo, hi)
    finally:
        inp.close()
        _clear_global_error()
    pixels = {}
    for c in wanted:
        a = data[:, :, index[c] - lo]
        if chosen.pixel_type(c) == "uint":
            # OpenImageIO normalises uint to [0, 1] on conversion to float (even when asked
            # for uint32 in a part of mixed types): undo it. Exact up to 2**24, and within
            # float32 rounding above.
            a = np.rint(a.astype(np.float64) * 4294967295.0)
        pixels[c] = np.ascontiguousarray(a, dtype=np.float32)
    return ExrImage(str(p), chosen, pixels)


def _read_range(inp: Any, p: Path, part: ExrPart, lo: int, hi: int) -> np.ndarray:
    """Channels ``[lo, hi)`` of ``part`` as float32 ``(H, W, hi - lo)``; ExrError on any error."""
    data = inp.read_image(part.index, 0, lo, hi, "float")
    if data is None or inp.has_error:
        label = f"part {part.name!r}" if part.name else f"part {part.index}"
        what = f"the pixels of {label}"
        raise ExrError(f"{p}: {explain(_error_text(inp), str(p), what)}")
    data = np.asarray(data, dtype=np.float32)
    if data.ndim == 2:
        data = data[:, :, None]
    if data.shape != (part.height, part.width, hi - lo):
        raise ExrError(
            f"{p}: OpenImageIO returned pixels of shape {data.shape}, expected "
            f"{(part.height, part.width, hi - lo)}"
        )
    return data


def _check_window(name: str, window: Iterable[int] | None) -> Window | None:
    if window is None:
        return None
    w = tuple(int(v) for v in window)
    if len(w) != 4 or w[2] < w[0] or w[3] < w[1]:
        raise InputError(f"{name} must be (xmin, ymin, xmax, ymax) with max >= min, got {window!r}")
    return w  # type: ignore[return-value]


def _check_compression(compression: str) -> str:
    comp = str(compression).strip().lower()
    base, _, level = comp.partition(":")
    ok = base in COMPRESSIONS and (not level or (base in _LEVELLED and level.isdigit()))
    if not ok:
        raise InputError(
            f"unknown EXR compression {compression!r}; use one of {', '.join(COMPRESSIONS)}"
        )
    return comp


def write_exr(
    path: str | os.PathLike[str],
    channels: Mapping[str, np.ndarray],
    *,
    pixel_type: str | Mapping[str, str] = "float",
    compression: str = "zip",
    attributes: Mapping[str, str | int | float] | None = None,
    data_window: Iterable[int] | None = None,
    display_window: Iterable[int] | None = None,
    tile_size: tuple[int, int] | None = None,
    line_order: str = "increasing",
) -> WriteReport:
    """Write a single-part EXR file atomically.

    Args:
        path: destination (replaced atomically if it exists).
        channels: channel name -> array ``(H, W)``, all of the same shape (any real dtype;
            stored as float32 or half).
        pixel_type: ``"float"`` or ``"half"`` for every channel, or a mapping channel ->
            type (channels not listed are float).
        compression: one of :data:`COMPRESSIONS` (``pxr24`` is lossy for float channels,
            ``b44``/``b44a`` for half channels, ``dwaa``/``dwab`` for R, G, B, Y channels).
        attributes: extra header attributes (str, int or float values).
        data_window: ``(xmin, ymin, xmax, ymax)`` inclusive; default ``(0, 0, W-1, H-1)``.
            Its size must match the arrays.
        display_window: default: the data window.
        tile_size: ``(width, height)`` to write a tiled file; default scanline.
        line_order: ``"increasing"``, ``"decreasing"`` or (tiled only) ``"random"``.

    Returns:
        A :class:`WriteReport` (with counts of half values clamped to +/-65504).

    Raises:
        InputError: invalid arguments (shapes, types, compression, windows).
        ExrError: the file cannot be written (folder missing, permission, disk full).
    """
    p = Path(path)
    prepared = _prepare_part(
        p,
        channels,
        pixel_type=pixel_type,
        compression=compression,
        attributes=attributes,
        data_window=data_window,
        display_window=display_window,
        tile_size=tile_size,
        line_order=line_order,
    )
    if p.is_dir():
        raise ExrError(f"{p}: is a folder; cannot write an EXR file there")
    _write_prepared(p, [prepared])
    return WriteReport(str(p), dict(prepared.types), prepared.compression, prepared.clamped)


@dataclass
class ExrPartData:
    """One part to write with :func:`write_exr_parts`.

    Attributes:
        name: the part's name (non-empty, unique in the file); readers select parts by it.
        channels: channel name -> array ``(H, W)`` (see :func:`write_exr`).
        pixel_type: ``"float"``/``"half"`` for every channel, or a mapping channel -> type.
        attributes: extra header attributes of this part (str, int or float values).
        data_window: ``(xmin, ymin, xmax, ymax)`` inclusive; default ``(0, 0, W-1, H-1)``.
        display_window: default: the data window. Every part of a file must share it
            (an OpenEXR rule for multi-part files).
    """

    name: str
    channels: Mapping[str, np.ndarray]
    pixel_type: str | Mapping[str, str] = "float"
    attributes: Mapping[str, str | int | float] | None = None
    data_window: Iterable[int] | None = None
    display_window: Iterable[int] | None = None


def write_exr_parts(
    path: str | os.PathLike[str],
    parts: Sequence[ExrPartData],
    *,
    compression: str = "zip",
) -> list[WriteReport]:
    """Write a multi-part EXR file atomically, one :class:`ExrPartData` per part, in order.

    Each part is prepared exactly like a :func:`write_exr` file (same checks, half clamping,
    deterministic bytes) and gets a ``name`` attribute; :func:`read_exr` and
    :func:`mcdenoise.io.load_buffers` select a part by that name (``part="spp16"``) or index.
    A single part gives a valid single-part file that still carries its name.

    Args:
        path: destination (replaced atomically if it exists).
        parts: the parts; names must be non-empty and unique, display windows equal.
        compression: one of :data:`COMPRESSIONS`, used for every part.

    Returns:
        One :class:`WriteReport` per part (``path`` is the file's), in order.

    Raises:
        InputError: no parts, bad or duplicate names, different display windows, or any
            argument :func:`write_exr` would refuse (the message names the part).
        ExrError: the file cannot be written.
    """
    p = Path(path)
    if isinstance(parts, ExrPartData) or not parts:
        raise InputError(f"{p}: write_exr_parts needs a non-empty sequence of ExrPartData")
    names: list[str] = []
    prepared: list[_Prepared] = []
    for k, part in enumerate(parts):
        if not isinstance(part, ExrPartData):
            raise InputError(f"{p}: part {k} must be an ExrPartData, got {type(part).__name__}")
        if not isinstance(part.name, str) or not part.name.strip():
            raise InputError(f"{p}: part {k} needs a non-empty name, got {part.name!r}")
        if part.name in names:
            raise InputError(f"{p}: part name {part.name!r} is used twice")
        if part.attributes and "name" in part.attributes:
            raise InputError(f"{p}: part {part.name!r}: set the name with ExrPartData.name")
        names.append(part.name)
        try:
            prep = _prepare_part(
                p,
                part.channels,
                pixel_type=part.pixel_type,
                compression=compression,
                attributes=part.attributes,
                data_window=part.data_window,
                display_window=part.display_window,
                tile_size=None,
                line_order="increasing",
            )
        except InputError as err:
            msg = str(err).removeprefix(f"{p}: ")
            raise InputError(f"{p}: part {part.name!r}: {msg}") from None
        prep.spec.attribute("name", part.name)
        prepared.append(prep)
    first = prepared[0].display_window
    for name, prep in zip(names, prepared):
        if prep.display_window != first:
            raise InputError(
                f"{p}: part {name!r} has display window {prep.display_window} but part "
                f"{names[0]!r} has {first}; the parts of a file must share it"
            )
    if p.is_dir():
        raise ExrError(f"{p}: is a folder; cannot write an EXR file there")
    _write_prepared(p, prepared)
    return [WriteReport(str(p), dict(pr.types), pr.compression, pr.clamped) for pr in prepared]


@dataclass
class _Prepared:
    """A validated part: its OpenImageIO spec and float32 pixels ``(H, W, C)``."""

    spec: Any
    pixels: np.ndarray
    types: dict[str, str]
    compression: str
    clamped: dict[str, int]
    display_window: Window


def _prepare_part(
    p: Path,
    channels: Mapping[str, np.ndarray],
    *,
    pixel_type: str | Mapping[str, str],
    compression: str,
    attributes: Mapping[str, str | int | float] | None,
    data_window: Iterable[int] | None,
    display_window: Iterable[int] | None,
    tile_size: tuple[int, int] | None,
    line_order: str,
) -> _Prepared:
    """Validate the arguments of one part and build its spec and pixels (no file access)."""
    if not channels:
        raise InputError(f"{p}: nothing to write (no channels)")
    names = list(channels)
    arrays: list[np.ndarray] = []
    shape: tuple[int, ...] | None = None
    for n in names:
        if not isinstance(n, str) or not n:
            raise InputError(f"{p}: channel names must be non-empty strings, got {n!r}")
        a = np.asarray(channels[n])
        if a.ndim != 2:
            raise InputError(f"{p}: channel {n!r} must be a 2-D array (H, W), got shape {a.shape}")
        if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
            raise InputError(f"{p}: channel {n!r} has non-numeric dtype {a.dtype}")
        if shape is None:
            shape = a.shape
        elif a.shape != shape:
            raise InputError(
                f"{p}: channel {n!r} has shape {a.shape} but {names[0]!r} has {shape}; "
                "all channels of a part must have the same size"
            )
        arrays.append(a)
    assert shape is not None
    h, w = shape
    if h == 0 or w == 0:
        raise InputError(f"{p}: cannot write an empty {w}x{h} image")

    if isinstance(pixel_type, str):
        types = {n: pixel_type for n in names}
    else:
        unknown = [n for n in pixel_type if n not in channels]
        if unknown:
            raise InputError(f"{p}: pixel_type names unknown channel(s) {', '.join(unknown)}")
        types = {n: pixel_type.get(n, "float") for n in names}
    for n, t in types.items():
        if t not in ("float", "half"):
            raise InputError(f"{p}: pixel type of {n!r} must be 'float' or 'half', got {t!r}")
    comp = _check_compression(compression)

    dw = _check_window("data_window", data_window) or (0, 0, w - 1, h - 1)
    if (dw[2] - dw[0] + 1, dw[3] - dw[1] + 1) != (w, h):
        raise InputError(
            f"{p}: data_window {dw} is {dw[2] - dw[0] + 1}x{dw[3] - dw[1] + 1} but the arrays "
            f"are {w}x{h}"
        )
    vw = _check_window("display_window", display_window) or dw
    if line_order not in ("increasing", "decreasing", "random"):
        raise InputError(f"line_order must be increasing, decreasing or random, got {line_order!r}")
    if line_order == "random" and tile_size is None:
        raise InputError("line_order='random' needs a tiled file (tile_size)")
    if tile_size is not None:
        tw, th = (int(v) for v in tile_size)
        if tw <= 0 or th <= 0:
            raise InputError(f"tile_size must be positive, got {tile_size!r}")

    # Pixels: float32, with half channels clamped to the finite half range (counted).
    pixels = np.empty((h, w, len(names)), dtype=np.float32)
    clamped: dict[str, int] = {}
    with np.errstate(invalid="ignore", over="ignore"):
        for k, (n, a) in enumerate(zip(names, arrays)):
            a32 = a.astype(np.float32, copy=False)
            if types[n] == "half":
                finite = np.isfinite(a32)
                over = finite & (np.abs(a32) > HALF_MAX)
                count = int(over.sum())
                if count:
                    a32 = np.where(over, np.sign(a32) * np.float32(HALF_MAX), a32)
                    clamped[n] = count
            pixels[:, :, k] = a32

    oiio = _oiio()
    spec = oiio.ImageSpec(w, h, len(names), "float")
    spec.channelnames = tuple(names)
    spec.channelformats = tuple(oiio.TypeDesc(types[n]) for n in names)
    spec.x, spec.y = dw[0], dw[1]
    spec.full_x, spec.full_y = vw[0], vw[1]
    spec.full_width, spec.full_height = vw[2] - vw[0] + 1, vw[3] - vw[1] + 1
    spec.attribute("compression", comp)
    spec.attribute("openexr:lineOrder", f"{line_order}Y")
    if tile_size is not None:
        spec.tile_width, spec.tile_height = tw, th
    attrs = dict(attributes or {})
    if "DateTime" not in attrs and "capDate" not in attrs:
        spec.attribute("DateTime", "")  # an empty value suppresses the automatic time stamp
    for key, value in attrs.items():
        if key == "capDate":
            key = "DateTime"
        if not isinstance(key, str) or not key:
            raise InputError(f"{p}: attribute names must be non-empty strings, got {key!r}")
        if isinstance(value, bool):
            value = int(value)
        if isinstance(value, float) and not math.isfinite(value):
            raise InputError(f"{p}: attribute {key!r} must be finite, got {value!r}")
        if isinstance(value, (np.integer, np.floating)):
            value = value.item()
        if not isinstance(value, (str, int, float)):
            raise InputError(
                f"{p}: attribute {key!r} must be a str, int or float, got {type(value).__name__}"
            )
        if isinstance(value, str):
            value = readable_name(value).replace("\0", "")  # OpenEXR strings: UTF-8, no NUL
        if isinstance(value, int) and not -(2**31) <= value < 2**31:
            raise InputError(f"{p}: attribute {key!r} does not fit a 32-bit int: {value}")
        spec.attribute(key, value)

    return _Prepared(spec, pixels, dict(types), comp, clamped, vw)


def _write_prepared(p: Path, prepared: Sequence[_Prepared]) -> None:
    """Write the prepared parts to ``p`` atomically (one part: a plain single-part file)."""
    oiio = _oiio()
    try:
        with atomic_path(p) as tmp:  # checked to the last chunk: OIIO may hide a failed flush
            out = oiio.ImageOutput.create("openexr")
            if out is None:
                raise ExrError(f"{p}: OpenImageIO has no EXR writer: {_error_text(oiio)}")
            closed = False
            try:
                specs = [pr.spec for pr in prepared]
                opened = (
                    out.open(str(tmp), specs) if len(specs) > 1 else out.open(str(tmp), specs[0])
                )
                if not opened:
                    raise ExrError(f"{p}: cannot write: {_error_text(out)}")
                ok, msg = True, ""
                for k, pr in enumerate(prepared):
                    if k and not out.open(str(tmp), pr.spec, "AppendSubimage"):
                        ok, msg = False, _error_text(out)
                        break
                    if not out.write_image(pr.pixels):
                        ok, msg = False, _error_text(out)
                        break
                closed = True
                if not out.close() or not ok:
                    raise ExrError(f"{p}: cannot write: {msg or _error_text(out)}")
            finally:
                if not closed:
                    out.close()  # release the temporary file before it is removed
    except OSError as e:
        if isinstance(e, ExrError):
            raise
        why = str(e) if isinstance(e, McdenoiseError) else f"{p}: cannot write ({e.strerror or e})"
        raise ExrError(why) from None
    finally:
        _clear_global_error()
