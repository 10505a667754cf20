"""The ``cycles`` profile: Blender multilayer EXR (header ``BlenderMultiChannel``).

Channels are ``<Layer>.<Pass>.<ch>`` (layer names may contain dots). Colour
``Noisy Image.R/G/B`` (preferred) else ``Combined.R/G/B``; albedo ``Denoising Albedo.R/G/B``;
normal ``Denoising Normal.X/Y/Z`` else ``Normal.X/Y/Z``; depth ``Denoising Depth.Z`` else
``Depth.Z`` (Cycles' Z is planar camera depth, not Mitsuba's distance along the ray);
position ``Position.X/Y/Z``. No variance. Layer: ``profile="cycles:<Layer>"``, by default the
first layer with ``Noisy Image``, else the first non-``Composite`` layer with ``Combined``.
``spp`` from the ``cycles.<Layer>.samples`` attribute Blender stamps. Light passes
(``Diffuse Direct`` ...) are left unmapped (Cycles stores them divided by colour); multi-view
files are not supported.
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
            "albedo": [BufferSource(layered(f"{L}.Denoising Albedo", RGB))],
            "normal": [
                BufferSource(layered(f"{L}.Denoising Normal", XYZ)),
                BufferSource(layered(f"{L}.Normal", XYZ)),
            ],
            "depth": [copied(f"{L}.Denoising Depth.Z"), copied(f"{L}.Depth.Z")],
            "position": [BufferSource(layered(f"{L}.Position", XYZ))],
        }

    def header_spp(self, attributes: Mapping[str, Any]) -> tuple[int, str] | None:
        if self._chosen is None:
            return None
        key = f"cycles.{self._chosen}.samples"
        return int_attribute(attributes, key)
