"""The tuned parameters of the fixed filters, and the bandwidth rule for guide features.

:class:`XbfSettings` (cross-bilateral) and :class:`NlmSettings` (non-local means) are the
parameters of the ``cross-bilateral`` and ``nlm`` methods (every field a ``-p key=value``)
and the base bandwidths the learned Kalantari models multiply per pixel. Their defaults were
tuned on path-traced Mitsuba 3 renders at 4 and 16 spp, with and without feature variances
(``docs/results/methods-notes.md``). Besides the filter's own parameters each holds the
preparation choices of the pipeline: which guide ``features`` to use, whether to ``prefilter``
the noisy ones, whether to ``demodulate`` by the albedo (offset ``albedo_eps``), and what to do
with ``fireflies`` (``clamp``, ``keep-energy`` or ``off``; :mod:`mcdenoise.prep.fireflies`).

Guide features are in the units of the preparation layer (``prep/inputs.py``): albedo as it
is, unit normals, depth and position divided by the scene extent.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

from mcdenoise.errors import InputError

#: Guide features a filter may use, in order; those absent from the input are skipped.
GUIDE_FEATURES: tuple[str, ...] = ("albedo", "normal", "depth", "position")
#: Their variance buffers (``albedo_var``, ...), which the methods that use them list.
GUIDE_VARS: tuple[str, ...] = tuple(g + "_var" for g in GUIDE_FEATURES)
#: ``variance_prior`` of the ``cross-bilateral`` method (``-p variance_prior``;
#: :mod:`mcdenoise.prep.variance`, 2-8 spp): on the demo renders at 2 spp, after the firefly
#: clamp, relMSE 0.132 -> 0.038 on ``caustics_glass``, 0.026 -> 0.015 on ``cornell``
#: (``docs/results/bias.md``). XbfSettings keeps 0, the per-pixel estimate the learned
#: ``kalantari-xbf`` was trained with.
XBF_VARIANCE_PRIOR = 3.0


@dataclass(frozen=True)
class XbfSettings:
    """Parameters of the cross-bilateral denoiser.

    ``sigma_color`` is in noise units (the colour distance is variance-normalised). With
    ``passes=2`` a second pass recomputes the colour distances on the first pass's result
    (a far less noisy guide), with bandwidth ``sigma_color_refine``; it costs twice the
    filtering time. ``var_cap`` is κ of the colour distance's variance pair ``min(κ v_i, v_j)``
    (1: the plain minimum; the bias it costs is in ``docs/results/bias.md``).
    ``sigma_<feature>`` are feature bandwidths (see the module docstring).
    Where a feature variance is present, ``sigma_<feature>²`` becomes the floor of the
    variance normaliser (Kalantari 2015) and ``feature_scale`` the normalised bandwidth, so a
    noisy feature is trusted less and a clean one exactly as without variance.
    """

    kernel_size: int = 21
    sigma_spatial: float = 8.0
    sigma_color: float = 2.0
    passes: int = 1
    sigma_color_refine: float = 0.5
    sigma_albedo: float = 0.1
    sigma_normal: float = 0.3
    sigma_depth: float = 0.02
    sigma_position: float = 0.02
    feature_scale: float = 1.0
    feature_gradient: bool = False
    var_pair: str = "min"
    var_cap: float = 1.0
    demodulate: bool = True
    albedo_eps: float = 1e-2
    prefilter: bool = True
    features: tuple[str, ...] = GUIDE_FEATURES
    fireflies: str = "clamp"
    variance_prior: float = 0.0


@dataclass(frozen=True)
class NlmSettings:
    """Parameters of the non-local-means denoiser.

    ``k``, ``alpha``, ``search_radius``, ``patch_radius``, ``var_pair`` as in
    :func:`~mcdenoise.filters.nlm.non_local_means` (3×3 patches and α = 2, where Rousselle
    uses 7×7 and α = 4, because the variance estimates of a 16 spp render are noisy).
    ``var_cap`` is κ of the variance pair ``min(κ v_i, v_j)``: 1 here, the value the learned
    ``kalantari-nlm`` filter was trained with and reproduces; the ``nlm`` method runs with
    :data:`~mcdenoise.methods.nlm.VAR_CAP` (16), since with 1 it darkened the 4 spp samples
    by up to 2.8 % (``docs/results/bias.md``). Feature
    terms (Rousselle 2013) use ``sigma_<feature>²`` as the floor of their normaliser
    ``max(τ, var, |∇f|²)`` and ``feature_scale`` as ``k_f``. ``patch_trim``: see
    :func:`~mcdenoise.filters.nlm.non_local_means`; inf (off) here, what ``kalantari-nlm`` was
    trained with; the ``nlm`` method runs with :data:`~mcdenoise.methods.nlm.PATCH_TRIM`.
    ``variance_prior`` (0 here; the ``nlm`` method's 3) and ``fireflies``:
    :mod:`mcdenoise.prep.variance`, :mod:`mcdenoise.prep.fireflies`.
    """

    search_radius: int = 10
    patch_radius: int = 1
    k: float = 0.45
    alpha: float = 2.0
    var_pair: str = "min"
    var_cap: float = 1.0
    sigma_albedo: float = 0.1
    sigma_normal: float = 0.3
    sigma_depth: float = 0.02
    sigma_position: float = 0.02
    feature_scale: float = 1.0
    feature_gradient: bool = True
    combine: str = "min"
    demodulate: bool = True
    albedo_eps: float = 1e-2
    prefilter: bool = True
    features: tuple[str, ...] = GUIDE_FEATURES
    fireflies: str = "clamp"
    variance_prior: float = 0.0
    patch_trim: float = float("inf")


S = TypeVar("S", XbfSettings, NlmSettings)


def with_overrides(settings: S, overrides: Mapping[str, Any]) -> S:
    """``settings`` with fields replaced by ``overrides``; an unknown name is an InputError."""
    names = {f.name for f in dataclasses.fields(settings)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise InputError(
            f"unknown setting(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}"
        )
    return dataclasses.replace(settings, **overrides)


def feature_bandwidths(
    s: XbfSettings | NlmSettings, guides: Sequence[str], with_var: Sequence[str]
) -> tuple[dict[str, float], dict[str, float]]:
    """Per-guide (bandwidth, normaliser floor) of the fixed filters.

    The distance is ``Δ² / σ_k²`` where the feature is clean, and ``Δ² / var`` where its
    variance (or, with ``feature_gradient``, its squared gradient) exceeds the floor ``σ_k²``;
    a normalised distance then gets the bandwidth ``feature_scale``.
    """
    raw = {
        "albedo": s.sigma_albedo,
        "normal": s.sigma_normal,
        "depth": s.sigma_depth,
        "position": s.sigma_position,
    }
    sig: dict[str, float] = {}
    floors: dict[str, float] = {}
    for name in guides:
        floors[name] = raw[name] ** 2
        normalised = name in with_var or s.feature_gradient
        sig[name] = s.feature_scale if normalised else s.feature_scale * raw[name]
    return sig, floors


def filter_radius(s: XbfSettings | NlmSettings) -> int:
    """Pixels of context one filtered pixel depends on (window, patches, feature gradients)."""
    grad = 1 if s.feature_gradient else 0
    if isinstance(s, XbfSettings):
        return s.passes * (s.kernel_size // 2) + grad
    return s.search_radius + s.patch_radius + grad


__all__ = [
    "GUIDE_FEATURES",
    "GUIDE_VARS",
    "XBF_VARIANCE_PRIOR",
    "NlmSettings",
    "XbfSettings",
    "feature_bandwidths",
    "filter_radius",
    "with_overrides",
]
