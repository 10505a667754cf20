"""Write EXR files: one part (:func:`write_exr`) or several named parts
(:func:`write_exr_parts`), through OpenImageIO, atomically and checked.

The reading side, the data types and the layout rules are in :mod:`mcdenoise.io.exr`; every
part is prepared (channels checked, half floats clamped to ±65504, windows and compression
validated) before anything is written, so a bad argument never leaves a half-written file.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mcdenoise.errors import ExrError, InputError, McdenoiseError
from mcdenoise.io.atomic import atomic_path
from mcdenoise.io.exr import Window, _clear_global_error, _oiio
from mcdenoise.io.exr_messages import error_text as _error_text
from mcdenoise.io.exr_messages import readable_name


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


#: Compression names accepted by :func:`write_exr` (an optional ``:level`` may follow
#: ``zip``, ``zips``, ``dwaa`` and ``dwab``).
COMPRESSIONS = ("none", "rle", "zips", "zip", "piz", "pxr24", "b44", "b44a", "dwaa", "dwab")


_LEVELLED = ("zip", "zips", "dwaa", "dwab")


#: Largest finite half-float value.
HALF_MAX = 65504.0


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
