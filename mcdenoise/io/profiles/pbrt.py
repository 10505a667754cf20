"""The ``pbrt`` profile: pbrt-v4's ``gbuffer`` film (``GBufferFilm::GetImage``).

Colour ``R,G,B``; albedo ``Albedo.R/G/B``; normal ``Ns.X/Y/Z`` (shading; ``N.*`` is geometric
and stays unmapped); position ``P.X/Y/Z``; depth = ``P.Z`` (camera-space z: planar depth,
valid for the default ``coordinatesystem "camera"``); both differ from the canonical
conventions (world position, depth along the ray) and are reported on load (not checked on a
real pbrt render: none can be installed here). Older pbrt-v4 names ``Px``, ``Nsx``...
are accepted. ``Variance.R/G/B`` is the *per-sample* variance ``S/(n-1)`` of pbrt's
``VarianceEstimator``, accumulated in *sensor* RGB, which for the default ``cie1931`` sensor
is CIE XYZ; so ``color_var`` = ``Variance.G / spp`` as a 1-channel luminance variance of the
mean (pbrt counts only samples that hit a surface, so background pixels are approximate).
``spp`` from the ``samplesPerPixel`` attribute pbrt writes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from mcdenoise.io.profiles.base import (
    RGB,
    Alternatives,
    BufferSource,
    Profile,
    copied,
    int_attribute,
)

_CAMERA_POSITION = (
    'pbrt\'s P is camera space by default (gbuffer film coordinatesystem "camera"), not world space'
)
_PLANAR_DEPTH = "planar depth (pbrt's P.Z, camera z), not the distance along the ray"


class PbrtProfile(Profile):
    """pbrt-v4 ``gbuffer`` film output (see the module docstring)."""

    name = "pbrt"
    description = "pbrt-v4 gbuffer film (R,G,B; Albedo.*; Ns.*; P.*; Variance.*)"

    def detect(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> str | None:
        for c in ("Ns.X", "Nsx", "Albedo.R", "Variance.R", "RelativeVariance.R", "dzdx"):
            if c in channels:
                return f"pbrt-v4 gbuffer channel {c!r}"
        return None

    def propose(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> Alternatives:
        return {
            "color": [copied(*RGB)],
            "albedo": [copied("Albedo.R", "Albedo.G", "Albedo.B")],
            "normal": [copied("Ns.X", "Ns.Y", "Ns.Z"), copied("Nsx", "Nsy", "Nsz")],
            "position": [
                BufferSource(("P.X", "P.Y", "P.Z"), note=_CAMERA_POSITION),
                BufferSource(("Px", "Py", "Pz"), note=_CAMERA_POSITION),
            ],
            "depth": [
                BufferSource(("P.Z",), note=_PLANAR_DEPTH),
                BufferSource(("Pz",), note=_PLANAR_DEPTH),
            ],
            "color_var": [BufferSource(("Variance.G",), "per_sample")],
        }

    def header_spp(self, attributes: Mapping[str, Any]) -> tuple[int, str] | None:
        return int_attribute(attributes, "samplesPerPixel")
