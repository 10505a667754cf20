"""What every renderer profile is made of: the :class:`Profile` base class, the
:class:`BufferSource` / :class:`ChannelMap` records a profile's proposals resolve into, and
the errors.

A profile proposes, for each buffer of :mod:`mcdenoise.io.buffers`, alternative
:class:`BufferSource`\\ s in order of preference (channel names that may or may not be in the
file); :func:`mcdenoise.io.profiles.resolve.resolve_channels` keeps the first complete one.
Channel positions and the order inside the file never matter.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from mcdenoise.errors import McdenoiseError
from mcdenoise.io.buffers import MissingFeatureError

#: Channel suffixes of RGB and XYZ triples.
RGB: tuple[str, str, str] = ("R", "G", "B")
XYZ: tuple[str, str, str] = ("X", "Y", "Z")


class ProfileError(McdenoiseError, ValueError):
    """A profile name, a mapping file or the channel layout of a file cannot be used."""


class IncompleteFeatureError(MissingFeatureError):
    """A feature is only partly present in the file (e.g. ``albedo.B`` missing)."""

    def __init__(
        self,
        buffer: str,
        missing: Sequence[str],
        found: Sequence[str],
        *,
        source: str | None = None,
        channels: Sequence[str] | None = None,
    ) -> None:
        self.missing = list(missing)
        self.present = list(found)
        self.source = source
        self.channels = list(channels) if channels is not None else None
        self.buffer = buffer
        where = f"{source}: " if source else ""
        msg = (
            f"{where}{buffer} is incomplete: missing channel(s) {', '.join(missing)} "
            f"(found {', '.join(found)}); a partially present feature is never skipped"
        )
        if self.channels is not None:
            msg += f" (file channels: {shorten(self.channels)})"
        msg += (
            "; write the file again with all of its channels, or name the channels to use "
            "in a mapping file (--mapping, see docs/formats.md)"
        )
        ValueError.__init__(self, msg)


def shorten(names: Sequence[str], limit: int = 40) -> str:
    """``names`` joined by commas, cut after ``limit`` (for error messages)."""
    shown = ", ".join(names[:limit])
    more = f", ... ({len(names) - limit} more)" if len(names) > limit else ""
    return (shown + more) or "none"


# --- channel maps ---------------------------------------------------------------------------
@dataclass(frozen=True)
class BufferSource:
    """How one buffer is computed from file channels.

    Attributes:
        channels: file channels, in buffer channel order (first moments for ``moments``).
        op: ``"copy"`` (as stored), ``"per_sample"`` (per-sample variance / spp) or
            ``"moments"`` (``max(m2 - m1^2, 0) / (spp - 1)``).
        m2: second-moment channels (``moments`` only), parallel to ``channels``.
        luminance_of: ``moments`` only: RGB channels whose luminance must equal ``channels[0]``
            on load, or the source is rejected (how Mitsuba's colour moments are matched).
        scale: per-channel factors applied after ``op`` (a sign flip of a renderer's axis,
            e.g. Blender's ``Vector.Y``, y up, into the canonical y down); empty = none.
        far: values at or above this are the renderer's "no hit" marker and become 0, the
            canonical value where the camera ray escapes (Blender's ``Depth.Z`` = 1e10).
        note: the source differs from the canonical convention in a way no conversion can
            fix (e.g. planar instead of along-the-ray depth): reported on load.
        expect_max: values above this are outside what the buffer's canonical meaning allows
            (e.g. an albedo above 1): counted and reported on load, kept as stored.
        expect_why: why such values occur, appended to that report.
    """

    channels: tuple[str, ...]
    op: str = "copy"
    m2: tuple[str, ...] = ()
    luminance_of: tuple[str, ...] = ()
    scale: tuple[float, ...] = ()
    far: float | None = None
    note: str = ""
    expect_max: float | None = None
    expect_why: str = ""

    def __post_init__(self) -> None:
        if self.scale and len(self.scale) != len(self.channels):
            raise ValueError(
                f"scale has {len(self.scale)} factors for {len(self.channels)} channels"
            )

    def file_channels(self) -> tuple[str, ...]:
        return self.channels + self.m2 + self.luminance_of

    def describe(self) -> str:
        """One-line description, e.g. ``"(m2 - m1^2)/(spp-1) of img.path.Y"``."""
        ch = ", ".join(self.channels)
        if self.op == "per_sample":
            text = f"{ch} / spp (per-sample variance)"
        elif self.op == "moments":
            text = f"(m2 - m1^2)/(spp - 1) with m1 = {ch}, m2 = {', '.join(self.m2)}"
        else:
            text = ch
        if self.scale:
            text += " times (" + ", ".join(f"{f:g}" for f in self.scale) + ")"
        if self.far is not None:
            text += f"; values >= {self.far:g} (no hit) -> 0"
        return text


@dataclass
class ChannelMap:
    """The resolution of a profile against one file's channels.

    Attributes:
        profile: profile name (``"mitsuba"``, ``"cycles:ViewLayer"``, ``"mapping"``...).
        reason: why this profile was chosen (detection rule, forced, mapping).
        sources: buffer -> candidate sources, tried in order on load (more than one only for
            sources checked against pixel values).
        spp: samples per pixel, if known; ``spp_source`` says where it came from.
        unmapped: file channels no buffer uses.
        notes: why some buffers are not produced (e.g. a variance without ``spp``).
        problems: errors found with ``strict=False`` (incomplete or missing required buffers).
    """

    profile: str
    reason: str
    sources: dict[str, tuple[BufferSource, ...]]
    spp: int | None
    spp_source: str | None
    unmapped: list[str]
    notes: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    def file_channels(self) -> list[str]:
        """Every file channel needed to build the buffers (no duplicates, stable order)."""
        out: dict[str, None] = {}
        for cands in self.sources.values():
            for s in cands:
                out.update(dict.fromkeys(s.file_channels()))
        return list(out)


@dataclass
class AssembledBuffers:
    """Arrays built from a :class:`ChannelMap`: buffer -> float32 ``(C, H, W)``."""

    arrays: dict[str, np.ndarray]
    sources: dict[str, BufferSource]
    notes: list[str]
    #: Conventions that differ from the canonical ones, and values out of the canonical range
    #: (one line each, ``"<buffer>: ..."``); :func:`mcdenoise.io.load_buffers` logs them.
    warnings: list[str] = field(default_factory=list)


# --- profiles --------------------------------------------------------------------------------
#: What :meth:`Profile.propose` returns: buffer -> alternative sources, preferred first.
Alternatives = dict[str, list[BufferSource]]


class Profile:
    """Base class: a renderer's channel-naming convention."""

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""

    @property
    def label(self) -> str:
        """Name as reported (may include options, e.g. ``cycles:ViewLayer``)."""
        return self.name

    def detect(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> str | None:
        """A reason string if the file looks written by this renderer, else None."""
        return None

    def propose(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> Alternatives:
        """Buffer -> alternative sources in order of preference (channels may be absent)."""
        raise NotImplementedError

    def header_spp(self, attributes: Mapping[str, Any]) -> tuple[int, str] | None:
        """Samples per pixel recorded in the header by this renderer, and the attribute name."""
        return None

    def __repr__(self) -> str:
        return f"<profile {self.label}>"


def copied(*channels: str) -> BufferSource:
    """A source that copies ``channels`` as stored."""
    return BufferSource(tuple(channels))


def layered(layer: str, suffixes: Iterable[str]) -> tuple[str, ...]:
    """``layer.<suffix>`` for each suffix."""
    return tuple(f"{layer}.{s}" for s in suffixes)


def int_attribute(attributes: Mapping[str, Any], key: str) -> tuple[int, str] | None:
    """A positive integer header attribute (int, integral float or numeric string) and where
    it came from, or None when absent or not a positive integer."""
    if key not in attributes:
        return None
    value = attributes[key]
    try:
        n = int(str(value).strip()) if not isinstance(value, (int, float)) else int(value)
    except ValueError:
        return None
    if isinstance(value, float) and value != n:
        return None
    return (n, f"header attribute {key}") if n > 0 else None
