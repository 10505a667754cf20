"""From a :class:`~mcdenoise.io.buffers.FeatureBuffers` to filter inputs, and ready-made denoisers.

:func:`prepare_inputs` sanitises the buffers (:func:`mcdenoise.io.buffers.sanitize`), normalises
the guide features to comparable scales and picks up the variances that are present:

* ``albedo`` as it is (reflectance, usually [0, 1], up to ~10 on glossy lobes in Mitsuba);
  ``normal`` as it is (unit vectors, [-1, 1]);
* ``depth`` and ``position`` divided by the scene extent (the diagonal of the robust bounding
  box of the first-hit positions, or the robust maximum depth), so that 1 means "across the
  scene"; their variances by the extent squared;
* features that come with a variance are **prefiltered** (variance-normalised NLM, 11×11
  window), as in Rousselle et al. 2013: a defocused or motion-blurred feature is as noisy as
  the colour and would otherwise imprint that noise on the result;
* ``color_var`` (variance of the mean) is averaged over channels and made robust with
  ``max(v, median_3×3(v))``: from a few samples the variance estimate is itself very noisy, and
  a pixel whose estimate came out near 0 would otherwise refuse all its neighbours. Without a
  ``color_var`` (or with one that cannot be right: 1 spp, or all zero) the variance is
  estimated from the colour (:func:`estimate_variance`) and
  :attr:`FilterInputs.estimated_variance` says so.

:func:`denoise_xbf` and :func:`denoise_nlm` run the whole pipeline: prepare, demodulate by the
(prefiltered) albedo when there is one -- filter the irradiance ``c / (albedo + ε)`` and
multiply back, so texture detail never has to survive the filter -- filter, remodulate, clamp
at 0. Their defaults (:class:`XbfSettings`, :class:`NlmSettings`) were tuned on path-traced
Mitsuba 3 renders at 16 spp: the project's ``data/samples`` (cornell, materials, caustic,
dof; 128×128, with variances) and four scratch scenes without feature variances (Cornell box,
a glossy / textured variant, an outdoor scene under sky light, a room lit by a small visible
light), and checked at 4 spp and 256×256. Every field can be overridden by keyword. They work
with colour only (weaker: nothing tells texture from noise), and with any subset of features.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.cross_bilateral import cross_bilateral
from mcdenoise.filters.nlm import non_local_means
from mcdenoise.io.buffers import FeatureBuffers, sanitize

#: Guide features a filter may use, in order; those absent from the buffers are skipped.
GUIDE_FEATURES: tuple[str, ...] = ("albedo", "normal", "depth", "position")

#: NLM settings of the feature prefilter (variance-normalised, paper denominator ``v_i + v_j``).
PREFILTER = {"search_radius": 5, "patch_radius": 3, "k": 1.0, "alpha": 1.0, "var_pair": "sum"}


@dataclass
class FilterInputs:
    """Sanitised, normalised tensors for the filters, all ``(1, C, H, W)``.

    Attributes:
        color: noisy linear HDR RGB colour, sanitised (NaN -> 0, clamped at 0).
        color_var: ``(1, 1, H, W)`` robust variance of the mean of ``color`` (channel mean):
            from the buffers, or estimated from the colour when :attr:`estimated_variance`.
        features: name -> normalised (and, where a variance exists, prefiltered) guide feature,
            in :data:`GUIDE_FEATURES` order, only those present.
        feature_vars: name -> normalised variance of the mean of the raw feature, when present.
        albedo: albedo ``(1, 3, H, W)`` for demodulation (prefiltered when it has a variance),
            or ``None``.
        extent: scene extent that depth / position were divided by (``None`` if neither).
        estimated_variance: True when ``color_var`` was estimated from the colour.
        repaired: buffer name -> number of NaN/Inf/negative values repaired by sanitising.
    """

    color: Tensor
    color_var: Tensor
    features: dict[str, Tensor] = field(default_factory=dict)
    feature_vars: dict[str, Tensor] = field(default_factory=dict)
    albedo: Tensor | None = None
    extent: float | None = None
    estimated_variance: bool = False
    repaired: dict[str, int] = field(default_factory=dict)


def box_mean(x: Tensor, r: int) -> Tensor:
    """Mean over the in-image part of a ``(2r+1)²`` window, ``(B, C, H, W)``.

    Separable (a row sum, then a column sum): ``4r + 2`` additions per pixel instead of
    ``(2r+1)²``, 30× fewer for the 63×63 regional features.
    """
    k = 2 * r + 1

    def window_sum(t: Tensor) -> Tensor:
        t = F.avg_pool2d(F.pad(t, (r, r, 0, 0)), (1, k), stride=1, divisor_override=1)
        return F.avg_pool2d(F.pad(t, (0, 0, r, r)), (k, 1), stride=1, divisor_override=1)

    return window_sum(x) / window_sum(torch.ones_like(x[:, :1]))


def _median3(x: Tensor) -> Tensor:
    """3×3 median (replicate border) of a ``(B, C, H, W)`` tensor."""
    h, w = x.shape[-2:]
    p = F.pad(x, (1, 1, 1, 1), mode="replicate")
    taps = [p[..., dy : dy + h, dx : dx + w] for dy in range(3) for dx in range(3)]
    return torch.stack(taps).median(dim=0).values


def robust_variance(var: Tensor) -> Tensor:
    """``max(v, median_3×3(v))`` of the channel-mean variance ``(B, 1, H, W)``.

    A variance of the mean estimated from a handful of samples is heavy-tailed: many pixels get
    an estimate near 0 (no outlier sample landed there) although their true variance is not.
    The median lifts those to their neighbourhood's level; the ``max`` keeps isolated high
    estimates (fireflies, the anti-aliased edge of a light) where they are, without spreading
    them onto clean neighbours as a blur of the variance would.
    """
    v = var.mean(dim=1, keepdim=True)
    return torch.maximum(v, _median3(v))


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
        edges = _quantile(li, torch.linspace(0, 1, bins + 1)).to(li.dtype)
        idx = torch.bucketize(li, edges[1:-1])
        sigma = torch.zeros(bins, dtype=mi.dtype, device=mi.device)
        for j in range(bins):
            sel = mi[idx == j]
            if sel.numel():
                sigma[j] = sel.median() / 0.6745
        nlf[i] = sigma[idx].square().view(1, h, w)
    excess = lum - _median3(lum)
    firefly = excess > firefly_sigmas * nlf.sqrt()
    return torch.where(firefly, torch.maximum(nlf, excess.square()), nlf).clamp_min(0.0)


def _quantile(x: Tensor, q: Tensor, dim: int = -1) -> Tensor:
    """``torch.quantile`` in float64 on at most ~2^20 evenly strided samples along ``dim``
    (``torch.quantile`` refuses inputs above 2^24 elements; percentiles do not need them all)."""
    n = x.shape[dim]
    step = max(1, n // (1 << 20))
    sub = x[..., ::step] if dim in (-1, x.ndim - 1) else x
    return torch.quantile(sub.double(), q.to(device=x.device, dtype=torch.float64), dim=dim)


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
            q = _quantile(p, torch.tensor([0.01, 0.99]), dim=1)
            diag = float((q[1] - q[0]).norm())
            if diag > 0:
                return diag
    if "depth" in buffers and hit is not None and bool(hit.any()):
        d = float(_quantile(buffers["depth"][0][hit], torch.tensor(0.99)))
        if d > 0:
            return d
    return None


def prepare_inputs(
    buffers: FeatureBuffers,
    *,
    features: Sequence[str] = GUIDE_FEATURES,
    prefilter: bool = True,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> FilterInputs:
    """Sanitise and normalise ``buffers`` into :class:`FilterInputs`.

    Args:
        buffers: the image's buffers; only ``color`` is required.
        features: which guide features to use if present (subset of :data:`GUIDE_FEATURES`).
        prefilter: prefilter features that have a variance buffer (see the module docstring).
        dtype, device: of the returned tensors.

    Raises:
        MissingFeatureError: when ``color`` is absent.
        InputError: for an unknown feature name.
    """
    unknown = [f for f in features if f not in GUIDE_FEATURES]
    if unknown:
        raise InputError(f"unknown guide feature(s) {unknown}; known: {list(GUIDE_FEATURES)}")
    buffers.require(["color"], needed_by="the classical filters")
    clean, repaired = sanitize(buffers)

    def t(name: str) -> Tensor:
        return clean[name].to(device=device, dtype=dtype).unsqueeze(0)

    color = t("color")
    wanted = [f for f in features if f in clean]
    extent = _robust_extent(clean) if {"depth", "position"} & set(wanted) else None
    feats: dict[str, Tensor] = {}
    fvars: dict[str, Tensor] = {}
    for name in wanted:
        scale = 1.0
        if name in ("depth", "position"):
            if extent is None:
                continue
            scale = 1.0 / extent
        f = t(name) * scale
        if name + "_var" in clean:
            fvars[name] = t(name + "_var") * scale**2
            if prefilter:
                with torch.no_grad():
                    f = non_local_means(f, color_var=fvars[name], **PREFILTER)  # type: ignore[arg-type]
        feats[name] = f
    albedo = feats.get("albedo")
    if albedo is None and "albedo" in clean and "albedo" in features:
        albedo = t("albedo")
    # One sample per pixel has no variance of the mean (the renderer writes 0): estimate it.
    usable_var = "color_var" in clean and buffers.spp != 1 and bool(clean["color_var"].max() > 0)
    if usable_var:
        color_var, estimated = robust_variance(t("color_var")), False
    else:
        color_var, estimated = estimate_variance(color), True
    return FilterInputs(
        color=color,
        color_var=color_var,
        features=feats,
        feature_vars=fvars,
        albedo=albedo,
        extent=extent,
        estimated_variance=estimated,
        repaired=repaired,
    )


def _demodulate(
    inp: FilterInputs, enabled: bool, eps: float
) -> tuple[Tensor, Tensor, Tensor | None]:
    """``(irradiance, its variance (B,1,H,W), factor)``; ``factor`` is None when not demodulating.

    The albedo is treated as exact: ``var(c / a) ≈ var(c) / mean_ch(a²)`` (dominated by the
    largest channel, so a saturated albedo with a zero channel does not inflate it).
    """
    if not enabled or inp.albedo is None:
        return inp.color, inp.color_var, None
    factor = inp.albedo + eps  # (1,3,H,W)
    irr = inp.color / factor
    var = inp.color_var / factor.square().mean(dim=1, keepdim=True)
    return irr, var, factor


def _apply_overrides(settings: object, overrides: dict[str, object]) -> object:
    names = {f.name for f in dataclasses.fields(settings)}  # type: ignore[arg-type]
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise InputError(
            f"unknown setting(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}"
        )
    return dataclasses.replace(settings, **overrides)  # type: ignore[type-var]


@dataclass(frozen=True)
class XbfSettings:
    """Defaults of :func:`denoise_xbf` (tuned as described in the module docstring).

    ``sigma_color`` is in noise units (the colour distance is variance-normalised). With
    ``passes=2`` a second pass recomputes the colour distances on the first pass's result
    (a far less noisy guide), with bandwidth ``sigma_color_refine``; on ``data/samples`` it
    lowers relMSE by ~10% at 16 spp (geometric-mean reduction 12.7x vs 11.4x) and not at 4 spp,
    for twice the filtering time, so the default is one pass. ``sigma_<feature>`` are
    feature bandwidths in the units of :func:`prepare_inputs` (albedo, unit normals, depth and
    position over the scene extent). Where a feature variance is present, ``sigma_<feature>²``
    becomes the floor of the variance normaliser (Kalantari 2015) and ``feature_scale`` the
    normalised bandwidth, so a noisy feature is trusted less and a clean one exactly as
    without variance.
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
    demodulate: bool = True
    albedo_eps: float = 1e-2
    prefilter: bool = True
    features: tuple[str, ...] = GUIDE_FEATURES


@dataclass(frozen=True)
class NlmSettings:
    """Defaults of :func:`denoise_nlm` (tuned as described in the module docstring).

    ``k``, ``alpha``, ``search_radius``, ``patch_radius``, ``var_pair`` as in
    :func:`~mcdenoise.filters.nlm.non_local_means` (3×3 patches and α = 2 beat Rousselle's
    7×7 / α = 4 on 16 spp renders with noisy variance estimates). Feature terms (Rousselle
    2013) use ``sigma_<feature>²`` as the floor of their normaliser ``max(τ, var, |∇f|²)`` and
    ``feature_scale`` as ``k_f``.
    """

    search_radius: int = 10
    patch_radius: int = 1
    k: float = 0.45
    alpha: float = 2.0
    var_pair: str = "min"
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


def _feature_args(
    inp: FilterInputs, s: XbfSettings | NlmSettings
) -> tuple[dict[str, float], dict[str, Tensor | None], dict[str, float]]:
    """(bandwidth, variance, floor) per guide feature of ``inp`` (see :func:`feature_bandwidths`)."""
    sig, floors = feature_bandwidths(s, list(inp.features), list(inp.feature_vars))
    fvars: dict[str, Tensor | None] = {n: inp.feature_vars.get(n) for n in inp.features}
    return sig, fvars, floors


def _finish(out: Tensor, factor: Tensor | None) -> Tensor:
    if factor is not None:
        out = out * factor
    return out.clamp_min(0.0)[0]


def denoise_xbf(buffers: FeatureBuffers, **overrides: object) -> Tensor:
    """Denoise with the cross-bilateral filter; returns the ``(3, H, W)`` float32 colour.

    Keyword overrides replace fields of :class:`XbfSettings` (an unknown name is an
    :class:`~mcdenoise.errors.InputError`). Works with colour only (the variance is then
    estimated) and with any subset of the guide features.

    Example:
        >>> fb = FeatureBuffers({"color": torch.full((3, 8, 8), 0.5)})
        >>> denoise_xbf(fb, kernel_size=5).shape
        torch.Size([3, 8, 8])
    """
    s: XbfSettings = _apply_overrides(XbfSettings(), overrides)  # type: ignore[assignment]
    if s.passes < 1:
        raise InputError(f"passes must be >= 1, got {s.passes}")
    inp = prepare_inputs(buffers, features=s.features, prefilter=s.prefilter)
    irr, var, factor = _demodulate(inp, s.demodulate, s.albedo_eps)
    sig, fvars, floors = _feature_args(inp, s)
    common = {
        "kernel_size": s.kernel_size,
        "sigma_spatial": s.sigma_spatial,
        "sigma_features": sig,
        "color_var": var,
        "var_pair": s.var_pair,
        "feature_vars": fvars,
        "feature_floor": floors,
        "feature_gradient": s.feature_gradient,
    }
    with torch.no_grad():
        out = cross_bilateral(irr, inp.features, sigma_color=s.sigma_color, **common)  # type: ignore[arg-type]
        for _ in range(s.passes - 1):
            out = cross_bilateral(
                irr,
                inp.features,
                sigma_color=s.sigma_color_refine,
                guide=out,
                **common,  # type: ignore[arg-type]
            )
    return _finish(out, factor)


def denoise_nlm(buffers: FeatureBuffers, **overrides: object) -> Tensor:
    """Denoise with variance-normalised NLM; returns the ``(3, H, W)`` float32 colour.

    Keyword overrides replace fields of :class:`NlmSettings`. Without a variance buffer the
    variance is estimated from the colour (:func:`estimate_variance`); guide features, when
    present, add Rousselle 2013 feature weights (``features=()`` turns them off).

    Example:
        >>> fb = FeatureBuffers({"color": torch.full((3, 8, 8), 0.5)})
        >>> denoise_nlm(fb, search_radius=2).shape
        torch.Size([3, 8, 8])
    """
    s: NlmSettings = _apply_overrides(NlmSettings(), overrides)  # type: ignore[assignment]
    inp = prepare_inputs(buffers, features=s.features, prefilter=s.prefilter)
    irr, var, factor = _demodulate(inp, s.demodulate, s.albedo_eps)
    sig, fvars, floors = _feature_args(inp, s)
    with torch.no_grad():
        out = non_local_means(
            irr,
            search_radius=s.search_radius,
            patch_radius=s.patch_radius,
            k=s.k,
            alpha=s.alpha,
            color_var=var,
            var_pair=s.var_pair,  # type: ignore[arg-type]
            features=inp.features or None,
            feature_k=sig,
            feature_vars=fvars,
            feature_floor=floors,
            feature_gradient=s.feature_gradient,
            combine=s.combine,  # type: ignore[arg-type]
        )
    return _finish(out, factor)
