"""The ``tungsten`` profile: Tungsten output as packaged for KPCN (Bako et al. 2017,
``tungsten.py``).

Colour ``R,G,B`` (pyexr's ``default``) or ``color.R/G/B``; ``albedo.R/G/B``, ``normal.R/G/B``,
``depth.Z``, ``diffuse.R/G/B``, ``specular.R/G/B``, ``visibility.Z``; variances
``<x>Variance.Z`` (1 channel, already the variance of the mean). The two half buffers that
Tungsten's ``two_buffer_variance`` writes (``colorA.R/G/B``/``colorB.R/G/B``, ``albedoA.R/G/B``,
``depthA.Z``, ...) are read as the canonical halves ``color_a``/``color_b``, ``albedo_a``/
``albedo_b``, ... (:data:`mcdenoise.io.buffers.HALF_NAMES`); their variances, where a file has
them, from ``<x>VarianceA.Z``/``<x>VarianceB.Z``. A file with only the ``A`` half is refused
on load (:func:`mcdenoise.io.buffers.check_halves`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from mcdenoise.io.buffers import HALF_SUFFIXES, VAR_SUFFIX
from mcdenoise.io.profiles.base import RGB, Alternatives, BufferSource, Profile, copied, layered

_TUNGSTEN_FEATURES = {
    "albedo": ("albedo", RGB),
    "normal": ("normal", RGB),
    "depth": ("depth", ("Z",)),
    "diffuse": ("diffuse", RGB),
    "specular": ("specular", RGB),
    "visibility": ("visibility", ("Z",)),
}


class TungstenProfile(Profile):
    """Tungsten / KPCN data (see the module docstring)."""

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
            "color": [copied(*RGB), BufferSource(layered("color", RGB))],
            "color_var": [copied("colorVariance.Z")],
        }
        for feat, (layer, suffixes) in _TUNGSTEN_FEATURES.items():
            alts[feat] = [BufferSource(layered(layer, suffixes))]
            alts[feat + VAR_SUFFIX] = [copied(f"{layer}Variance.Z")]
        for feat, (layer, suffixes) in {"color": ("color", RGB), **_TUNGSTEN_FEATURES}.items():
            for tag, half in zip("AB", HALF_SUFFIXES):
                alts[feat + half] = [BufferSource(layered(layer + tag, suffixes))]
                alts[feat + half + VAR_SUFFIX] = [copied(f"{layer}Variance{tag}.Z")]
        return alts
