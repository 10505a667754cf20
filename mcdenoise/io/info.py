"""What is in an EXR file, as seen by mcdenoise (backs ``mcdenoise info``).

:func:`describe` reports the detected profile and why, the parts with their windows, which
buffers were found (from which channels, stored as half or float, converted how), which known
buffers are missing, the channels no buffer uses, NaN/Inf/negative counts per buffer
(docs/hard-cases.md item 10: values are loaded as they are and only counted here), and the
sample count.
Unlike :func:`mcdenoise.io.load_buffers` it does not stop at an incomplete feature or a missing
colour: those are listed under ``problems``. Unreadable files still raise ExrError.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

from mcdenoise.io.buffer_files import MappingArg, read_buffers
from mcdenoise.io.buffers import BUFFER_NAMES, MAX_MAGNITUDE, out_of_range_counts
from mcdenoise.io.exr import ExrPart, probe_exr
from mcdenoise.io.profiles import Profile, ProfileError


@dataclass
class BufferInfo:
    """One loaded buffer.

    Attributes:
        name: buffer name (``color``, ``albedo_var``...).
        channels: file channels it was built from.
        pixel_types: stored type of each of those channels (``half``/``float``/``uint``).
        conversion: how it was built (``"copy"``, ``"per_sample"``, ``"moments"``) and from what.
        shape: ``(C, H, W)``.
        nan, inf, negative: counts of NaN, +/-Inf and negative values (as loaded).
        min, max: smallest / largest finite value (``None`` if there is none).
    """

    name: str
    channels: list[str]
    pixel_types: list[str]
    conversion: str
    shape: tuple[int, int, int]
    nan: int
    inf: int
    negative: int
    min: float | None
    max: float | None


@dataclass
class FileInfo:
    """Description of one EXR file; ``to_dict()`` is JSON-safe, ``format_text()`` readable."""

    path: str
    profile: str | None
    profile_reason: str | None
    parts: list[ExrPart]
    parts_used: list[int]
    width: int
    height: int
    data_window: tuple[int, int, int, int]
    display_window: tuple[int, int, int, int]
    spp: int | None
    spp_source: str | None
    buffers: list[BufferInfo] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    unmapped: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when the file loads (a colour buffer, no incomplete feature)."""
        return not self.problems and any(b.name == "color" for b in self.buffers)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-serialisable dict (tuples as lists, non-finite floats as strings)."""
        d = asdict(self)
        d["ok"] = self.ok
        return _json_safe(d)

    def format_text(self) -> str:
        """Multi-line human-readable report."""
        lines = [f"file        {self.path}"]
        reason = f" ({self.profile_reason})" if self.profile_reason else ""
        lines.append(f"profile     {self.profile or 'none'}{reason}")
        lines.append(f"parts       {len(self.parts)}")
        for p in self.parts:
            used = "*" if p.index in self.parts_used else " "
            layout = (
                f"tiled {p.tile_size[0]}x{p.tile_size[1]}"
                if p.tile_size
                else ("tiled" if p.tiled else "scanline")
            )
            name = repr(p.name) if p.name else "(unnamed)"
            lines.append(
                f"  {used}#{p.index} {name} {p.width}x{p.height} data {_win(p.data_window)} "
                f"display {_win(p.display_window)} {layout} {p.compression} "
                f"{p.line_order}Y, {len(p.channels)} channels ({_types(p)})"
            )
        lines.append(
            f"resolution  {self.width}x{self.height}  data window {_win(self.data_window)}  "
            f"display window {_win(self.display_window)}"
        )
        spp = f"{self.spp} ({self.spp_source})" if self.spp is not None else "unknown"
        lines.append(f"spp         {spp}")
        lines.append("buffers" if self.buffers else "buffers     none")
        for b in self.buffers:
            types = "/".join(sorted(set(b.pixel_types)))
            rng = f"[{_num(b.min)}, {_num(b.max)}]" if b.min is not None else "[no finite values]"
            lines.append(
                f"  {b.name:<14} {b.shape[0]}ch {types:<5} nan {b.nan} inf {b.inf} "
                f"neg {b.negative} range {rng}  <- {b.conversion}"
            )
        lines.append(f"missing     {', '.join(self.missing) or 'none'}")
        lines.append(f"unmapped    {', '.join(self.unmapped) or 'none'}")
        for n in self.notes:
            lines.append(f"note        {n}")
        for pr in self.problems:
            lines.append(f"PROBLEM     {pr}")
        if self.problems:
            lines.append("            (denoise refuses this file until the problem is fixed)")
        return "\n".join(lines)


def _win(w: tuple[int, int, int, int]) -> str:
    return f"({w[0]},{w[1]})-({w[2]},{w[3]})"


def _num(x: float) -> str:
    return f"{x:.6g}"


def _types(p: ExrPart) -> str:
    counts: dict[str, int] = {}
    for c in p.channels:
        counts[c.pixel_type] = counts.get(c.pixel_type, 0) + 1
    return ", ".join(f"{n} {t}" for t, n in counts.items())


def _json_safe(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    if isinstance(x, (str, int, float, bool)) or x is None:
        return x
    if isinstance(x, np.generic):
        return _json_safe(x.item())
    return str(x)


def _stats(t: torch.Tensor) -> tuple[int, int, int, float | None, float | None]:
    finite = torch.isfinite(t)
    vals = t[finite]
    lo = float(vals.min()) if vals.numel() else None
    hi = float(vals.max()) if vals.numel() else None
    return (
        int(torch.isnan(t).sum()),
        int(torch.isinf(t).sum()),
        int((t < 0).sum()),
        lo,
        hi,
    )


def describe(
    path: str | os.PathLike[str],
    *,
    profile: str | Profile = "auto",
    mapping: MappingArg = None,
    part: str | int | None = None,
    spp: int | None = None,
    max_pixels: int | None = None,
    max_read_bytes: int | None = None,
) -> FileInfo:
    """Describe an EXR file (see the module docstring); arguments as for ``load_buffers``.

    Raises:
        ExrError: unreadable, corrupt, truncated or too large files.
        InputError: invalid arguments (``spp`` conflicting with the header, bad mapping...).
    """
    src = str(path)
    try:
        res = read_buffers(
            path,
            profile=profile,
            mapping=mapping,
            part=part,
            spp=spp,
            max_pixels=max_pixels,
            strict=False,
            max_read_bytes=max_read_bytes,
            warn=False,
        )
    except ProfileError as e:
        parts = probe_exr(path)
        ref = parts[0]
        return FileInfo(
            path=src,
            profile=None,
            profile_reason=None,
            parts=parts,
            parts_used=[],
            width=ref.width,
            height=ref.height,
            data_window=ref.data_window,
            display_window=ref.display_window,
            spp=spp,
            spp_source="spp= argument" if spp is not None else None,
            unmapped=[c for p in parts for c in p.channel_names],
            problems=[str(e)],
        )

    fb = res.buffers
    cmap = res.channel_map
    ptype = {c.name: c.pixel_type for i in res.used_parts for c in res.parts[i].channels}
    infos = []
    for name in fb.names():
        t = fb[name]
        chans = fb.channels.get(name, [])
        src_desc = next(
            (s for s in cmap.sources.get(name, ()) if list(s.channels + s.m2) == chans), None
        )
        conversion = f"{src_desc.op}: {src_desc.describe()}" if src_desc else ", ".join(chans)
        nan, inf, neg, lo, hi = _stats(t)
        infos.append(
            BufferInfo(
                name=name,
                channels=chans,
                pixel_types=[ptype.get(c, "unknown") for c in chans],
                conversion=conversion,
                shape=(int(t.shape[0]), int(t.shape[1]), int(t.shape[2])),
                nan=nan,
                inf=inf,
                negative=neg,
                min=lo,
                max=hi,
            )
        )
    ref = res.parts[res.used_parts[0]] if res.used_parts else res.parts[0]
    notes = list(res.notes) + _repair_notes(fb)
    return FileInfo(
        path=src,
        profile=cmap.profile,
        profile_reason=cmap.reason,
        parts=res.parts,
        parts_used=res.used_parts,
        width=ref.width,
        height=ref.height,
        data_window=ref.data_window,
        display_window=ref.display_window,
        spp=cmap.spp,
        spp_source=cmap.spp_source,
        buffers=infos,
        missing=[b for b in BUFFER_NAMES if b not in fb],
        unmapped=list(cmap.unmapped),
        notes=notes,
        problems=list(cmap.problems),
    )


def _repair_notes(fb: Any) -> list[str]:
    """One line per buffer holding values ``denoise`` repairs (NaN, Inf, out of range)."""
    notes = []
    for name in fb.names():
        nan, inf, huge = out_of_range_counts(fb[name])
        if not (nan or inf or huge):
            continue
        counts = [
            f"{n} {what}"
            for n, what in (
                (nan, "NaN values"),
                (inf, "Inf values"),
                (huge, f"values beyond +/-{MAX_MAGNITUDE:.0e} (damaged pixel data?)"),
            )
            if n
        ]
        held = ", ".join(counts[:-1]) + " and " + counts[-1] if len(counts) > 1 else counts[0]
        notes.append(
            f"{name} holds {held}; denoise repairs them (NaN -> 0, Inf and out-of-range "
            "values -> the buffer's nearest in-range value)"
        )
    return notes
