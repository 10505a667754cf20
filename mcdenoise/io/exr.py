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

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from mcdenoise.errors import ExrError, InputError
from mcdenoise.io.exr_messages import error_text as _error_text
from mcdenoise.io.exr_messages import explain, readable_name, special_file_kind
from mcdenoise.io.limits import (  # noqa: F401  (re-exported: the limits' historic home)
    DEFAULT_MAX_PIXELS,
    MAX_PIXELS_ENV,
    check_pixel_limit,
    check_read_size,
    resolve_max_pixels,
)

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


# --- helpers -------------------------------------------------------------------------------
def _oiio():
    import OpenImageIO  # lazy: OpenImageIO only where an image is written

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
        import OpenEXR  # lazy: optional, see except

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
