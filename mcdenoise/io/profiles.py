"""Renderer profiles: which EXR channels hold which feature buffer, looked up by NAME.

A profile turns the channel names (and header attributes) of a file into a
:class:`ChannelMap`: for every buffer of :mod:`mcdenoise.io.buffers` (``color``, ``albedo``,
``normal``, ``depth``, ``position``, ``diffuse``, ``specular``, ``visibility``, ``motion`` and
their ``<name>_var`` variances *of the mean*) the file channels it comes from and how they are
converted. Channel positions and the order inside the file never matter.

The ``mcdenoise`` canonical layout (what :func:`mcdenoise.io.save_buffers` writes)
------------------------------------------------------------------------------------

==============  ==========================================  =====================================
buffer          EXR channels                                contents
==============  ==========================================  =====================================
color           ``R``, ``G``, ``B``                         noisy radiance, linear HDR RGB
albedo          ``albedo.R``, ``albedo.G``, ``albedo.B``    first-hit reflectance, linear RGB
normal          ``normal.X``, ``normal.Y``, ``normal.Z``    shading normal, world space
depth           ``depth.Z``                                 distance camera -> first hit
position        ``position.X``, ``.Y``, ``.Z``              first-hit world position
diffuse         ``diffuse.R``, ``.G``, ``.B``               diffuse part of color
specular        ``specular.R``, ``.G``, ``.B``              specular part of color
visibility      ``visibility.Y``                            direct-light visibility in [0, 1]
motion          ``motion.X``, ``motion.Y``                  motion to the previous frame (pixels)
motion_valid    ``motion_valid.Y``                          1 where the motion is trustworthy
<buffer>_var    ``<buffer>_var.<same suffixes>``            variance of the mean of <buffer>
<buffer>_var    ``<buffer>_var.Y`` (1 channel)              luminance variance of the mean
==============  ==========================================  =====================================

e.g. ``color_var.R/G/B`` or ``color_var.Y``, ``depth_var.Z``, ``normal_var.X/Y/Z``. Header
attributes: ``mcdenoise:layout`` = ``"1"`` (marks the layout; detection relies on it) and
``mcdenoise:spp`` (int, samples per pixel of ``color``). Other ``mcdenoise:*`` attributes
(method, params JSON, source, seconds) are written by callers.

Renderer profiles (checked against each renderer's source or output)
---------------------------------------------------------------------

``mitsuba``  Mitsuba 3 ``aov`` integrator, optionally nesting a ``moment`` integrator (verified by
    rendering with Mitsuba 3.9.1 ``scalar_rgb`` and ``Bitmap.write``). Colour: ``R,G,B`` (else a
    nested integrator's ``<name>.R/G/B``). AOVs are ``<aovname>.<suffix>``, the common names are
    recognised: albedo ``albedo.R/G/B``; normal ``normal|nn|sh_normal .X/Y/Z``; depth
    ``depth|dd .T`` (distance along the ray); position ``position|pp .X/Y/Z``. An AOV integrator
    nested in a ``moment`` integrator gets its integrator name as prefix (``aov.albedo.R``),
    which is accepted. Alpha (``A``, ``<name>.A`` of nested integrators) is ignored.
    The ``moment`` integrator writes, for each nested integrator ``N``, first moments
    ``[M.]N.<ch>`` and second moments ``[M.]m2_N.<ch>`` (``M``: the moment integrator's name
    when it is itself nested). Variance of the mean = ``(m2 - m1^2) / (spp - 1)`` (the unbiased
    estimate; ``/spp`` underestimates it by ``(spp-1)/spp`` — measured on 400 renders at
    4 spp: empirical variance of the pixel mean / ((m2 - m1^2)/(spp-1)) = 0.98). Two facts that
    matter: (1) the moments of an integrator's colour are stored as CIE **XYZ** (``.X/.Y/.Z``,
    ``R,G,B`` = sRGB(XYZ)), so per-channel RGB variances cannot be derived; ``color_var`` is
    the 1-channel *luminance* variance from the ``Y`` moments, and the moment pair whose
    ``Y`` equals the luminance of ``R,G,B`` is chosen on load (none matching: no ``color_var``,
    with a note). AOV moments (``m2_aov.albedo.R``) are per channel and give per-channel
    variances. (2) Render with ``rfilter = box``: with the default gaussian filter samples are
    splatted over neighbours and the moments no longer give the variance of the pixel mean
    (measured: 0.2x the true value). Mitsuba writes no sample count: ``spp`` comes from
    ``mcdenoise:spp`` if present, else the caller's ``spp=``; without it no variance is produced
    and ``mcdenoise info`` says why. ``generatedBy = "Mitsuba version ..."`` identifies files.

``cycles``  Blender multilayer EXR (header ``BlenderMultiChannel``), channels
    ``<Layer>.<Pass>.<ch>`` (layer names may contain dots). Colour ``Noisy Image.R/G/B``
    (preferred) else ``Combined.R/G/B``; albedo ``Denoising Albedo.R/G/B``; normal
    ``Denoising Normal.X/Y/Z`` else ``Normal.X/Y/Z``; depth ``Denoising Depth.Z`` else
    ``Depth.Z`` (Cycles' Z is planar camera depth, not Mitsuba's distance along the ray);
    position ``Position.X/Y/Z``. No variance. Layer: ``profile="cycles:<Layer>"``, by default
    the first layer with ``Noisy Image``, else the first non-``Composite`` layer with
    ``Combined``. ``spp`` from the ``cycles.<Layer>.samples`` attribute Blender stamps.
    Light passes (``Diffuse Direct`` ...) are left unmapped (Cycles stores them divided by
    colour); multi-view files are not supported.

``pbrt``  pbrt-v4 ``gbuffer`` film (``GBufferFilm::GetImage``): colour ``R,G,B``; albedo
    ``Albedo.R/G/B``; normal ``Ns.X/Y/Z`` (shading; ``N.*`` is geometric and stays unmapped);
    position ``P.X/Y/Z``; depth = ``P.Z`` (camera-space z: planar depth, valid for the default
    ``coordinatesystem "camera"``). Older pbrt-v4 names ``Px``, ``Nsx``... are accepted.
    ``Variance.R/G/B`` is the *per-sample* variance ``S/(n-1)`` of pbrt's ``VarianceEstimator``,
    accumulated in *sensor* RGB, which for the default ``cie1931`` sensor is CIE XYZ; so
    ``color_var`` = ``Variance.G / spp`` as a 1-channel luminance variance of the mean (pbrt
    counts only samples that hit a surface, so background pixels are approximate). ``spp``
    from the ``samplesPerPixel`` attribute pbrt writes.

``tungsten``  Tungsten as packaged for KPCN (Bako et al. 2017, ``tungsten.py``): colour
    ``R,G,B`` (pyexr's ``default``) or ``color.R/G/B``; ``albedo.R/G/B``, ``normal.R/G/B``,
    ``depth.Z``, ``diffuse.R/G/B``, ``specular.R/G/B``, ``visibility.Z``; variances
    ``<x>Variance.Z`` (1 channel, already variance of the mean). Half buffers ``<x>A.*`` are
    left unmapped.

A user mapping file (TOML or JSON) names channels directly and overrides the profile for the
buffers it lists (see :func:`load_mapping`)::

    color = ["beauty.R", "beauty.G", "beauty.B"]
    albedo = ["alb.R", "alb.G", "alb.B"]
    color_var = ["var.Y"]
    spp = 64
    variance = "sample"   # *_var channels hold the per-sample variance: divided by spp

Channel completeness: ``color`` is required; any other feature that is partially present
(``albedo.R/G`` without ``albedo.B``) is an error naming the missing channels and listing what
the file has, never silently skipped. Features simply absent are fine.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from mcdenoise.errors import InputError, McdenoiseError
from mcdenoise.io.buffers import (
    BUFFER_NAMES,
    FEATURES,
    VAR_SUFFIX,
    MissingFeatureError,
    expected_channels,
)

#: Canonical channel suffixes of each feature (``color`` has no layer prefix).
SUFFIXES: dict[str, tuple[str, ...]] = {
    "color": ("R", "G", "B"),
    "albedo": ("R", "G", "B"),
    "normal": ("X", "Y", "Z"),
    "depth": ("Z",),
    "position": ("X", "Y", "Z"),
    "diffuse": ("R", "G", "B"),
    "specular": ("R", "G", "B"),
    "visibility": ("Y",),
    "motion": ("X", "Y"),
    "motion_valid": ("Y",),
}
#: Value of the ``mcdenoise:layout`` attribute written by :func:`mcdenoise.io.save_buffers`.
LAYOUT_VERSION = "1"
LAYOUT_ATTR = "mcdenoise:layout"
SPP_ATTR = "mcdenoise:spp"

# Rec. 709 / sRGB luminance weights (row Y of the linear-sRGB -> XYZ matrix, D65).
_LUMA = (0.2126729, 0.7151522, 0.0721750)
_RGB = ("R", "G", "B")
_XYZ = ("X", "Y", "Z")


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
            msg += f" (file channels: {_shorten(self.channels)})"
        ValueError.__init__(self, msg)


def _shorten(names: Sequence[str], limit: int = 40) -> str:
    shown = ", ".join(names[:limit])
    more = f", ... ({len(names) - limit} more)" if len(names) > limit else ""
    return (shown + more) or "none"


def canonical_channels(buffer: str, n_channels: int | None = None) -> tuple[str, ...]:
    """EXR channel names of ``buffer`` in the ``mcdenoise`` layout.

    >>> canonical_channels("color"), canonical_channels("depth_var")
    (('R', 'G', 'B'), ('depth_var.Z',))
    >>> canonical_channels("color_var", 1)
    ('color_var.Y',)
    """
    want = expected_channels(buffer)
    n = want if n_channels is None else n_channels
    is_var = buffer.endswith(VAR_SUFFIX)
    base = buffer[: -len(VAR_SUFFIX)] if is_var else buffer
    if n != want and not (is_var and n == 1):
        raise InputError(f"buffer {buffer!r} cannot have {n} channel(s)")
    if buffer == "color":
        return _RGB
    suffixes = SUFFIXES[base] if n == want else ("Y",)
    return tuple(f"{buffer}.{s}" for s in suffixes)


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
    """

    channels: tuple[str, ...]
    op: str = "copy"
    m2: tuple[str, ...] = ()
    luminance_of: tuple[str, ...] = ()

    def file_channels(self) -> tuple[str, ...]:
        return self.channels + self.m2 + self.luminance_of

    def describe(self) -> str:
        """One-line description, e.g. ``"(m2 - m1^2)/(spp-1) of img.path.Y"``."""
        ch = ", ".join(self.channels)
        if self.op == "per_sample":
            return f"{ch} / spp (per-sample variance)"
        if self.op == "moments":
            return f"(m2 - m1^2)/(spp - 1) with m1 = {ch}, m2 = {', '.join(self.m2)}"
        return ch


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


# --- profiles --------------------------------------------------------------------------------
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


def _copy(*channels: str) -> BufferSource:
    return BufferSource(tuple(channels))


def _layered(layer: str, suffixes: Iterable[str]) -> tuple[str, ...]:
    return tuple(f"{layer}.{s}" for s in suffixes)


class McdenoiseProfile(Profile):
    name = "mcdenoise"
    description = "mcdenoise canonical layout (R,G,B; albedo.R/G/B; normal.X/Y/Z; depth.Z; ...)"

    def detect(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> str | None:
        if LAYOUT_ATTR in attributes:
            return f"header attribute {LAYOUT_ATTR}={attributes[LAYOUT_ATTR]!r}"
        return None

    def propose(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> Alternatives:
        alts: Alternatives = {}
        for feat, n in FEATURES.items():
            alts[feat] = [BufferSource(canonical_channels(feat))]
            var = feat + VAR_SUFFIX
            alts[var] = [BufferSource(canonical_channels(var))]
            if n > 1:
                alts[var].append(BufferSource(canonical_channels(var, 1)))
        return alts

    def header_spp(self, attributes: Mapping[str, Any]) -> tuple[int, str] | None:
        return None  # mcdenoise:spp is read for every profile


_MITSUBA_AOVS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    # feature: (recognised AOV names in order of preference, suffixes)
    "albedo": (("albedo",), _RGB),
    "normal": (("normal", "nn", "sh_normal"), _XYZ),
    "depth": (("depth", "dd"), ("T",)),
    "position": (("position", "pp"), _XYZ),
}
_MITSUBA_AOV_NAMES = {n for names, _ in _MITSUBA_AOVS.values() for n in names} | {
    "geo_normal",
    "uv",
    "dp_du",
    "dp_dv",
    "duv_dx",
    "duv_dy",
    "prim_index",
    "shape_index",
}


def _stems(channels: Sequence[str], suffixes: Sequence[str]) -> list[str]:
    """Distinct ``stem`` such that some ``stem.<suffix>`` is a channel, in file order."""
    out: dict[str, None] = {}
    for c in channels:
        stem, dot, suffix = c.rpartition(".")
        if dot and suffix in suffixes:
            out[stem] = None
    return list(out)


def _m2_partner(channel: str, present: set[str]) -> str | None:
    """The second-moment channel of ``channel`` written by Mitsuba's ``moment`` integrator:
    ``m2_`` prefixed to one name segment (``img.path.X`` -> ``img.m2_path.X``,
    ``aov.albedo.R`` -> ``m2_aov.albedo.R``), if exactly one such channel exists."""
    segs = channel.split(".")
    found = []
    for i in range(len(segs) - 1):
        cand = ".".join([*segs[:i], "m2_" + segs[i], *segs[i + 1 :]])
        if cand in present:
            found.append(cand)
    return found[0] if len(found) == 1 else None


class MitsubaProfile(Profile):
    name = "mitsuba"
    description = "Mitsuba 3 aov integrator (+ moment integrator for variances)"

    def detect(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> str | None:
        gen = str(attributes.get("generatedBy", ""))
        if gen.startswith("Mitsuba"):
            return f"header attribute generatedBy={gen!r}"
        for c in channels:
            segs = c.split(".")
            if any(s.startswith("m2_") for s in segs[:-1]):
                return f"moment-integrator channel {c!r}"
            if len(segs) >= 2 and segs[-1] == "T" and segs[-2] in ("depth", "dd"):
                return f"Mitsuba depth AOV channel {c!r}"
            if len(segs) >= 2 and segs[-2] in ("nn", "sh_normal", "pp"):
                return f"Mitsuba AOV channel {c!r}"
        return None

    def propose(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> Alternatives:
        present = set(channels)
        alts: Alternatives = {}
        # Colour: the film's R,G,B, else a nested integrator's <name>.R/G/B.
        color = [_copy(*_RGB)]
        for stem in _stems(channels, _RGB):
            if "." not in stem and stem not in _MITSUBA_AOV_NAMES and not stem.startswith("m2_"):
                color.append(BufferSource(_layered(stem, _RGB)))
        alts["color"] = color
        # Luminance variance of colour from XYZ moments of any integrator; matched on load.
        color_var = []
        for stem in _stems(channels, _XYZ):
            last = stem.rpartition(".")[2]
            if last in _MITSUBA_AOV_NAMES or last.startswith("m2_"):
                continue
            m1 = f"{stem}.Y"
            m2 = _m2_partner(m1, present)
            if m1 in present and m2 is not None:
                color_var.append(BufferSource((m1,), "moments", (m2,), _RGB))
        if color_var:
            alts["color_var"] = color_var
        # AOVs, unprefixed first (preference order of names), then prefixed ones.
        for feat, (names, suffixes) in _MITSUBA_AOVS.items():
            stems = _stems(channels, suffixes)
            ordered = [n for n in names if n in stems]
            ordered += [s for n in names for s in stems if s.endswith("." + n)]
            ordered = [s for s in ordered if not any(p.startswith("m2_") for p in s.split("."))]
            feat_alts = [BufferSource(_layered(s, suffixes)) for s in ordered]
            if feat_alts:
                alts[feat] = feat_alts
            var_alts = []
            for src in feat_alts:
                partners = [_m2_partner(c, present) for c in src.channels]
                if all(partners) and all(c in present for c in src.channels):
                    var_alts.append(
                        BufferSource(src.channels, "moments", tuple(partners))  # type: ignore[arg-type]
                    )
            if var_alts:
                alts[feat + VAR_SUFFIX] = var_alts
        return alts


_CYCLES_PASSES = (
    "Combined",
    "Noisy Image",
    "Denoising Albedo",
    "Denoising Normal",
    "Denoising Depth",
    "Depth",
    "Mist",
    "Position",
    "Normal",
    "Vector",
    "UV",
    "Object Index",
    "Material Index",
    "Diffuse Direct",
    "Diffuse Indirect",
    "Diffuse Color",
    "Glossy Direct",
    "Glossy Indirect",
    "Glossy Color",
    "Transmission Direct",
    "Transmission Indirect",
    "Transmission Color",
    "Emission",
    "Environment",
    "Ambient Occlusion",
    "Shadow Catcher",
    "Noisy Shadow Catcher",
)
_CYCLES_RE = re.compile(
    r"^(?P<layer>.+)\.(?P<pass>"
    + "|".join(re.escape(p) for p in _CYCLES_PASSES)
    + r")\.(?P<ch>[^.]+)$"
)


def cycles_layers(channels: Sequence[str]) -> dict[str, set[str]]:
    """View layer -> pass names present, in file order, for Blender multilayer channels."""
    layers: dict[str, set[str]] = {}
    for c in channels:
        m = _CYCLES_RE.match(c)
        if m:
            layers.setdefault(m["layer"], set()).add(m["pass"])
    return layers


class CyclesProfile(Profile):
    name = "cycles"
    description = "Blender Cycles multilayer EXR (<Layer>.<Pass>.<channel>)"

    def __init__(self, layer: str | None = None) -> None:
        self.layer = layer
        self._chosen: str | None = layer

    @property
    def label(self) -> str:
        return f"cycles:{self._chosen}" if self._chosen else "cycles"

    def detect(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> str | None:
        if "BlenderMultiChannel" in attributes:
            return "header attribute BlenderMultiChannel"
        for layer, passes in cycles_layers(channels).items():
            if passes & {"Combined", "Noisy Image"}:
                return f"Blender pass channels in layer {layer!r}"
        return None

    def choose_layer(self, channels: Sequence[str]) -> str:
        layers = cycles_layers(channels)
        if self.layer is not None:
            if self.layer not in layers:
                raise ProfileError(
                    f"no Cycles view layer {self.layer!r}; the file has "
                    f"{', '.join(map(repr, layers)) or 'no Blender pass channels'}"
                )
            return self.layer
        for test in (
            lambda n, p: "Noisy Image" in p,
            lambda n, p: "Combined" in p and n != "Composite",
            lambda n, p: "Combined" in p,
        ):
            for n, p in layers.items():
                if test(n, p):
                    return n
        raise ProfileError(
            "no Cycles view layer with a Noisy Image or Combined pass; "
            f"channels: {_shorten(list(channels))}"
        )

    def propose(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> Alternatives:
        L = self.choose_layer(channels)
        self._chosen = L
        return {
            "color": [
                BufferSource(_layered(f"{L}.Noisy Image", _RGB)),
                BufferSource(_layered(f"{L}.Combined", _RGB)),
            ],
            "albedo": [BufferSource(_layered(f"{L}.Denoising Albedo", _RGB))],
            "normal": [
                BufferSource(_layered(f"{L}.Denoising Normal", _XYZ)),
                BufferSource(_layered(f"{L}.Normal", _XYZ)),
            ],
            "depth": [_copy(f"{L}.Denoising Depth.Z"), _copy(f"{L}.Depth.Z")],
            "position": [BufferSource(_layered(f"{L}.Position", _XYZ))],
        }

    def header_spp(self, attributes: Mapping[str, Any]) -> tuple[int, str] | None:
        if self._chosen is None:
            return None
        key = f"cycles.{self._chosen}.samples"
        return _int_attr(attributes, key)


class PbrtProfile(Profile):
    name = "pbrt"
    description = "pbrt-v4 gbuffer film (R,G,B; Albedo.*; Ns.*; P.*; Variance.*)"

    def detect(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> str | None:
        for c in ("Ns.X", "Nsx", "Albedo.R", "Variance.R", "RelativeVariance.R", "dzdx"):
            if c in channels:
                return f"pbrt-v4 gbuffer channel {c!r}"
        return None

    def propose(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> Alternatives:
        return {
            "color": [_copy(*_RGB)],
            "albedo": [_copy("Albedo.R", "Albedo.G", "Albedo.B")],
            "normal": [_copy("Ns.X", "Ns.Y", "Ns.Z"), _copy("Nsx", "Nsy", "Nsz")],
            "position": [_copy("P.X", "P.Y", "P.Z"), _copy("Px", "Py", "Pz")],
            "depth": [_copy("P.Z"), _copy("Pz")],
            "color_var": [BufferSource(("Variance.G",), "per_sample")],
        }

    def header_spp(self, attributes: Mapping[str, Any]) -> tuple[int, str] | None:
        return _int_attr(attributes, "samplesPerPixel")


_TUNGSTEN_FEATURES = {
    "albedo": ("albedo", _RGB),
    "normal": ("normal", _RGB),
    "depth": ("depth", ("Z",)),
    "diffuse": ("diffuse", _RGB),
    "specular": ("specular", _RGB),
    "visibility": ("visibility", ("Z",)),
}


class TungstenProfile(Profile):
    name = "tungsten"
    description = "Tungsten / KPCN data (albedo, normal, depth, diffuse, specular, *Variance)"

    def detect(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> str | None:
        for c in channels:
            if c.endswith("Variance.Z") and c.partition("Variance")[0] in (
                "color",
                "diffuse",
                "specular",
                "albedo",
                "normal",
                "depth",
                "visibility",
            ):
                return f"Tungsten/KPCN variance channel {c!r}"
        if "normal.R" in channels:
            return "Tungsten/KPCN normal channel 'normal.R'"
        return None

    def propose(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> Alternatives:
        alts: Alternatives = {
            "color": [_copy(*_RGB), BufferSource(_layered("color", _RGB))],
            "color_var": [_copy("colorVariance.Z")],
        }
        for feat, (layer, suffixes) in _TUNGSTEN_FEATURES.items():
            alts[feat] = [BufferSource(_layered(layer, suffixes))]
            alts[feat + VAR_SUFFIX] = [_copy(f"{layer}Variance.Z")]
        return alts


@dataclass(frozen=True)
class ChannelMapping:
    """A user mapping: buffer -> file channels, plus optional ``spp`` and variance kind."""

    buffers: dict[str, tuple[str, ...]]
    spp: int | None = None
    variance: str = "mean"
    source: str = "mapping"


class MappingProfile(Profile):
    """Only what a user mapping names (used when no renderer profile applies)."""

    name = "mapping"
    description = "only the channels named by a mapping file"

    def propose(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> Alternatives:
        return {}


_PROFILES: dict[str, type[Profile]] = {
    "mcdenoise": McdenoiseProfile,
    "mitsuba": MitsubaProfile,
    "cycles": CyclesProfile,
    "pbrt": PbrtProfile,
    "tungsten": TungstenProfile,
}
#: Profile names accepted by :func:`get_profile` (``cycles`` also as ``cycles:<Layer>``).
PROFILE_NAMES: tuple[str, ...] = tuple(_PROFILES)


def get_profile(name: str | Profile) -> Profile:
    """The profile called ``name`` (``"mcdenoise"``, ``"mitsuba"``, ``"cycles"``,
    ``"cycles:<Layer>"``, ``"pbrt"``, ``"tungsten"``); a Profile instance is returned as is."""
    if isinstance(name, Profile):
        return name
    if not isinstance(name, str):
        raise ProfileError(f"profile must be a name, got {name!r}")
    key, _, option = name.partition(":")
    cls = _PROFILES.get(key.strip().lower())
    if cls is None:
        raise ProfileError(
            f"unknown profile {name!r}; use 'auto' or one of {', '.join(PROFILE_NAMES)}"
        )
    if cls is CyclesProfile:
        return CyclesProfile(option or None)
    if option:
        raise ProfileError(f"profile {key!r} takes no option (got {name!r})")
    return cls()


def _detect(channels: Sequence[str], attributes: Mapping[str, Any]) -> tuple[Profile, str]:
    order: list[Profile] = [
        McdenoiseProfile(),
        CyclesProfile(),
        PbrtProfile(),
        TungstenProfile(),
        MitsubaProfile(),
    ]
    for prof in order:
        why = prof.detect(channels, attributes)
        if why:
            return prof, why
    generic = set(_RGB) | {c for f in FEATURES for c in canonical_channels(f)}
    if generic & set(channels):
        return McdenoiseProfile(), "only generic channel names (R,G,B ...): mcdenoise layout"
    raise ProfileError(
        "cannot tell which renderer wrote this file (channels: "
        f"{_shorten(list(channels))}); pass profile= one of {', '.join(PROFILE_NAMES)} "
        "or a mapping file"
    )


def detect_profile(channel_names: Sequence[str], attributes: Mapping[str, Any]) -> Profile:
    """Guess the renderer profile from channel names and header attributes.

    Rules, first match wins: ``mcdenoise:layout`` attribute -> mcdenoise; Blender multilayer
    (``BlenderMultiChannel`` or ``<Layer>.Combined.*``) -> cycles; pbrt-v4 gbuffer names
    (``Ns.X``, ``Albedo.R``, ``Variance.R``, ``dzdx``) -> pbrt; KPCN ``<x>Variance.Z`` or
    ``normal.R`` -> tungsten; ``generatedBy = Mitsuba...``, ``m2_`` moments, ``depth.T`` or
    ``nn/sh_normal/pp`` AOVs -> mitsuba; otherwise plain ``R,G,B`` -> mcdenoise.

    Raises:
        ProfileError: nothing recognisable (the message lists the channels).
    """
    return _detect(channel_names, attributes)[0]


# --- mapping files ---------------------------------------------------------------------------
def _parse_mapping_text(text: str, fmt: str, where: str) -> Any:
    if fmt == "toml":
        try:
            import tomllib
        except ModuleNotFoundError:  # Python 3.10
            try:
                import tomli as tomllib  # type: ignore[no-redef]
            except ModuleNotFoundError:
                raise ProfileError(
                    f"{where}: reading TOML needs Python 3.11+ (or the tomli package); "
                    "use a JSON mapping file"
                ) from None
        try:
            return tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise ProfileError(f"{where}: invalid TOML: {e}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise ProfileError(f"{where}: invalid JSON: {e.msg} (line {e.lineno})") from None


def load_mapping(mapping: str | os.PathLike[str] | Mapping[str, Any]) -> ChannelMapping:
    """Read and validate a user mapping (TOML or JSON file, or an already parsed mapping).

    Keys: buffer names (see :data:`mcdenoise.io.buffers.BUFFER_NAMES`) -> list of channel
    names, with the buffer's channel count (1 allowed for ``*_var``); optional ``spp``
    (positive int) and ``variance`` (``"mean"``: ``*_var`` channels hold the variance of the
    mean; ``"sample"``: per-sample variance, divided by ``spp`` on load).

    Raises:
        ProfileError: unreadable file, syntax error, unknown key, wrong type or channel count.
    """
    if isinstance(mapping, Mapping):
        data: Any = dict(mapping)
        where = "mapping"
    else:
        path = Path(mapping)
        where = str(path)
        if not path.is_file():
            raise ProfileError(f"{where}: mapping file not found")
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            raise ProfileError(f"{where}: cannot read mapping file ({e})") from None
        suffix = path.suffix.lower()
        if suffix == ".toml":
            data = _parse_mapping_text(text, "toml", where)
        elif suffix == ".json":
            data = _parse_mapping_text(text, "json", where)
        else:
            try:
                data = json.loads(text)
            except json.JSONDecodeError:
                data = _parse_mapping_text(text, "toml", where)
    if not isinstance(data, dict):
        raise ProfileError(f"{where}: a mapping must be a table of buffer = [channels]")
    buffers: dict[str, tuple[str, ...]] = {}
    spp = None
    variance = "mean"
    for key, value in data.items():
        if key == "spp":
            if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
                raise ProfileError(f"{where}: spp must be a positive integer, got {value!r}")
            spp = value
        elif key == "variance":
            if value not in ("mean", "sample"):
                raise ProfileError(f"{where}: variance must be 'mean' or 'sample', got {value!r}")
            variance = value
        elif key in BUFFER_NAMES:
            if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
                raise ProfileError(f"{where}: {key} must be a list of channel names, got {value!r}")
            want = expected_channels(key)
            ok = len(value) == want or (key.endswith(VAR_SUFFIX) and len(value) == 1)
            if not ok:
                allowed = f"{want}" + (" or 1" if key.endswith(VAR_SUFFIX) and want > 1 else "")
                raise ProfileError(
                    f"{where}: {key} needs {allowed} channel name(s), got {len(value)}: {value}"
                )
            buffers[key] = tuple(value)
        else:
            raise ProfileError(
                f"{where}: unknown key {key!r}; allowed: spp, variance, {', '.join(BUFFER_NAMES)}"
            )
    if not buffers:
        raise ProfileError(f"{where}: the mapping names no buffer")
    return ChannelMapping(buffers, spp, variance, where)


# --- resolution ------------------------------------------------------------------------------
def _int_attr(attributes: Mapping[str, Any], key: str) -> tuple[int, str] | None:
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


def _resolve_spp(
    prof: Profile,
    attributes: Mapping[str, Any],
    mapping: ChannelMapping | None,
    spp: int | None,
) -> tuple[int | None, str | None]:
    if spp is not None and (isinstance(spp, bool) or not isinstance(spp, int) or spp <= 0):
        raise InputError(f"spp must be a positive integer, got {spp!r}")
    found: list[tuple[int, str]] = []
    for cand in (_int_attr(attributes, SPP_ATTR), prof.header_spp(attributes)):
        if cand is not None:
            found.append(cand)
    if mapping is not None and mapping.spp is not None:
        found.append((mapping.spp, f"spp in {mapping.source}"))
    if spp is not None:
        found.append((spp, "spp= argument"))
    values = {v for v, _ in found}
    if len(values) > 1:
        raise InputError(
            "conflicting sample counts: " + ", ".join(f"{v} ({src})" for v, src in found)
        )
    return (found[0][0], found[0][1]) if found else (None, None)


def resolve_channels(
    channels: Sequence[str],
    attributes: Mapping[str, Any],
    *,
    profile: str | Profile = "auto",
    mapping: str | os.PathLike[str] | Mapping[str, Any] | ChannelMapping | None = None,
    spp: int | None = None,
    strict: bool = True,
    source: str | None = None,
) -> ChannelMap:
    """Map a file's channels to buffers with a profile (detected or forced) and a mapping.

    Args:
        channels: the file's channel names.
        attributes: its header attributes.
        profile: ``"auto"``, a profile name (``"cycles:ViewLayer"``) or a Profile.
        mapping: a mapping file/dict (:func:`load_mapping`); its entries override the
            profile's for the buffers they name, and are required to be present.
        spp: samples per pixel if known (must agree with the header and the mapping).
        strict: raise on a missing ``color`` or an incomplete feature (else record them in
            ``problems``, for ``mcdenoise info``).
        source: file name used in error messages.

    Raises:
        ProfileError, MissingFeatureError, IncompleteFeatureError, InputError.
    """
    names = list(channels)
    present = set(names)
    cmapping = (
        mapping if isinstance(mapping, ChannelMapping) or mapping is None else load_mapping(mapping)
    )
    if isinstance(profile, str) and profile.strip().lower() == "auto":
        try:
            prof, reason = _detect(names, attributes)
        except ProfileError:
            if cmapping is None:
                raise
            prof, reason = MappingProfile(), f"mapping {cmapping.source} (no profile detected)"
    else:
        prof = get_profile(profile)
        reason = "forced" if not isinstance(profile, Profile) else "given"
    alts = prof.propose(names, attributes)
    spp_value, spp_source = _resolve_spp(prof, attributes, cmapping, spp)
    if cmapping is not None:
        for buf, chans in cmapping.buffers.items():
            op = (
                "per_sample"
                if buf.endswith(VAR_SUFFIX) and cmapping.variance == "sample"
                else "copy"
            )
            alts[buf] = [BufferSource(chans, op)]
        if not isinstance(prof, MappingProfile):
            reason += f", overridden by {cmapping.source}"

    where = source
    sources: dict[str, tuple[BufferSource, ...]] = {}
    problems: list[str] = []
    notes: list[str] = []
    for buf in BUFFER_NAMES:
        cands = alts.get(buf, [])
        complete = [s for s in cands if all(c in present for c in s.file_channels())]
        if complete:
            checked = [s for s in complete if s.luminance_of]
            sources[buf] = tuple(checked) if checked else (complete[0],)
            continue
        forced = cmapping is not None and buf in cmapping.buffers
        partial = [s for s in cands if any(c in present for c in s.channels)]
        if partial or forced:
            best = max(partial or cands, key=lambda s: sum(c in present for c in s.channels))
            missing = [c for c in best.file_channels() if c not in present]
            found = [c for c in best.file_channels() if c in present]
            if not found:  # a mapping entry none of whose channels exist
                err: Exception = MissingFeatureError(
                    [f"{buf} ({', '.join(missing)})"],
                    [],
                    source=where,
                    channels=names,
                    needed_by=f"mapping {cmapping.source}" if cmapping else None,
                )
            else:
                err = IncompleteFeatureError(buf, missing, found, source=where, channels=names)
            if strict:
                raise err
            problems.append(str(err))
        elif buf == "color":
            err = MissingFeatureError(["color"], [], source=where, channels=names)
            if strict:
                raise err
            problems.append(str(err))

    used = {c for cands in sources.values() for s in cands for c in s.file_channels()}
    for buf in list(sources):
        needs = [s for s in sources[buf] if s.op in ("per_sample", "moments")]
        if not needs:
            continue
        if spp_value is None:
            notes.append(
                f"{buf} not produced: {needs[0].describe()} needs the sample count; "
                "pass spp= or put spp in a mapping file"
            )
            del sources[buf]
        elif spp_value < 2 and any(s.op == "moments" for s in needs):
            notes.append(f"{buf} not produced: a variance from moments needs spp >= 2")
            del sources[buf]
    unmapped = [c for c in names if c not in used]
    return ChannelMap(
        profile=prof.label,
        reason=reason,
        sources=sources,
        spp=spp_value,
        spp_source=spp_source,
        unmapped=unmapped,
        notes=notes,
        problems=problems,
    )


def _luminance(r: np.ndarray, g: np.ndarray, b: np.ndarray) -> np.ndarray:
    return _LUMA[0] * r + _LUMA[1] * g + _LUMA[2] * b


def assemble(cmap: ChannelMap, pixels: Mapping[str, np.ndarray]) -> AssembledBuffers:
    """Build the buffers of ``cmap`` from channel arrays.

    Args:
        cmap: from :func:`resolve_channels`.
        pixels: channel name -> float32 ``(H, W)`` (at least ``cmap.file_channels()``).

    Returns:
        :class:`AssembledBuffers` with float32 ``(C, H, W)`` arrays. NaN/Inf/negative values
        of copied channels are kept as stored; variances from moments are clamped at 0
        (negative only by rounding).
    """
    arrays: dict[str, np.ndarray] = {}
    chosen: dict[str, BufferSource] = {}
    notes: list[str] = []
    spp = cmap.spp
    for buf, cands in cmap.sources.items():
        for src in cands:
            stack = np.stack([pixels[c] for c in src.channels]).astype(np.float32, copy=False)
            if src.op == "copy":
                out = stack
            elif src.op == "per_sample":
                assert spp is not None
                out = stack / np.float32(spp)
            elif src.op == "moments":
                assert spp is not None and spp >= 2
                m2 = np.stack([pixels[c] for c in src.m2]).astype(np.float32, copy=False)
                if src.luminance_of:
                    lum = _luminance(*(pixels[c] for c in src.luminance_of))
                    if not np.allclose(stack[0], lum, rtol=1e-3, atol=1e-5, equal_nan=True):
                        continue
                with np.errstate(invalid="ignore", over="ignore"):
                    diff = m2 - stack * stack
                    out = np.where(diff < 0, np.float32(0), diff) / np.float32(spp - 1)
            else:  # pragma: no cover - ops are fixed above
                raise ValueError(f"unknown op {src.op!r}")
            arrays[buf] = np.ascontiguousarray(out, dtype=np.float32)
            chosen[buf] = src
            break
        else:
            tried = "; ".join(s.describe() for s in cands)
            notes.append(
                f"{buf} not produced: no moment pair's first moment Y equals the luminance of "
                f"R,G,B (tried {tried})"
            )
    return AssembledBuffers(arrays, chosen, notes)
