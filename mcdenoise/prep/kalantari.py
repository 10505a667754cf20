"""The Kalantari models' inputs from a FeatureBuffers: per-pixel features (Kalantari, Bako, Sen
2015, section 4) and the prepared item a model filters (:func:`prepare_item`).

The features describe, at every pixel, what the filter is about to average: how noisy the
colour is, how much the scene's geometry and texture vary around it, and how many samples
there are. They are computed from :class:`~mcdenoise.prep.inputs.FilterInputs` (sanitised,
normalised, prefiltered buffers) and the demodulated irradiance the filter sees, on the
*whole image*, so a training patch sees exactly the values inference computes.

Primary features (Kalantari 2015: screen position, colour, world position, shading normal,
texture value of the first hit; the second-bounce texture and direct-light visibility are not
in mcdenoise's data and are left out):

=====================  ================================================================
``screen.x/y``         pixel centre / image size, [0, 1]
``color.r/g/b``        ``log1p`` of the demodulated irradiance
``<guide>.<ch>``       each guide feature present (albedo r/g/b, normal x/y/z, depth,
                       position x/y/z over the scene extent, as the filter sees them)
=====================  ================================================================

Secondary features (Kalantari 2015 computes means, standard deviations, gradients and the
mean absolute deviation of the primary ones over small blocks, and the sample count):

=========================  ============================================================
``lum.mean.w``             local mean of the log-luminance over a ``w × w`` window
``lum.std.w``              its local standard deviation (w = 3, 7, 21)
``<guide>.std.w``          local standard deviation of a guide (channel mean), w = 3, 7, 21
``lum.grad``, ``<guide>.grad``   gradient magnitude (central differences, channel mean)
``lum.mad``                mean absolute deviation of the log-luminance over 3 × 3
``color.relvar``           ``log`` of the colour's relative variance of the mean
                           ``v / (L² + 10⁻⁴)`` -- the noise level the filter must remove
``<guide>.var``            ``log(10⁻⁶ + variance of the mean)`` of a guide that has one
``spp``                    ``log2(spp)`` (the training mean when the input does not say)
=========================  ============================================================

Regional features (``regional=True``; not in the paper): the means over a ``63 × 63`` window
(:data:`~mcdenoise.models.features.REGION`) of ``color.relvar``, ``lum.std.7``, ``lum.grad`` and each ``<guide>.grad``,
named ``region.relvar``, ``region.lum.std``, ``region.lum.grad``, ``region.<guide>.grad``. A
pixel's own statistics are noisy estimates of how noisy and how detailed its surroundings
are; averaged over a region they are precise, and a filter's best bandwidths vary slowly
across an image (fitted per 16×16 block they reach most of what per-pixel fits reach;
``docs/results/``). The shipped cross-bilateral model uses them.

The ordered names depend only on which guides are present
(:func:`~mcdenoise.models.features.feature_names`, which the model stores and checks with its
normalisation statistics); :func:`compute_features` returns its channels in that order.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from mcdenoise.filters.box import box_mean
from mcdenoise.filters.settings import GUIDE_FEATURES, NlmSettings, XbfSettings
from mcdenoise.io.buffers import FeatureBuffers, MissingFeatureError
from mcdenoise.models.features import REGION, WINDOWS, feature_names
from mcdenoise.models.kalantari import ModelCard
from mcdenoise.prep.inputs import FilterInputs, demodulate_inputs, prepare_inputs

#: Raw features of rows ``[y0, y1)`` of a prepared item (:func:`item_features`).
FeatureFn = Callable[[int, int], Tensor]


def _local_std(x: Tensor, w: int) -> Tensor:
    """Channel-mean local standard deviation ``(B, 1, H, W)`` over ``w × w``."""
    m = box_mean(x, w // 2)
    v = (box_mean(x * x, w // 2) - m * m).clamp_min(0)
    return v.mean(1, keepdim=True).sqrt()


def _grad(x: Tensor) -> Tensor:
    """Channel-mean gradient magnitude by central differences (replicate border)."""
    p = F.pad(x, (1, 1, 1, 1), mode="replicate")
    gx = (p[..., 1:-1, 2:] - p[..., 1:-1, :-2]) * 0.5
    gy = (p[..., 2:, 1:-1] - p[..., :-2, 1:-1]) * 0.5
    return (gx.square() + gy.square()).mean(1, keepdim=True).sqrt()


def _mad3(x: Tensor) -> Tensor:
    """Mean absolute deviation from the 3×3 mean, ``(B, 1, H, W)``."""
    m = box_mean(x, 1)
    h, w = x.shape[-2:]
    p = F.pad(x, (1, 1, 1, 1), mode="replicate")
    dev = [(p[..., dy : dy + h, dx : dx + w] - m).abs() for dy in range(3) for dx in range(3)]
    return torch.stack(dev).mean(0).mean(1, keepdim=True)


#: Rows of context the features of a row depend on: the regional mean (``REGION // 2``) of a
#: local statistic (at most ``max(WINDOWS) // 2``, or 2 for the 3×3 MAD and the gradients).
FEATURE_HALO = REGION // 2 + max(max(WINDOWS) // 2, 2)


def compute_features(
    inp: FilterInputs,
    irradiance: Tensor,
    irradiance_var: Tensor,
    spp: float | None,
    *,
    regional: bool = False,
    rows: tuple[int, int] | None = None,
) -> tuple[Tensor, list[str]]:
    """Raw (un-normalised) features ``(1, F, H, W)`` and their names.

    Args:
        inp: prepared filter inputs of one image (batch 1).
        irradiance: ``(1, 3, H, W)`` what the filter averages (demodulated colour, or colour).
        irradiance_var: ``(1, 1, H, W)`` its variance of the mean.
        spp: samples per pixel, or ``None`` when unknown (the ``spp`` feature is then NaN and
            :meth:`~mcdenoise.models.features.FeatureStats.normalize` replaces it by the training mean).
        regional: also the regional means (see the module docstring).
        rows: only the rows ``[y0, y1)`` (``(1, F, y1 - y0, W)``), computed from those rows
            and :data:`FEATURE_HALO` rows of context on each side: the same values as the
            whole image's, with memory for a band only.
    """
    guides = [g for g in GUIDE_FEATURES if g in inp.features]
    with_vars = [g for g in guides if g in inp.feature_vars]
    feats = guide_features(
        {g: inp.features[g] for g in guides},
        {g: inp.feature_vars[g] for g in with_vars},
        irradiance,
        irradiance_var,
        spp,
        regional=regional,
        rows=rows,
    )
    return feats, feature_names(guides, with_vars, regional)


def guide_features(
    guides: Mapping[str, Tensor],
    guide_vars: Mapping[str, Tensor],
    irradiance: Tensor,
    irradiance_var: Tensor,
    spp: float | None,
    *,
    regional: bool = False,
    rows: tuple[int, int] | None = None,
) -> Tensor:
    """:func:`compute_features` from the prepared guides ``(1, C, H, W)`` (name -> tensor, in
    :data:`GUIDE_FEATURES` order) and the variances of those the model uses."""
    _, _, h, w = irradiance.shape
    y0, y1 = rows if rows is not None else (0, h)
    if not 0 <= y0 < y1 <= h:
        raise ValueError(f"rows {rows} outside the image's {h} rows")
    # The band and its context; outputs are cropped back to [y0, y1) at the end.
    c0, c1 = max(0, y0 - FEATURE_HALO), min(h, y1 + FEATURE_HALO)
    if (c0, c1) != (0, h):
        irradiance = irradiance[..., c0:c1, :]
        irradiance_var = irradiance_var[..., c0:c1, :]
        guides = {g: f[..., c0:c1, :] for g, f in guides.items()}
        guide_vars = {g: v[..., c0:c1, :] for g, v in guide_vars.items()}
    dt, dev = irradiance.dtype, irradiance.device
    ys = (
        torch.linspace(0, 1, h, dtype=dt, device=dev)
        if h > 1
        else torch.zeros(1, dtype=dt, device=dev)
    )[c0:c1]
    xs = (
        torch.linspace(0, 1, w, dtype=dt, device=dev)
        if w > 1
        else torch.zeros(1, dtype=dt, device=dev)
    )
    sy, sx = torch.meshgrid(ys, xs, indexing="ij")
    color = torch.log1p(irradiance.clamp_min(0))
    lum_lin = irradiance.clamp_min(0).mean(1, keepdim=True)
    lum = torch.log1p(lum_lin)
    names = [g for g in GUIDE_FEATURES if g in guides]
    chans: list[Tensor] = [sx[None, None], sy[None, None], color]
    chans += [guides[g] for g in names]
    lum_std = [_local_std(lum, k) for k in WINDOWS]
    chans += [box_mean(lum, k // 2) for k in WINDOWS] + lum_std
    for g in names:
        chans += [_local_std(guides[g], k) for k in WINDOWS]
    grads = [_grad(lum)] + [_grad(guides[g]) for g in names]
    chans += grads
    chans += [_mad3(lum)]
    relvar = torch.log((irradiance_var + 1e-12) / (lum_lin.square() + 1e-4))
    chans += [relvar]
    chans += [
        torch.log(guide_vars[g].mean(1, keepdim=True) + 1e-6) for g in names if g in guide_vars
    ]
    s = math.log2(spp) if spp else math.nan
    chans += [torch.full_like(lum, s)]
    if regional:
        r = REGION // 2
        chans += [box_mean(x, r) for x in [relvar, lum_std[WINDOWS.index(7)], *grads]]
    if (c0, c1) != (y0, y1):
        chans = [x[..., y0 - c0 : y1 - c0, :] for x in chans]
    feats = torch.cat(chans, dim=1)
    del chans
    expected = len(feature_names(names, [g for g in names if g in guide_vars], regional))
    if feats.shape[1] != expected:  # a programming error, not an input error
        raise AssertionError(f"{feats.shape[1]} feature channels for {expected} names")
    return feats


def item_features(item: Mapping[str, Tensor], spp: float | None, *, regional: bool) -> FeatureFn:
    """The features of a prepared item (:func:`prepare_item` with ``features=False``) as a
    function of the rows: ``fn(y0, y1) -> (1, F, y1 - y0, W)``, equal to those rows of
    :func:`compute_features` (what ``features=True`` stores)."""
    guides = {g: item[f"feat.{g}"][None] for g in GUIDE_FEATURES if f"feat.{g}" in item}
    gvars = {g: item[f"fvar.{g}"][None] for g in guides if f"fvar.{g}" in item}
    irr, var = item["irr"][None], item["irr_var"][None]

    def rows(y0: int, y1: int) -> Tensor:
        return guide_features(guides, gvars, irr, var, spp, regional=regional, rows=(y0, y1))

    return rows


def check_inputs(card: ModelCard, buffers: FeatureBuffers) -> None:
    """Refuse buffers without a guide (or guide variance) the model was trained with."""
    missing = [g for g in card.guides if g not in buffers]
    missing += [f"{g}_var" for g in card.guide_vars if g in buffers and f"{g}_var" not in buffers]
    if missing:
        raise MissingFeatureError(
            missing,
            sorted(buffers.buffers),
            source=buffers.source,
            needed_by=f"this Kalantari {card.kind} model (trained with {', '.join(card.guides)};"
            " use the fixed filters nlm or cross-bilateral for such inputs)",
        )


def prepare_item(
    buffers: FeatureBuffers,
    kind: str,
    settings: XbfSettings | NlmSettings,
    guides: Sequence[str],
    reference: Tensor | None = None,
    guide_vars: Sequence[str] | None = None,
    *,
    regional: bool = False,
    features: bool = True,
    fireflies: str | None = None,
    variance_prior: float | None = None,
    variance_prior_max_spp: float | None = None,
) -> dict[str, Tensor]:
    """Filter inputs and raw features of one image, ``{name: (C, H, W)}``.

    ``guide_vars``: use the variances of these guides only (``None``: every one present), so
    an input with more buffers than a model was trained with is seen as the model expects.
    ``fireflies``: the firefly handling (:mod:`mcdenoise.prep.fireflies`), default the
    settings' own; ``variance_prior``: the low-spp variance (:mod:`mcdenoise.prep.variance`),
    default the settings' own (0: the per-pixel estimate the shipped models were trained with),
    applied up to ``variance_prior_max_spp`` samples per pixel (``None``: prepare_inputs').

    Keys: ``color`` (sanitised noisy colour), ``irr``/``irr_var`` (what the filter averages and
    its variance), ``factor`` (remodulation, ones without albedo), ``feat.<g>``/``fvar.<g>``
    (guides as :func:`~mcdenoise.prep.inputs.prepare_inputs` normalises them; a variance as
    its channel mean, ``(1, H, W)``), ``features``
    (raw features; not with ``features=False``: :func:`item_features` computes them a band
    of rows at a time, the same values without an ``F × H × W`` tensor), and ``reference`` when
    given.
    """
    inp: FilterInputs = prepare_inputs(
        buffers,
        features=tuple(guides),
        prefilter=settings.prefilter,
        fireflies=settings.fireflies if fireflies is None else fireflies,
        variance_prior=settings.variance_prior if variance_prior is None else variance_prior,
        **(
            {}
            if variance_prior_max_spp is None
            else {"variance_prior_max_spp": variance_prior_max_spp}
        ),
    )
    missing = [g for g in guides if g not in inp.features]
    if missing:  # e.g. position present but no usable scene extent
        raise MissingFeatureError(
            missing, sorted(buffers.buffers), source=buffers.source, needed_by="the Kalantari model"
        )
    if guide_vars is not None:
        inp.feature_vars = {g: v for g, v in inp.feature_vars.items() if g in guide_vars}
    irr, var, factor = demodulate_inputs(inp, enabled=settings.demodulate, eps=settings.albedo_eps)
    out = {
        "color": inp.color[0],
        "irr": irr[0],
        "irr_var": var[0],
        "factor": (factor if factor is not None else torch.ones_like(irr))[0],
    }
    if features:
        out["features"] = compute_features(inp, irr, var, buffers.spp, regional=regional)[0][0]
    for g in guides:
        out[f"feat.{g}"] = inp.features[g][0]
        if g in inp.feature_vars:  # the channel mean: all that the features and filters use
            out[f"fvar.{g}"] = inp.feature_vars[g].mean(dim=1, keepdim=True)[0]
    if reference is not None:
        out["reference"] = reference
    return out


def prepare_for_model(
    card: ModelCard,
    buffers: FeatureBuffers,
    reference: Tensor | None = None,
    *,
    features: bool = True,
    fireflies: str | None = None,
    variance_prior: float | None = None,
    variance_prior_max_spp: float | None = None,
) -> dict[str, Tensor]:
    """The item :meth:`~mcdenoise.models.kalantari.KalantariModel.filter` needs for one image
    (:func:`prepare_item` with the model's kind, settings, guides and guide variances;
    ``features=False``: without the features, see :func:`item_features`; ``fireflies``:
    the firefly handling, default the model's settings', :mod:`mcdenoise.prep.fireflies`;
    ``variance_prior``: likewise, :mod:`mcdenoise.prep.variance`).

    Raises:
        MissingFeatureError: the image lacks a guide the model was trained with.
    """
    check_inputs(card, buffers)
    return prepare_item(
        buffers,
        card.kind,
        card.filter_settings(),
        card.guides,
        reference,
        card.guide_vars,
        regional=card.regional,
        features=features,
        fireflies=fireflies,
        variance_prior=variance_prior,
        variance_prior_max_spp=variance_prior_max_spp,
    )


__all__ = [
    "FEATURE_HALO",
    "FeatureFn",
    "check_inputs",
    "compute_features",
    "guide_features",
    "item_features",
    "prepare_for_model",
    "prepare_item",
]
