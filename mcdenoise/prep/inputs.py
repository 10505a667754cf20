"""From a :class:`~mcdenoise.io.buffers.FeatureBuffers` to sanitised, normalised filter inputs.

:func:`prepare_inputs` sanitises the buffers (:func:`mcdenoise.io.buffers.sanitize`), normalises
the guide features to comparable scales and picks up the variances that are present:

* ``albedo`` as it is (reflectance, usually [0, 1], up to ~10 on glossy lobes in Mitsuba);
  ``normal`` as it is (unit vectors, [-1, 1]);
* ``depth`` and ``position`` divided by the scene extent (the diagonal of the robust bounding
  box of the first-hit positions, or the robust maximum depth), so that 1 means "across the
  scene"; their variances by the extent squared;
* features that come with a variance are **prefiltered** (variance-normalised NLM, 11×11
  window), as in Rousselle et al. 2013: a defocused or motion-blurred feature is as noisy as
  the colour and would otherwise imprint that noise on the result (with ``variance_prior``,
  at a few samples per pixel, steered by :func:`low_spp_prefilter_variance`); with
  ``estimate_missing=True`` a feature *without* a variance buffer (a Mitsuba ``aov`` file,
  Cycles) is prefiltered the same way with a variance estimated from its own neighbourhood
  (:func:`estimate_feature_variance`), at most what the colour's noise allows
  (:func:`feature_noise_cap`);
* ``color_var`` (variance of the mean) is averaged over channels and made robust with
  ``max(v, median_3×3(v))``: from a few samples the variance estimate is itself very noisy, and
  a pixel whose estimate came out near 0 would otherwise refuse all its neighbours. Without a
  ``color_var`` (or with one that cannot be right: 1 spp, or all zero) the variance is
  estimated from the colour (:func:`estimate_variance`) and
  :attr:`FilterInputs.estimated_variance` says so.

:func:`demodulate_inputs` then divides the colour by the (prefiltered) albedo when there is
one (:mod:`mcdenoise.filters.albedo`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.albedo import ALBEDO_EPS, demodulate, demodulated_variance
from mcdenoise.filters.box import box_mean, median3
from mcdenoise.filters.nlm import non_local_means
from mcdenoise.filters.settings import GUIDE_FEATURES, NlmSettings, XbfSettings, feature_bandwidths
from mcdenoise.io.buffers import FeatureBuffers, sanitize
from mcdenoise.prep.fireflies import check_mode, remove_fireflies
from mcdenoise.prep.variance import MAX_SPP, low_spp_variance

#: NLM settings of the feature prefilter (variance-normalised, paper denominator ``v_i + v_j``).
PREFILTER = {"search_radius": 5, "patch_radius": 3, "k": 1.0, "alpha": 1.0, "var_pair": "sum"}
#: The same for a feature whose variance is estimated (:func:`estimate_feature_variance`):
#: 3×3 patches in a 7×7 window. Measured with kpcn on the ``basic`` source
#: (docs/results/kpcn.md, "Out of distribution"): on a defocused 4-spp albedo 7×7 patches
#: leave 1.4× the error; the 11×11 window gains 1 % at 4 spp for 2.5× the time.
PREFILTER_ESTIMATED = {**PREFILTER, "patch_radius": 1, "search_radius": 3}


@dataclass
class FilterInputs:
    """Sanitised, normalised tensors for the filters, all ``(1, C, H, W)``.

    Attributes:
        color: noisy linear HDR RGB colour, sanitised (NaN -> 0, clamped at 0).
        color_var: ``(1, 1, H, W)`` robust variance of the mean of ``color`` (channel mean):
            from the buffers, or estimated from the colour when :attr:`estimated_variance`.
        features: name -> normalised (and, where a variance exists, prefiltered) guide feature,
            in :data:`~mcdenoise.filters.settings.GUIDE_FEATURES` order, only those present.
        feature_vars: name -> normalised variance of the mean of the raw feature, when present.
        albedo: albedo ``(1, 3, H, W)`` for demodulation (prefiltered when it has a variance),
            or ``None``.
        extent: scene extent that depth / position were divided by (``None`` if neither).
        estimated_variance: True when ``color_var`` was estimated from the colour.
        estimated_features: features prefiltered with a variance estimated from themselves
            (``estimate_missing``).
        repaired: buffer name -> number of NaN/Inf/negative values repaired by sanitising.
        fireflies: pixels the firefly handling (``prepare_inputs(fireflies=...)``) changed.
        firefly_energy: ``(3,)`` colour summed over the image taken out of those pixels
            (redistributed to their neighbours in ``"keep-energy"`` mode), or ``None``.
    """

    color: Tensor
    color_var: Tensor
    features: dict[str, Tensor] = field(default_factory=dict)
    feature_vars: dict[str, Tensor] = field(default_factory=dict)
    albedo: Tensor | None = None
    extent: float | None = None
    estimated_variance: bool = False
    estimated_features: tuple[str, ...] = ()
    repaired: dict[str, int] = field(default_factory=dict)
    fireflies: int = 0
    firefly_energy: Tensor | None = None


def robust_variance(var: Tensor) -> Tensor:
    """``max(v, median_3×3(v))`` of the channel-mean variance ``(B, 1, H, W)``.

    A variance of the mean estimated from a handful of samples is heavy-tailed: many pixels get
    an estimate near 0 (no outlier sample landed there) although their true variance is not.
    The median lifts those to their neighbourhood's level; the ``max`` keeps isolated high
    estimates (fireflies, the anti-aliased edge of a light) where they are, without spreading
    them onto clean neighbours as a blur of the variance would.
    """
    v = var.mean(dim=1, keepdim=True)
    return torch.maximum(v, median3(v))


def estimate_variance(color: Tensor, *, bins: int = 16, firefly_sigmas: float = 4.0) -> Tensor:
    """Estimate the per-pixel variance of the mean of a noisy colour image from itself.

    Two parts:

    * a **noise-level function** of intensity: Monte Carlo noise is heteroscedastic (brighter
      pixels are noisier), so one sigma per image would over-blur the dark parts and
      under-filter the bright ones. Pixels are split into ``bins`` quantile bins of smoothed
      luminance; in each, σ is the robust MAD estimate ``median(|d|) / 0.6745`` of the
      diagonal Haar detail ``d = (a - b - c + d) / 2`` of 2×2 blocks (variance σ² for i.i.d.
      noise, and blind to axis-aligned edges);
    * **fireflies**: a pixel brighter than its 3×3 median by more than ``firefly_sigmas`` σ
      gets the squared excess as its variance, so the filters treat it as the outlier it is.

    Texture and noise cannot be told apart from colour alone, so this is a conservative
    estimate; filter with the renderer's variance whenever there is one.

    Args:
        color: ``(B, C, H, W)`` noisy linear colour, finite, >= 0.

    Returns:
        ``(B, 1, H, W)`` non-negative variance estimate, same dtype.
    """
    b, _, h, w = color.shape
    x = F.pad(color, (0, 1, 0, 1), mode="replicate")
    detail = (x[..., :-1, :-1] - x[..., :-1, 1:] - x[..., 1:, :-1] + x[..., 1:, 1:]) * 0.5
    mag = detail.abs().mean(dim=1, keepdim=True)  # (B,1,H,W)
    lum = color.mean(dim=1, keepdim=True)
    smooth = box_mean(lum, 2)
    nlf = torch.empty_like(mag)
    for i in range(b):
        li, mi = smooth[i].flatten(), mag[i].flatten()
        edges = quantile_subsampled(li, torch.linspace(0, 1, bins + 1)).to(li.dtype)
        idx = torch.bucketize(li, edges[1:-1])
        sigma = torch.zeros(bins, dtype=mi.dtype, device=mi.device)
        for j in range(bins):
            sel = mi[idx == j]
            if sel.numel():
                sigma[j] = sel.median() / 0.6745
        nlf[i] = sigma[idx].square().view(1, h, w)
    excess = lum - median3(lum)
    firefly = excess > firefly_sigmas * nlf.sqrt()
    return torch.where(firefly, torch.maximum(nlf, excess.square()), nlf).clamp_min(0.0)


def chi2_median_fraction(dof: int) -> float:
    """Median of ``χ²_dof / dof`` (Wilson–Hilferty: ``(1 - 2 / (9 dof))³``; 0.470 for 1, 0.794
    for 3 degrees of freedom, within 4 % of the exact 0.455 and 0.789): what the median of the
    channel mean of ``dof`` squared Gaussian details is, as a fraction of their variance."""
    return (1.0 - 2.0 / (9.0 * dof)) ** 3


def estimate_feature_variance(feature: Tensor) -> Tensor:
    """Per-pixel variance of the mean of a noisy feature, estimated from its neighbourhood.

    For a feature without a variance buffer (albedo, normal, ...): the squared diagonal Haar
    detail ``d = (a - b - c + d) / 2`` of each 2×2 block (variance σ² for independent noise,
    0 on flat regions and on axis-aligned edges), averaged over channels, then a separable
    5-tap median (along rows, then along columns), divided by the median of that channel
    mean for Gaussian noise (:func:`chi2_median_fraction`). The median makes it local (noise
    from depth of field or motion blur is confined to the defocused or moving parts) and
    robust: a sharp diagonal edge or a corner puts large details on a line one or two pixels
    wide, at most two of any five taps in a row or a column, and is not taken for noise, while
    a region where most details are large is.

    Args:
        feature: ``(B, C, H, W)`` finite feature.

    Returns:
        ``(B, 1, H, W)`` non-negative variance estimate, same dtype.
    """
    x = F.pad(feature, (0, 1, 0, 1), mode="replicate")
    d = (x[..., :-1, :-1] - x[..., :-1, 1:] - x[..., 1:, :-1] + x[..., 1:, 1:]) * 0.5
    d2 = d.square().mean(dim=1, keepdim=True)
    med = _line_median(_line_median(d2, -1), -2)
    return (med / chi2_median_fraction(feature.shape[1])).clamp_min(0.0)


def _line_median(x: Tensor, dim: int, radius: int = 2) -> Tensor:
    """Median of the ``2 radius + 1`` taps along ``dim`` (-1: rows, -2: columns), replicate
    border."""
    pad = (radius, radius, 0, 0) if dim == -1 else (0, 0, radius, radius)
    p = F.pad(x, pad, mode="replicate")
    n = x.shape[dim]
    taps = [p.narrow(dim, i, n) for i in range(2 * radius + 1)]
    return torch.stack(taps).median(dim=0).values


#: Share of the colour's relative variance that :func:`feature_noise_cap` allows a feature.
FEATURE_NOISE_CAP = 0.5


def feature_noise_cap(color: Tensor, color_var: Tensor, feature: Tensor) -> Tensor:
    """Upper bound ``(B, 1, H, W)`` of a feature's variance of the mean, from the colour's.

    Colour and feature come from the same samples, and the colour is about the albedo times
    the irradiance, so where the albedo (or the surface) varies inside a pixel the colour
    varies with it: a feature's relative variance is at most about the colour's,
    ``var(f) <= cap · var(c) / c² · mean_ch(f²)`` (``c`` the 3×3 mean luminance, cap
    :data:`FEATURE_NOISE_CAP`). :func:`estimate_feature_variance` cannot tell noise from a
    texture finer than its window; this bound can: on a well-converged render the colour's
    variance is small, so the texture of the feature is not taken for noise and blurred.
    """
    lum = box_mean(color.mean(dim=1, keepdim=True), 1)
    rel = color_var / (lum.square() + 1e-4)
    return FEATURE_NOISE_CAP * rel * feature.square().mean(dim=1, keepdim=True)


def low_spp_prefilter_variance(
    feature: Tensor, variance: Tensor, spp: float | None, max_spp: float = MAX_SPP
) -> Tensor:
    """The variance that steers a feature's prefilter at ``max_spp`` samples per pixel or fewer
    (default :data:`~mcdenoise.prep.variance.MAX_SPP`): ``max(v, e)`` of the feature's (pooled) variance buffer ``v``
    (channel mean) and its neighbourhood estimate ``e`` (:func:`estimate_feature_variance`);
    ``variance`` itself above that, or when ``spp`` is unknown.

    A feature's variance buffer from 2 samples is as noisy as the colour's: where the two
    samples of a defocused pixel happened to land on the same surface it is 0, and the pooled
    prior (:mod:`mcdenoise.prep.variance`) does not lift it, since it pools over pixels of
    similar *albedo* -- which the noisy albedo itself decides. The prefilter then keeps the
    albedo as noisy as it was written, and demodulation brings that noise back into the
    result (Rousselle et al. 2013 prefilter the features for this reason; OIDN denoises its
    auxiliary images first). The neighbourhood estimate sees the noise the buffer missed.

    Unlike :func:`~mcdenoise.prep.aux_prefilter.aux_feature_variance` (``kpcn``'s, for a
    feature *without* a buffer), the estimate is not capped by the colour's noise: at a few
    samples the colour's relative noise is far above any texture's, so the cap would only
    hold back the noisy albedo of mixing pixels. Measured on the demo renders at 2 spp
    (``nlm``/``cross-bilateral`` relMSE, ``docs/results/robustness.md``): ``dof_row``
    0.0655/0.0649 with the buffer alone, 0.0327/0.0348 with the capped estimate (mixing pixels
    uncapped), 0.0240/0.0258 with this; ``textured_floors`` 0.0259/0.0274 -> 0.0226/0.0236;
    ``cornell`` and ``caustics_glass`` within 0.3 %. At 8 spp the changes are under 1 %.
    """
    if spp is None or spp > max_spp:
        return variance
    return torch.maximum(variance.mean(dim=1, keepdim=True), estimate_feature_variance(feature))


def prefilter_feature(
    feature: Tensor, variance: Tensor, settings: Mapping[str, Any] = PREFILTER
) -> Tensor:
    """A noisy feature filtered by variance-normalised NLM (``settings``, default
    :data:`PREFILTER`) guided by itself."""
    with torch.no_grad():
        return non_local_means(feature, color_var=variance, **settings)


def quantile_subsampled(x: Tensor, q: Tensor, dim: int = -1) -> Tensor:
    """``torch.quantile`` in float64 on at most ~2^20 evenly strided samples along ``dim``
    (``torch.quantile`` refuses inputs above 2^24 elements; percentiles do not need them all)."""
    n = x.shape[dim]
    step = max(1, n // (1 << 20))
    sub = x[..., ::step] if dim in (-1, x.ndim - 1) else x
    return torch.quantile(sub.double(), q.to(device=x.device, dtype=torch.float64), dim=dim)


#: Where the 90th percentile of the colour's luminance (channel mean) is brought by
#: :func:`exposure_scale`: about the 5th-95th percentile of the training renders' (0.07-1.6
#: on the random scenes at 16 spp).
EXPOSURE_RANGE = (0.2, 1.0)
#: Quantile of the luminance that :func:`exposure_scale` measures.
EXPOSURE_QUANTILE = 0.9


def exposure_scale(
    color: Tensor, lo: float = EXPOSURE_RANGE[0], hi: float = EXPOSURE_RANGE[1]
) -> float:
    """Factor that brings the :data:`EXPOSURE_QUANTILE` of ``color``'s luminance into
    ``[lo, hi]`` (1 when it is inside, or when the image is black).

    Args:
        color: ``(C, H, W)`` or ``(1, C, H, W)`` sanitised linear colour.
    """
    lum = color.mean(dim=-3).flatten()
    level = float(quantile_subsampled(lum, torch.tensor(EXPOSURE_QUANTILE)))
    if not math.isfinite(level) or level <= 0:
        return 1.0
    return min(max(level, lo), hi) / level


def _robust_extent(buffers: FeatureBuffers) -> float | None:
    """Diagonal of the 1st-99th percentile box of hit positions, or the 99th percentile depth."""
    hit = None
    if "depth" in buffers:
        hit = buffers["depth"][0] > 0
    if "position" in buffers:
        p = buffers["position"].reshape(3, -1)
        if hit is not None:
            p = p[:, hit.flatten()]
        if p.shape[1] > 0:
            q = quantile_subsampled(p, torch.tensor([0.01, 0.99]), dim=1)
            diag = float((q[1] - q[0]).norm())
            if diag > 0:
                return diag
    if "depth" in buffers and hit is not None and bool(hit.any()):
        d = float(quantile_subsampled(buffers["depth"][0][hit], torch.tensor(0.99)))
        if d > 0:
            return d
    return None


def prepare_inputs(
    buffers: FeatureBuffers,
    *,
    features: Sequence[str] = GUIDE_FEATURES,
    prefilter: bool = True,
    estimate_missing: bool = False,
    prefilter_settings: Mapping[str, Any] | None = None,
    fireflies: str = "off",
    variance_prior: float = 0.0,
    variance_prior_max_spp: float = MAX_SPP,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> FilterInputs:
    """Sanitise and normalise ``buffers`` into :class:`FilterInputs`.

    Args:
        buffers: the image's buffers; only ``color`` is required.
        features: which guide features to use if present (subset of
            :data:`~mcdenoise.filters.settings.GUIDE_FEATURES`).
        prefilter: prefilter features that have a variance buffer (see the module docstring).
        estimate_missing: prefilter features that have none, with a variance estimated from
            the feature (:func:`estimate_feature_variance`; not put in ``feature_vars``).
        prefilter_settings: NLM settings of the prefilter of features that have a variance
            buffer (default :data:`PREFILTER`, the classical filters' choice; ``kpcn`` uses
            :data:`PREFILTER_ESTIMATED`).
        fireflies: ``"clamp"``, ``"keep-energy"`` or ``"off"`` (the default, so a caller that
            does not ask gets the colour as it is): outlier pixels are clamped against their
            5×5 neighbourhood before anything else sees the colour
            (:func:`~mcdenoise.prep.fireflies.remove_fireflies`, with the raw albedo and
            normal when present); the variance of a clamped pixel is scaled with it. Which
            methods use it, and the bias: :mod:`mcdenoise.prep.fireflies`.
        variance_prior: degrees of freedom ``ν₀`` of the pooled variance the renderer's
            per-pixel variance is shrunk towards (:func:`~mcdenoise.prep.variance.low_spp_variance`,
            after the firefly pass, before ``max(v, median_3×3(v))``); 0, the default, keeps
            the per-pixel estimate (what the learned models were trained with). With it, the
            features' prefilter is steered by :func:`low_spp_prefilter_variance`.
        variance_prior_max_spp: the most samples per pixel both apply at (the Kalantari
            methods: 2).
        dtype, device: of the returned tensors.

    Raises:
        MissingFeatureError: when ``color`` is absent.
        InputError: for an unknown feature name.
    """
    check_mode(fireflies)
    unknown = [f for f in features if f not in GUIDE_FEATURES]
    if unknown:
        raise InputError(f"unknown guide feature(s) {unknown}; known: {list(GUIDE_FEATURES)}")
    buffers.require(["color"], needed_by="the classical filters")
    clean, repaired = sanitize(buffers)

    def t(name: str) -> Tensor:
        return clean[name].to(device=device, dtype=dtype).unsqueeze(0)

    color = t("color")
    # One sample per pixel has no variance of the mean (the renderer writes 0): estimate it.
    usable_var = "color_var" in clean and buffers.spp != 1 and bool(clean["color_var"].max() > 0)
    estimated = not usable_var
    raw_var = t("color_var").mean(dim=1, keepdim=True) if usable_var else estimate_variance(color)
    n_fireflies, firefly_energy, firefly_mask = 0, None, None
    if fireflies != "off":
        ff = remove_fireflies(
            color,
            raw_var,
            fireflies,
            albedo=t("albedo") if "albedo" in clean else None,
            normal=t("normal") if "normal" in clean else None,
            dense=buffers.spp is None or buffers.spp <= MAX_SPP,
        )
        n_fireflies, firefly_energy, firefly_mask = ff.count, ff.removed[0], ff.mask
        if n_fireflies:
            color = ff.color
            # The estimate is re-made from the cleaned colour (its noise level function no
            # longer sees the outliers); the renderer's variance is scaled where clamped.
            raw_var = estimate_variance(color) if estimated else ff.variance
    pool_guides = {g: t(g) for g in ("albedo", "normal") if g in clean}
    if not estimated and variance_prior > 0:
        raw_var = low_spp_variance(
            raw_var,
            buffers.spp,
            pool_guides,
            prior_dof=variance_prior,
            exclude=firefly_mask,
            luminance=color.mean(dim=1, keepdim=True),
            max_spp=variance_prior_max_spp,
        )
    color_var = raw_var if estimated else robust_variance(raw_var)
    wanted = [f for f in features if f in clean]
    extent = _robust_extent(clean) if {"depth", "position"} & set(wanted) else None
    feats: dict[str, Tensor] = {}
    fvars: dict[str, Tensor] = {}
    estimated_features: list[str] = []
    for name in wanted:
        scale = 1.0
        if name in ("depth", "position"):
            if extent is None:
                continue
            scale = 1.0 / extent
        f = t(name) * scale
        if name + "_var" in clean:
            fvars[name] = t(name + "_var") * scale**2
            steer = fvars[name]
            if variance_prior > 0:  # as noisy as the colour's from a few samples
                fvars[name] = low_spp_variance(
                    fvars[name],
                    buffers.spp,
                    pool_guides,
                    prior_dof=variance_prior,
                    max_spp=variance_prior_max_spp,
                )
                steer = low_spp_prefilter_variance(
                    f, fvars[name], buffers.spp, variance_prior_max_spp
                )
            if prefilter:
                f = prefilter_feature(f, steer, prefilter_settings or PREFILTER)
        elif estimate_missing:
            v = torch.minimum(estimate_feature_variance(f), feature_noise_cap(color, color_var, f))
            f = prefilter_feature(f, v, PREFILTER_ESTIMATED)
            estimated_features.append(name)
        feats[name] = f
    albedo = feats.get("albedo")
    if albedo is None and "albedo" in clean and "albedo" in features:
        albedo = t("albedo")
    return FilterInputs(
        color=color,
        color_var=color_var,
        features=feats,
        feature_vars=fvars,
        albedo=albedo,
        extent=extent,
        estimated_variance=estimated,
        estimated_features=tuple(estimated_features),
        repaired=repaired,
        fireflies=n_fireflies,
        firefly_energy=firefly_energy,
    )


def demodulate_inputs(
    inp: FilterInputs, *, enabled: bool = True, eps: float = ALBEDO_EPS
) -> tuple[Tensor, Tensor, Tensor | None]:
    """``(irradiance, its variance (B,1,H,W), factor)`` of prepared inputs.

    ``factor`` (``albedo + eps``, what the filtered irradiance is multiplied by) is ``None``
    when not demodulating (``enabled`` false or no albedo): the colour is then filtered as it is.
    """
    if not enabled or inp.albedo is None:
        return inp.color, inp.color_var, None
    irr, factor = demodulate(inp.color, inp.albedo, eps)
    return irr, demodulated_variance(inp.color_var, factor), factor


def guide_args(
    inp: FilterInputs, s: XbfSettings | NlmSettings
) -> tuple[dict[str, float], dict[str, Tensor | None], dict[str, float]]:
    """(bandwidth, variance, floor) per guide feature of ``inp`` (see
    :func:`~mcdenoise.filters.settings.feature_bandwidths`)."""
    sig, floors = feature_bandwidths(s, list(inp.features), list(inp.feature_vars))
    fvars: dict[str, Tensor | None] = {n: inp.feature_vars.get(n) for n in inp.features}
    return sig, fvars, floors


__all__ = [
    "EXPOSURE_QUANTILE",
    "EXPOSURE_RANGE",
    "FEATURE_NOISE_CAP",
    "PREFILTER",
    "PREFILTER_ESTIMATED",
    "FilterInputs",
    "chi2_median_fraction",
    "demodulate_inputs",
    "estimate_feature_variance",
    "estimate_variance",
    "exposure_scale",
    "feature_noise_cap",
    "guide_args",
    "low_spp_prefilter_variance",
    "prefilter_feature",
    "prepare_inputs",
    "quantile_subsampled",
    "robust_variance",
]
