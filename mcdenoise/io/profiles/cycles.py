"""The ``cycles`` profile: Blender multilayer EXR (header ``BlenderMultiChannel``).

Channels are ``<Layer>.<Pass>.<ch>`` (layer names may contain dots). Blender 5 writes one part
per pass (part ``<Layer>.<Pass>``) and its header attributes (``BlenderMultiChannel``,
``cycles.<Layer>.samples``) in part 0 only; :func:`mcdenoise.io.read_buffers` reads part 0's
attributes whatever part is chosen. Layer: ``profile="cycles:<Layer>"``, by default the first
layer with ``Noisy Image``, else the first non-``Composite`` layer with ``Combined``.
``spp`` from ``cycles.<Layer>.samples``. No variance.

What each pass holds, read in the Cycles source (``kernel/film/denoising_passes.h``,
``data_passes.h``, ``geom/primitive.h``) and measured on Blender 5.0.1 output
(``data/recipes/cycles/render_cycles.py``; docs/results/io-notes.md), and how it is mapped to
the canonical conventions of :mod:`mcdenoise.io.buffers`, preferred source first:

=============  ================================  ==============================================
buffer         pass                              convention -> canonical
=============  ================================  ==============================================
color          ``Noisy Image``, else ``Combined``  noisy radiance (``Combined`` is denoised when
                                                 Blender's denoiser ran: then ``Noisy Image``)
albedo         ``Denoising Albedo``              follows mirror-like bounces; lights seen
                                                 directly or in mirrors write their emission
                                                 (values far above 1): reported, kept
normal         ``Normal``                        world space, first hit, averaged: canonical
               ``Denoising Normal`` (fallback)   **camera space** (x right, y up, z into the
                                                 picture); no camera matrix in the file, so it
                                                 is kept and reported
depth          ``Denoising Depth``               distance along the ray, averaged, 0 where
                                                 the ray escapes: canonical (through mirror-like
                                                 bounces it continues to the next surface)
               ``Depth`` (fallback)              **planar** camera z of the first sample, 1e10
                                                 where the ray escapes: 1e10 -> 0, reported
position       ``Position``                      world space, first sample of the pixel, 0
                                                 where the ray escapes
motion         ``Vector.X``, ``Vector.Y``        previous - current position in pixels, y up:
                                                 canonical ``motion`` = (X, -Y)
motion_next    ``Vector.Z``, ``Vector.W``        current - next, y up: ``motion_next`` =
                                                 (-Z, W)
=============  ================================  ==============================================

A layer without denoising data therefore gets the world-space ``Normal`` like any other and
its planar ``Depth`` with a warning, never silently. Light passes (``Diffuse Direct`` ...)
are left unmapped (Cycles stores them divided by colour); multi-view files are not supported.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

from mcdenoise.io.profiles.base import (
    RGB,
    XYZ,
    Alternatives,
    BufferSource,
    Profile,
    ProfileError,
    copied,
    int_attribute,
    layered,
    shorten,
)

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
#: Header attribute Blender writes (in part 0) on every multilayer EXR.
BLENDER_ATTR = "BlenderMultiChannel"
#: Blender's ``Depth`` value where the camera ray escapes (``film_get_pass_pixel_depth``).
BLENDER_NO_HIT = 1e10
_ALBEDO_WHY = (
    "Cycles' Denoising Albedo holds the emission of lights seen directly or in mirror-like "
    "surfaces, not a reflectance"
)
_CAMERA_NORMAL = (
    "camera-space normals (Cycles' Denoising Normal: x right, y up, z into the picture), not "
    "world space; enable the Normal pass for world-space normals"
)
_PLANAR_DEPTH = (
    "planar depth (Cycles' Depth pass: distance to the camera plane, first sample of each "
    "pixel), not the distance along the ray; enable Denoising Data for that"
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
    """Blender Cycles multilayer EXR; ``layer`` picks a view layer (default: see the module
    docstring). The chosen layer is part of :attr:`label` (``cycles:<Layer>``)."""

    name = "cycles"
    description = "Blender Cycles multilayer EXR (<Layer>.<Pass>.<channel>)"

    def __init__(self, layer: str | None = None) -> None:
        self.layer = layer
        self._chosen: str | None = layer

    @property
    def label(self) -> str:
        return f"cycles:{self._chosen}" if self._chosen else "cycles"

    def detect(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> str | None:
        if BLENDER_ATTR in attributes:
            return f"header attribute {BLENDER_ATTR}"
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
            f"channels: {shorten(list(channels))}"
        )

    def propose(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> Alternatives:
        L = self.choose_layer(channels)
        self._chosen = L
        return {
            "color": [
                BufferSource(layered(f"{L}.Noisy Image", RGB)),
                BufferSource(layered(f"{L}.Combined", RGB)),
            ],
            "albedo": [
                BufferSource(
                    layered(f"{L}.Denoising Albedo", RGB),
                    expect_max=1.0,
                    expect_why=_ALBEDO_WHY,
                )
            ],
            "normal": [
                BufferSource(layered(f"{L}.Normal", XYZ)),
                BufferSource(layered(f"{L}.Denoising Normal", XYZ), note=_CAMERA_NORMAL),
            ],
            "depth": [
                copied(f"{L}.Denoising Depth.Z"),
                BufferSource((f"{L}.Depth.Z",), far=BLENDER_NO_HIT, note=_PLANAR_DEPTH),
            ],
            "position": [BufferSource(layered(f"{L}.Position", XYZ))],
            "motion": [BufferSource(layered(f"{L}.Vector", ("X", "Y")), scale=(1.0, -1.0))],
            "motion_next": [BufferSource(layered(f"{L}.Vector", ("Z", "W")), scale=(-1.0, 1.0))],
        }

    def header_spp(self, attributes: Mapping[str, Any]) -> tuple[int, str] | None:
        if self._chosen is None:
            return None
        key = f"cycles.{self._chosen}.samples"
        return int_attribute(attributes, key)
