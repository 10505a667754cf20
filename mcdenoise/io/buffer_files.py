"""Reading and writing :class:`~mcdenoise.io.buffers.FeatureBuffers` as EXR files.

:func:`load_buffers` reads any supported renderer's file through a profile
(:mod:`mcdenoise.io.profiles`); :func:`save_buffers` writes the ``mcdenoise`` canonical layout.

Window policy (docs/hard-cases.md item 6): buffers hold exactly the pixels of the *data
window* (no padding to, or cropping by, the display window). Both windows are kept on the
FeatureBuffers (``data_window``, ``display_window``) and written back unchanged by
:func:`save_buffers`, so offsets and negative origins survive a read -> write -> read round
trip. A file whose buffers
would come from parts with different data windows is refused (never broadcast or padded).

Multi-part files: with ``part=None`` channels are looked up by name in every part (a name
present in two parts must be disambiguated with ``part=``); ``part="name"`` or an index
restricts the search to that part. Exception: a file whose parts are *each* a complete image in
the ``mcdenoise`` layout (every part carries ``mcdenoise:layout``, as written by
:func:`save_buffers_parts`, e.g. the spp levels ``spp4``, ``spp16``, ... of ``mcdenoise
render``) defaults to its first part. In a Blender file (``BlenderMultiChannel`` in part 0;
Blender 5 writes one part ``<Layer>.<Pass>`` per pass), ``part`` names a view layer
(``"ViewLayer"``) or any part of one, and selects every part of that layer; Blender's
file-wide header attributes (``cycles.<Layer>.samples``...), written in part 0 only, are read
whatever part is chosen.

Conventions of the renderer that differ from the canonical ones (planar depth, camera-space
normals, albedo out of range) are logged as warnings (logger ``mcdenoise.io.buffer_files``)
and kept in the notes (``attributes["_notes"]``, ``mcdenoise info``).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from mcdenoise.errors import ExrError, InputError
from mcdenoise.io.buffers import FeatureBuffers, base_feature, halves_problem
from mcdenoise.io.exr import ExrPart, probe_exr, read_exr, select_part
from mcdenoise.io.exr_write import ExrPartData, WriteReport, write_exr, write_exr_parts
from mcdenoise.io.limits import check_pixel_limit, check_read_size
from mcdenoise.io.profiles import (
    BLENDER_ATTR,
    LAYOUT_ATTR,
    LAYOUT_VERSION,
    SPP_ATTR,
    ChannelMap,
    Profile,
    assemble,
    canonical_channels,
    cycles_layers,
    resolve_channels,
)

log = logging.getLogger(__name__)

MappingArg = str | os.PathLike[str] | Mapping[str, Any] | None


@dataclass
class LoadResult:
    """Everything :func:`read_buffers` learned about a file.

    Attributes:
        buffers: the loaded buffers.
        channel_map: the profile resolution (sources, unmapped channels, notes, problems).
        parts: headers of every part of the file.
        used_parts: indices of the parts pixels were read from.
        notes: why some buffers were not produced (also in ``buffers.attributes["_notes"]``).
    """

    buffers: FeatureBuffers
    channel_map: ChannelMap
    parts: list[ExrPart]
    used_parts: list[int]
    notes: list[str] = field(default_factory=list)


def _window_text(p: ExrPart) -> str:
    label = repr(p.name) if p.name else f"#{p.index}"
    x0, y0, x1, y1 = p.data_window
    return f"part {label} {p.width}x{p.height} at ({x0},{y0})-({x1},{y1})"


def read_buffers(
    path: str | os.PathLike[str],
    *,
    profile: str | Profile = "auto",
    mapping: MappingArg = None,
    part: str | int | None = None,
    spp: int | None = None,
    max_pixels: int | None = None,
    strict: bool = True,
    max_read_bytes: int | None = None,
    warn: bool = True,
) -> LoadResult:
    """Like :func:`load_buffers`, but return the resolution details too.

    ``strict=False`` records a missing ``color`` or an incomplete feature in
    ``channel_map.problems`` instead of raising (used by :func:`mcdenoise.io.describe`).
    ``warn=False`` leaves the profile's convention warnings in ``notes`` only (not logged).
    """
    src = str(path)
    parts = probe_exr(path)
    if part is None and len(parts) > 1 and all(LAYOUT_ATTR in p.attributes for p in parts):
        part = 0  # every part is a complete mcdenoise image (spp levels): the first one
    blender = BLENDER_ATTR in parts[0].attributes
    if part is None:
        searched = parts
    elif blender:
        searched = _blender_layer_parts(parts, part, src)
    else:
        searched = [select_part(parts, part, src)]
    owner: dict[str, int] = {}
    duplicated: dict[str, list[int]] = {}
    for p in searched:
        for c in p.channel_names:
            if c in owner:
                duplicated.setdefault(c, [owner[c]]).append(p.index)
            else:
                owner[c] = p.index
    attributes: dict[str, Any] = {}
    for p in reversed(searched):  # the first part wins on conflicting attributes
        attributes.update(p.attributes)
    if blender:  # Blender writes its file-wide attributes (samples, ...) in part 0 only
        for k, v in parts[0].attributes.items():
            attributes.setdefault(k, v)
    names = list(owner)

    cmap = resolve_channels(
        names, attributes, profile=profile, mapping=mapping, spp=spp, strict=strict, source=src
    )
    needed = cmap.file_channels()
    ambiguous = [c for c in needed if c in duplicated]
    if ambiguous:
        c = ambiguous[0]
        where = ", ".join(repr(parts[i].name or f"#{i}") for i in duplicated[c])
        raise ExrError(f"{src}: channel {c!r} exists in parts {where}; choose one with part=")
    by_part: dict[int, list[str]] = {}
    for c in needed:
        by_part.setdefault(owner[c], []).append(c)
    used = sorted(by_part)
    windows = {parts[i].data_window for i in used}
    if len(windows) > 1:
        _refuse_halves_of_other_sizes(src, cmap, owner, parts)
        raise ExrError(
            f"{src}: buffers would come from parts of different data windows "
            f"({'; '.join(_window_text(parts[i]) for i in used)}); they are never "
            "broadcast or padded: choose one part with part="
        )

    for i in used:
        check_pixel_limit(parts[i], src, max_pixels)
    # Every part and channel about to be read, counted before anything is allocated.
    check_read_size(src, parts, by_part, max_read_bytes=max_read_bytes)
    pixels: dict[str, np.ndarray] = {}
    for i in used:
        got = read_exr(
            path,
            part=i,
            channels=by_part[i],
            max_pixels=max_pixels,
            max_read_bytes=max_read_bytes,
        )
        pixels.update(got.pixels)
    built = assemble(cmap, pixels)
    notes = cmap.notes + built.notes + built.warnings
    if warn:
        for w in built.warnings:
            log.warning("%s: %s", src, w)

    ref = parts[used[0]] if used else searched[0]
    scalar_attrs = {k: v for k, v in attributes.items() if isinstance(v, (str, int, float))}
    scalar_attrs["_file_channels"] = names
    if notes:
        scalar_attrs["_notes"] = list(notes)
    fb = FeatureBuffers(
        buffers={b: torch.from_numpy(a) for b, a in built.arrays.items()},
        spp=cmap.spp,
        source=src,
        profile=cmap.profile,
        channels={b: list(s.channels + s.m2) for b, s in built.sources.items()},
        attributes=scalar_attrs,
        data_window=ref.data_window,
        display_window=ref.display_window,
    )
    problem = halves_problem(fb)
    if problem:
        if strict:
            raise InputError(f"{src}: {problem}")
        cmap.problems.append(problem)
    return LoadResult(fb, cmap, parts, used, notes)


def _refuse_halves_of_other_sizes(
    src: str, cmap: ChannelMap, owner: Mapping[str, int], parts: list[ExrPart]
) -> None:
    """Halves read from parts of different sizes: refused by name (before the generic
    different-windows error)."""
    window: dict[str, ExrPart] = {}
    for buf, srcs in cmap.sources.items():
        chans = [c for s in srcs for c in s.file_channels()]
        if chans:
            window[buf] = parts[owner[chans[0]]]
    for buf, p in window.items():
        if buf.endswith("_a") and buf != base_feature(buf):
            other = window.get(buf[:-2] + "_b")
            if other is not None and other.data_window != p.data_window:
                raise InputError(
                    f"{src}: {buf} ({_window_text(p)}) and {buf[:-2]}_b ({_window_text(other)}) "
                    "differ in size: the two halves of an image must have its size"
                )


def _blender_layer_parts(parts: list[ExrPart], part: str | int, src: str) -> list[ExrPart]:
    """Every part of the view layer ``part`` names, in a Blender file of one part per pass.

    ``part`` is a layer name (``"ViewLayer"``), or a part (``"ViewLayer.Combined"`` or an
    index) whose channels are one layer's: reading that part alone would drop the layer's
    other passes (Blender 5 writes ``<Layer>.<Pass>`` parts).
    """
    layer_of = {p.index: set(cycles_layers(p.channel_names)) for p in parts}
    all_layers = {name for names in layer_of.values() for name in names}
    if isinstance(part, str) and part in all_layers and not any(p.name == part for p in parts):
        layer = part
    else:
        chosen = select_part(parts, part, src)
        layers = layer_of[chosen.index]
        if len(layers) != 1:
            return [chosen]
        layer = next(iter(layers))
    return [p for p in parts if layer_of[p.index] == {layer}]


def load_buffers(
    path: str | os.PathLike[str],
    *,
    profile: str | Profile = "auto",
    mapping: MappingArg = None,
    part: str | int | None = None,
    spp: int | None = None,
    max_pixels: int | None = None,
    max_read_bytes: int | None = None,
) -> FeatureBuffers:
    """Read an EXR file into :class:`FeatureBuffers` (float32 ``(C, H, W)`` tensors).

    Args:
        path: the EXR file.
        profile: ``"auto"`` (detect), or ``"mcdenoise"``, ``"mitsuba"``, ``"cycles"``,
            ``"cycles:<Layer>"``, ``"pbrt"``, ``"tungsten"``.
        mapping: a TOML/JSON mapping file or dict (buffer -> channel names, ``spp``,
            ``variance``) overriding the profile for the buffers it names.
        part: restrict to one part (name or index); default: search every part by name.
            In a Blender file: a view layer name, or a part of a layer (all of its parts).
        spp: samples per pixel of the colour, if the file does not record it (needed to turn
            moments or per-sample variances into variances of the mean).
        max_pixels: refuse larger data windows (default ``$MCDENOISE_MAX_PIXELS`` or 200 MP).
        max_read_bytes: refuse reading more bytes, over every part and channel read
            (default ``$MCDENOISE_MAX_READ_BYTES`` or 1 GiB); see :mod:`mcdenoise.io.limits`.

    Returns:
        FeatureBuffers over the data window with ``source``, ``profile``, ``channels``,
        ``spp``, ``attributes`` (header scalars, plus ``_file_channels`` = every channel
        name of the file and, when some buffer could not be produced, ``_notes``) and both
        windows. Colour is linear HDR RGB as stored; values are not sanitised.

    Raises:
        ExrError: unreadable, corrupt, truncated or too large files; parts of different sizes.
        MissingFeatureError: no colour; IncompleteFeatureError: a partially present feature.
        ProfileError, InputError: bad profile, mapping, or conflicting ``spp``.
    """
    return read_buffers(
        path,
        profile=profile,
        mapping=mapping,
        part=part,
        spp=spp,
        max_pixels=max_pixels,
        strict=True,
        max_read_bytes=max_read_bytes,
    ).buffers


def save_buffers(
    path: str | os.PathLike[str],
    buffers: FeatureBuffers,
    *,
    half: bool | Iterable[str] = False,
    compression: str = "zip",
    attributes: Mapping[str, str | int | float] | None = None,
) -> WriteReport:
    """Write ``buffers`` atomically in the ``mcdenoise`` canonical layout.

    Args:
        path: destination EXR (replaced atomically).
        buffers: what to write; tensors ``(C, H, W)`` on any device (copied to CPU float32).
        half: store every buffer (``True``) or the named buffers as half floats; finite
            values beyond +/-65504 are clamped and counted in the report.
        compression: EXR compression (see :data:`mcdenoise.io.exr_write.COMPRESSIONS`).
        attributes: extra header attributes (e.g. ``mcdenoise:method``); ``mcdenoise:*``
            attributes already on ``buffers`` are kept, these override them.

    Returns:
        The :class:`~mcdenoise.io.exr_write.WriteReport`.

    The header gets ``mcdenoise:layout`` and, when known, ``mcdenoise:spp``. The data and
    display windows of ``buffers`` are written as they are (their size must match).
    """
    part = _canonical_part(path, buffers, half=half, attributes=attributes)
    return write_exr(
        path,
        part.channels,
        pixel_type=part.pixel_type,
        compression=compression,
        attributes=part.attributes,
        data_window=part.data_window,
        display_window=part.display_window,
    )


def save_buffers_parts(
    path: str | os.PathLike[str],
    parts: Mapping[str, FeatureBuffers],
    *,
    half: bool | Iterable[str] = False,
    compression: str = "zip",
    attributes: Mapping[str, str | int | float] | None = None,
    part_attributes: Mapping[str, Mapping[str, str | int | float]] | None = None,
) -> list[WriteReport]:
    """Write several images of the same size as one multi-part EXR, one canonical part each.

    Each part is exactly what :func:`save_buffers` would write for its FeatureBuffers (with
    ``mcdenoise:layout`` and ``mcdenoise:spp``), plus a part ``name``. :func:`load_buffers`
    reads one with ``part="name"``; without ``part`` it reads the first.

    Args:
        path: destination EXR (replaced atomically).
        parts: part name -> buffers, in file order (e.g. ``{"spp4": fb4, "spp16": fb16}``).
        half: as in :func:`save_buffers`, applied to every part (names absent from a part
            are ignored for that part).
        compression: EXR compression of every part.
        attributes: header attributes given to every part.
        part_attributes: part name -> attributes of that part only (override ``attributes``).

    Returns:
        One :class:`~mcdenoise.io.exr_write.WriteReport` per part, in order.

    Raises:
        InputError: no parts, an empty part, parts of different display windows, unknown
            names in ``part_attributes``.
        ExrError: the file cannot be written.
    """
    if not parts:
        raise InputError(f"{path}: no parts to save")
    extra = dict(part_attributes or {})
    unknown = sorted(set(extra) - set(parts))
    if unknown:
        raise InputError(f"{path}: part_attributes names unknown part(s) {', '.join(unknown)}")
    if isinstance(half, str):
        raise InputError(f"half must be a bool or a list of buffer names, got {half!r}")
    half_names = half if isinstance(half, bool) else set(half)
    data: list[ExrPartData] = []
    for name, buffers in parts.items():
        attrs = {**(attributes or {}), **extra.get(name, {})}
        part_half = (
            half_names if isinstance(half_names, bool) else half_names & set(buffers.names())
        )
        try:
            data.append(
                _canonical_part(path, buffers, half=part_half, attributes=attrs, part_name=name)
            )
        except InputError as err:
            msg = str(err).removeprefix(f"{path}: ")
            raise InputError(f"{path}: part {name!r}: {msg}") from None
    return write_exr_parts(path, data, compression=compression)


def _canonical_part(
    path: str | os.PathLike[str],
    buffers: FeatureBuffers,
    *,
    half: bool | Iterable[str],
    attributes: Mapping[str, str | int | float] | None,
    part_name: str = "",
) -> ExrPartData:
    """The canonical channels, pixel types, attributes and windows of ``buffers``."""
    names = buffers.names()
    if not names:
        raise InputError(f"{path}: no buffers to save")
    if isinstance(half, bool):
        half_set = set(names) if half else set()
    else:
        if isinstance(half, str):
            raise InputError(f"half must be a bool or a list of buffer names, got {half!r}")
        half_set = set(half)
        unknown = sorted(half_set - set(names))
        if unknown:
            raise InputError(f"half names buffer(s) not present: {', '.join(unknown)}")

    h, w = buffers.shape
    channels: dict[str, np.ndarray] = {}
    types: dict[str, str] = {}
    for name in names:
        t = buffers[name].detach().to("cpu", torch.float32)
        arr = t.numpy()
        for k, ch in enumerate(canonical_channels(name, arr.shape[0])):
            channels[ch] = arr[k]
            types[ch] = "half" if name in half_set else "float"

    attrs: dict[str, str | int | float] = {
        k: v
        for k, v in buffers.attributes.items()
        if k.startswith("mcdenoise:") and isinstance(v, (str, int, float))
    }
    attrs.pop(SPP_ATTR, None)
    attrs.update(attributes or {})
    if LAYOUT_ATTR in (attributes or {}) and str(attrs[LAYOUT_ATTR]) != LAYOUT_VERSION:
        raise InputError(f"{LAYOUT_ATTR} is set by save_buffers; got {attrs[LAYOUT_ATTR]!r}")
    attrs[LAYOUT_ATTR] = LAYOUT_VERSION
    if buffers.spp is not None:
        given = (attributes or {}).get(SPP_ATTR)
        if given is not None and given != buffers.spp:
            raise InputError(f"{SPP_ATTR}={given!r} contradicts buffers.spp={buffers.spp}")
        attrs[SPP_ATTR] = int(buffers.spp)

    dw = buffers.data_window or (0, 0, w - 1, h - 1)
    if (dw[2] - dw[0] + 1, dw[3] - dw[1] + 1) != (w, h):
        raise InputError(
            f"{path}: buffers.data_window {tuple(dw)} is {dw[2] - dw[0] + 1}x{dw[3] - dw[1] + 1} "
            f"but the buffers are {w}x{h}; update data_window (or set it to None)"
        )
    vw = buffers.display_window or dw
    return ExrPartData(
        name=part_name,
        channels=channels,
        pixel_type=types,
        attributes=attrs,
        data_window=dw,
        display_window=vw,
    )
