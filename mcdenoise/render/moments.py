"""Film moments -> feature buffers with per-pixel variances of the mean.

Every buffer of one render comes from ONE Mitsuba render call: a ``moment`` integrator nests an
``aov`` integrator (the plan's feature buffers) which nests the plan's radiance integrator, on
an ``hdrfilm`` with a ``box`` reconstruction filter and an ``independent`` sampler
(:func:`moment_integrator` builds the dict; the scene builder adds film and sampler). With a box
filter every sample lands in exactly one pixel with weight 1, so the developed film holds, per
pixel and channel, the plain sample mean ``m1`` and (``m2_*`` channels of ``moment``) the mean
of the squares ``m2``. The unbiased variance of the mean of ``n`` i.i.d. samples is then

    var = n/(n-1) * (m2 - m1²) / n = (m2 - m1²) / (n - 1)

(``/ n`` instead would be low by ``(n-1)/n``, 25 % at 4 spp), clamped at 0 where float32
round-off makes it slightly negative, and 0 when ``n == 1`` (no estimate possible).

Renders with distinct seeds are independent sample sets: :meth:`Moments.merge` pools them
(spp-weighted means of ``m1`` and ``m2``, float64), which is how the spp levels are rendered
progressively and how a high-spp reference is rendered in bounded-memory passes.

Half buffers (:func:`buffers_from_halves`): the moments of two disjoint sample streams A
and B (rendered with distinct seeds, :func:`~mcdenoise.render.jobs.half_level_passes`) give
``color_a``, ``color_b`` (and feature halves) with their variances of the mean; when both
halves hold the same number of samples the full buffer is written as the mean of the two
float32 halves, so ``color == (color_a + color_b) / 2`` holds bit for bit in float32 (the
float64 sum of two float32 values is exact, halving is exact, and one rounding to float32 is
what float32 ``(a + b) / 2`` does too); its variance comes from the pooled moments.

Channels are looked up in the film by NAME (:func:`film_channels`), never by position.
Arrays are float64 ``(C, H, W)`` while accumulating; :func:`buffers_from_moments` returns a
float32 :class:`~mcdenoise.io.buffers.FeatureBuffers` (colour: linear HDR RGB, Rec.709
primaries; normal and position in world space; depth = distance along the camera ray, 0 where
the ray escapes).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from mcdenoise.errors import InputError
from mcdenoise.io.buffers import HALF_SUFFIXES, VAR_SUFFIX, FeatureBuffers

#: Feature buffer -> Mitsuba ``aov`` type that produces it.
AOV_TYPES: dict[str, str] = {
    "albedo": "albedo",
    "normal": "sh_normal",
    "depth": "depth",
    "position": "position",
}
#: Channel suffixes Mitsuba gives each AOV type's output (``<aov>.<suffix>``).
_SUFFIXES: dict[str, tuple[str, ...]] = {
    "albedo": ("R", "G", "B"),
    "normal": ("X", "Y", "Z"),
    "depth": ("T",),
    "position": ("X", "Y", "Z"),
}
#: Names given to the nested integrators; they prefix the film's channel names
#: (``inner.radiance.R``, ``inner.albedo.R``, ``m2_inner.radiance.R``, ...).
AOV_NAME = "inner"
RADIANCE_NAME = "radiance"
#: Prefix of the ``moment`` integrator's second-moment channels.
M2_PREFIX = "m2_"


def _check_features(features: Sequence[str]) -> tuple[str, ...]:
    unknown = [f for f in features if f not in AOV_TYPES]
    if unknown:
        raise InputError(
            f"no Mitsuba AOV for feature(s) {', '.join(unknown)}; known: {', '.join(AOV_TYPES)}"
        )
    if len(set(features)) != len(features):
        raise InputError(f"features listed twice: {list(features)}")
    return tuple(features)


def moment_integrator(radiance: Mapping[str, Any], features: Sequence[str]) -> dict[str, Any]:
    """The ``moment`` -> ``aov`` (``features``) -> ``radiance`` integrator dict.

    >>> d = moment_integrator({"type": "path", "max_depth": 2}, ["albedo", "depth"])
    >>> d["inner"]["aovs"], d["inner"]["radiance"]["type"]
    ('albedo:albedo,depth:depth', 'path')
    """
    feats = _check_features(features)
    aov: dict[str, Any] = {"type": "aov", RADIANCE_NAME: dict(radiance)}
    if feats:
        aov["aovs"] = ",".join(f"{f}:{AOV_TYPES[f]}" for f in feats)
    return {"type": "moment", AOV_NAME: aov}


def film_channels(features: Sequence[str]) -> dict[str, tuple[str, ...]]:
    """Buffer name -> the film channels of its first moment (``color`` first).

    >>> film_channels(["depth"])
    {'color': ('inner.radiance.R', 'inner.radiance.G', 'inner.radiance.B'), 'depth': ('inner.depth.T',)}
    """
    out = {"color": tuple(f"{AOV_NAME}.{RADIANCE_NAME}.{c}" for c in "RGB")}
    for f in _check_features(features):
        out[f] = tuple(f"{AOV_NAME}.{f}.{s}" for s in _SUFFIXES[f])
    return out


@dataclass
class Moments:
    """Per-pixel first and second sample moments of ``spp`` i.i.d. samples per pixel.

    ``m1[name]`` and ``m2[name]`` are float64 ``(C, H, W)``: the means of the samples and of
    their squares, for ``color`` and each feature buffer.
    """

    m1: dict[str, np.ndarray]
    m2: dict[str, np.ndarray]
    spp: int

    def merge(self, other: Moments) -> Moments:
        """The moments of the union of both (independent) sample sets."""
        if set(self.m1) != set(other.m1):
            raise InputError(
                f"cannot merge moments of different buffers: {sorted(self.m1)} vs {sorted(other.m1)}"
            )
        n = self.spp + other.spp
        a, b = self.spp / n, other.spp / n
        return Moments(
            {k: a * self.m1[k] + b * other.m1[k] for k in self.m1},
            {k: a * self.m2[k] + b * other.m2[k] for k in self.m2},
            n,
        )


def moments_from_film(
    names: Sequence[str], pixels: np.ndarray, features: Sequence[str], spp: int
) -> Moments:
    """Moments from a developed film: channel ``names`` and ``pixels`` ``(H, W, C)``.

    Raises:
        InputError: a needed channel is missing (the message lists what the film has).
    """
    index = {n: i for i, n in enumerate(names)}
    chans = film_channels(features)
    missing = [
        p + c for cs in chans.values() for c in cs for p in ("", M2_PREFIX) if p + c not in index
    ]
    if missing:
        raise InputError(
            f"the film has no channel(s) {', '.join(missing)}; it has {', '.join(names)}"
        )
    m1 = {
        b: np.stack([pixels[..., index[c]] for c in cs]).astype(np.float64)
        for b, cs in chans.items()
    }
    m2 = {
        b: np.stack([pixels[..., index[M2_PREFIX + c]] for c in cs]).astype(np.float64)
        for b, cs in chans.items()
    }
    return Moments(m1, m2, spp)


def render_moments(scene: Any, spp: int, seed: int, features: Sequence[str]) -> Moments:
    """Render ``scene`` (integrator from :func:`moment_integrator`) once with ``spp`` samples
    per pixel and sampler ``seed``; return the moments of colour and ``features``."""
    import mitsuba as mi  # lazy: Mitsuba is optional and slow to import

    if spp < 1:
        raise InputError(f"spp must be >= 1, got {spp}")
    mi.render(scene, spp=spp, seed=seed)
    bitmap = scene.sensors()[0].film().bitmap(raw=False)
    struct = bitmap.struct_()
    names = [struct[i].name for i in range(bitmap.channel_count())]
    pixels = np.array(bitmap, dtype=np.float32, copy=True)
    return moments_from_film(names, pixels, features, spp)


def variance_of_mean(m1: np.ndarray, m2: np.ndarray, spp: int) -> np.ndarray:
    """``max(0, (m2 - m1²) / (spp - 1))``; zeros when ``spp == 1``."""
    if spp <= 1:
        return np.zeros_like(m1)
    return np.maximum((m2 - m1 * m1) / (spp - 1), 0.0)


def buffers_from_moments(
    moments: Moments, attributes: Mapping[str, Any] | None = None
) -> FeatureBuffers:
    """Each buffer's mean and ``<name>_var`` (variance of the mean) as float32 ``(C, H, W)``.

    ``spp`` of the result is ``moments.spp``; ``attributes`` are copied onto it.
    """
    buffers: dict[str, torch.Tensor] = {}
    for name, m1 in moments.m1.items():
        var = variance_of_mean(m1, moments.m2[name], moments.spp)
        buffers[name] = torch.from_numpy(m1.astype(np.float32))
        buffers[name + VAR_SUFFIX] = torch.from_numpy(var.astype(np.float32))
    return FeatureBuffers(buffers, spp=moments.spp, attributes=dict(attributes or {}))


def buffers_from_halves(
    a: Moments | None,
    b: Moments | None,
    halve: Sequence[str] = ("color",),
    attributes: Mapping[str, Any] | None = None,
) -> FeatureBuffers:
    """The buffers of the union of the sample sets ``a`` and ``b``, with the halves of the
    buffers named in ``halve`` when both hold the same number of samples.

    Every half gets its variance of the mean (``color_a_var``, ``albedo_b_var``). Where halves
    are written,
    the full buffer is their float32 mean (module docstring) and its variance comes from the
    pooled moments. ``a`` or ``b`` may be ``None`` (a level of 1 spp): the other alone, no
    halves.
    """
    if a is None or b is None:
        only = a if b is None else b
        if only is None:
            raise InputError("buffers_from_halves needs at least one half")
        return buffers_from_moments(only, attributes)
    out = buffers_from_moments(a.merge(b), attributes)
    if a.spp != b.spp:
        return out
    for name in halve:
        if name not in a.m1:
            continue
        ha = a.m1[name].astype(np.float32)
        hb = b.m1[name].astype(np.float32)
        mean = (ha.astype(np.float64) + hb.astype(np.float64)) / 2
        out[name] = torch.from_numpy(mean.astype(np.float32))
        out[name + HALF_SUFFIXES[0]] = torch.from_numpy(ha)
        out[name + HALF_SUFFIXES[1]] = torch.from_numpy(hb)
        for half, m in zip(HALF_SUFFIXES, (a, b)):
            var = variance_of_mean(m.m1[name], m.m2[name], m.spp)
            out[name + half + VAR_SUFFIX] = torch.from_numpy(var.astype(np.float32))
    return out
