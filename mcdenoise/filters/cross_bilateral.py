"""Cross-bilateral filter with per-pixel bandwidths (Kalantari, Bako, Sen 2015).

For each pixel ``i`` over a ``k × k`` window of in-image neighbours ``j``::

    ĉ_i  = Σ_j d_ij c_j / Σ_j d_ij
    d_ij = exp(-‖p_i - p_j‖² / 2α_i²)                     spatial
         · exp(-D(c_i, c_j) / 2β_i²)                      colour
         · Π_k exp(-D_k(f_i,k, f_j,k) / 2γ_k,i²)           guide features

with the distances

    D(c_i, c_j)   = mean_ch (c_i - c_j)² / (ε + v_i + min(κ v_i, v_j))   (v: variance of the mean)
    D_k(f_i, f_j) = mean_ch (f_i - f_j)² / max(δ_k, ψ²_k,i [, |∇f_k,i|²])

The colour distance is normalised by the variance as in Rousselle et al. 2012 (two noisy samples
of the same value have ``E[D] ≈ 1``, so β is in units of noise), with ``min(κ v_i, v_j)`` in
place of ``v_j`` by default (``var_pair="sum"`` gives ``v_i + v_j``): a much noisier neighbour,
such as the anti-aliased edge of a visible light, must not look similar to a dark clean centre.
On renders with a visible light source this is the difference between a 4x improvement and a
100x degradation in relMSE. The cap is asymmetric, and that costs energy: a pixel that drew a
bright sample (high value, high variance estimate) accepts its darker neighbours while they
refuse it, so its excess is lost and the image darkens (``docs/results/bias.md``); the cap
``κ = var_cap`` (default 1, the plain minimum) lets a neighbour up to κ times noisier than
the centre count with its own noise. Without a variance it is the raw mean squared difference (β in
colour units). A feature distance is divided by the feature's
variance at the centre pixel (Kalantari 2015), floored at δ_k so that noise-free features do
not blow up, and optionally by its squared gradient (Rousselle et al. 2013), so that smoothly
varying features (depth on a slanted wall) do not stop the filter; without variance or
gradient it is the raw mean squared difference of the (pre-normalised) feature.

Every bandwidth is a float or a tensor (0-d, ``(B,1,1,1)`` or ``(B,1,H,W)``): a network can
predict it per pixel and gradients flow to it (float64 ``gradcheck`` in the tests). Bandwidths
are clamped at ``tiny ** 0.25`` of the dtype, so σ → 0 gives the identity, never NaN.
"""

from __future__ import annotations

import math
from typing import Literal

import torch
from torch import Tensor, nn

from mcdenoise.errors import InputError
from mcdenoise.filters._common import (
    Features,
    Param,
    bandwidth_floor,
    check_image,
    check_kernel_size,
    check_param,
    check_same_size,
    check_var_cap,
    check_variance,
    feature_normalizer,
    inv_two_sq,
    named_features,
    param_max,
    per_feature,
)
from mcdenoise.filters.kernels import Window, accumulate_weighted, exp_cut, neg_exp

#: Denominator floor ε of the colour distance (relative to a variance of the mean).
COLOR_EPS = 1e-4
#: Default floor δ of a feature distance's normaliser.
FEATURE_FLOOR = 1e-3


def cross_bilateral(
    color: Tensor,
    features: Features | None = None,
    *,
    kernel_size: int = 21,
    sigma_spatial: Param = 8.0,
    sigma_color: Param = 1.0,
    sigma_features: Param | list[Param] | dict[str, Param] = 1.0,
    color_var: Tensor | None = None,
    var_pair: Literal["min", "sum"] = "min",
    var_cap: float = 1.0,
    feature_vars: list[Tensor | None] | dict[str, Tensor | None] | None = None,
    feature_floor: float | list[float] | dict[str, float] = FEATURE_FLOOR,
    feature_gradient: bool = False,
    color_eps: float = COLOR_EPS,
    guide: Tensor | None = None,
    centre_weight: Literal["one", "max"] = "one",
    tile: int | tuple[int, int] | None = None,
) -> Tensor:
    """Filter ``color`` with the Kalantari 2015 cross-bilateral weights.

    Args:
        color: ``(B, C, H, W)`` noisy linear HDR colour (or demodulated irradiance), finite,
            float32 or float64. The output has the same dtype.
        features: guide features, a sequence or a name -> tensor mapping of ``(B, C_k, H, W)``
            tensors of the same size as ``color`` (e.g. albedo in [0, 1], normals in [-1, 1],
            depth divided by the scene extent). ``None``: spatial + colour terms only.
        kernel_size: odd window edge ``k`` (21 in Kalantari 2015).
        sigma_spatial: α, in pixels.
        sigma_color: β, in noise units when ``color_var`` is given, else in colour units.
        sigma_features: γ_k: one value for all features, or one per feature (list or dict).
        color_var: ``(B, 1 or C, H, W)`` variance of the mean of ``color`` (averaged over
            channels) for the normalised colour distance; ``None`` for the raw distance.
        var_pair: ``"min"`` (default): ``D = mean_ch Δ² / (ε + v_i + min(v_i, v_j))``;
            ``"sum"``: ``ε + v_i + v_j``. With ``"sum"`` a neighbour much noisier than the
            centre (the anti-aliased edge of a visible light) looks "similar" to a dark, clean
            centre and bleeds into it; ``"min"`` trusts it only up to the centre's own noise.
        var_cap: κ >= 1 of ``"min"``: ``D = mean_ch Δ² / (ε + v_i + min(κ v_i, v_j))`` (a
            neighbour counts with its own variance up to κ times the centre's); 1 is the plain
            minimum, ``inf`` gives ``"sum"``. Ignored with ``"sum"``.
        feature_vars: per-feature variance of the mean ``(B, 1 or C_k, H, W)`` or ``None``.
        feature_floor: δ_k, the floor of each feature normaliser (used when a variance or
            ``feature_gradient`` is present).
        feature_gradient: also normalise each feature distance by its squared gradient.
        color_eps: ε of the colour distance denominator.
        guide: ``(B, C, H, W)`` colour used in the colour distance instead of ``color`` (e.g.
            a prefiltered image); the values averaged are still those of ``color``.
        centre_weight: ``"one"``: the pixel's own weight is 1 (the largest any pixel gets);
            ``"max"``: the largest weight of its other neighbours (Buades, Coll, Morel 2005),
            so a pixel that its features and colour separate from everything around it (a
            firefly) no longer outweighs its best neighbours. Measured on the demo renders
            (``docs/results/filters.md``): 1.10 -> 0.66 relMSE on ``caustics_glass`` at
            16 spp without firefly clamping, neutral with it; the default stays ``"one"``.
        tile: output tile of the kernel loop (memory bound); the result does not depend on it.

    Returns:
        ``(B, C, H, W)`` filtered colour, same dtype and device as ``color``.

    Example:
        >>> c = torch.full((1, 3, 6, 6), 0.5)
        >>> torch.allclose(cross_bilateral(c, kernel_size=3), c)
        True
    """
    color = check_image(color, "color")
    k = check_kernel_size(kernel_size)
    if centre_weight not in ("one", "max"):
        raise InputError(f"centre_weight must be 'one' or 'max', got {centre_weight!r}")
    dtype = color.dtype
    guide_c = color
    if guide is not None:
        guide_c = check_image(guide, "guide").to(dtype)
        check_same_size(color, guide_c, "guide")
    var = check_variance(color_var, color, "color_var")
    if var_pair not in ("min", "sum"):
        raise InputError(f"var_pair must be 'min' or 'sum', got {var_pair!r}")
    pair_min = var_pair == "min"
    var_cap = check_var_cap(var_cap)
    pair_min = pair_min and var_cap != float("inf")  # min(∞ · v_i, v_j) is v_j (0 · ∞ is NaN)
    if not color_eps > 0:
        raise InputError(f"color_eps must be > 0, got {color_eps!r}")
    alpha = check_param(sigma_spatial, "sigma_spatial", color)
    beta = check_param(sigma_color, "sigma_color", color)

    feats = named_features(features)
    names = [n for n, _ in feats]
    gammas = per_feature(sigma_features, names, "sigma_features")
    fvars = per_feature(feature_vars, names, "feature_vars")
    floors = per_feature(feature_floor, names, "feature_floor")

    # Stack all features into one tensor and one per-pixel scale per channel, so that one
    # offset costs the same few ops whatever the number of features:
    #   Σ_k D_k / 2γ_k² = Σ_ch (f_i - f_j)²_ch · scale_ch,i
    f_list: list[Tensor] = []
    scale_list: list[Tensor | float] = []
    for (name, f), gamma, fv, floor in zip(feats, gammas, fvars, floors):
        f = check_image(f, name).to(dtype)
        check_same_size(color, f, name)
        g = check_param(gamma, f"sigma_features[{name}]", color)
        fvar = check_variance(fv, f, f"feature_vars[{name}]") if fv is not None else None
        fl = check_param(floor, f"feature_floor[{name}]", color)
        norm = feature_normalizer(f, fvar, float(fl), use_gradient=feature_gradient)
        s = inv_two_sq(g, dtype)
        s = s / (norm * f.shape[1])  # float, 0-d, (B,1,1,1) or (B,1,H,W)
        f_list.append(f)
        scale_list.extend([s] * f.shape[1])
    fstack = torch.cat(f_list, dim=1) if f_list else None  # (B, ΣC_k, H, W)
    # Per-pixel scales: one (B, 1, H, W) plane per feature, applied to its channels by
    # broadcasting (the same products as one plane per channel, in 4 planes instead of 10).
    fscale: list[tuple[int, int, Tensor | float]] = []
    if fstack is not None:
        if all(not isinstance(s, Tensor) for s in scale_list):
            # constant scales: fold them into the features once, (f_i - f_j)² · s = (√s f_i - √s f_j)²
            root = torch.tensor(
                [float(s) ** 0.5 for s in scale_list], dtype=dtype, device=color.device
            )
            fstack = fstack * root.view(1, -1, 1, 1)
        else:
            c0 = 0
            for f in f_list:
                s = scale_list[c0]
                fscale.append((c0, c0 + f.shape[1], s if isinstance(s, Tensor) else float(s)))
                c0 += f.shape[1]
    del f_list, scale_list

    spatial = inv_two_sq(alpha, dtype)  # 1/2α²   float or (B,1,·,·)
    col = inv_two_sq(beta, dtype)  # 1/2β²
    c = guide_c.shape[1]
    col = col / c  # mean over channels
    den_i = None
    vmean = None
    if var is not None:
        vmean = var.mean(dim=1, keepdim=True)  # (B,1,H,W)
        den_i = vmean + color_eps  # ε + v_i
    # Offsets whose spatial weight is below neg_exp's cut for every pixel contribute nothing.
    amax = max(param_max(alpha), bandwidth_floor(dtype))
    cut = exp_cut(dtype)
    # In-place arithmetic on per-offset temporaries when nothing needs a gradient.
    inplace = not torch.is_grad_enabled() or not any(
        isinstance(t, Tensor) and t.requires_grad
        for t in (color, guide_c, var, alpha, beta, fstack, *[s for _, _, s in fscale])
    )

    neg_col = -col  # exact: x · (-c) = -(x · c)
    tiny_w = math.exp(-cut)  # what neg_exp subtracts

    def weight_fn(win: Window) -> Tensor | None:
        r2 = float(win.dy * win.dy + win.dx * win.dx)
        if r2 > 0 and r2 / (2 * amax * amax) > cut:
            return None  # the spatial term alone puts every weight below exp(-cut): all 0
        if inplace:
            return _weight_inplace(win, r2)
        d = win.neighbour(guide_c) - win.centre(guide_c)
        e = d.square().sum(dim=1, keepdim=True)  # (B,1,h,w)
        if den_i is not None and vmean is not None:
            vj = win.neighbour(vmean)
            if pair_min:
                vc = win.centre(vmean)
                vj = torch.minimum(vc if var_cap == 1 else vc * var_cap, vj)
            e = e / (win.centre(den_i) + vj)
        e = e * win.param(col)
        if fstack is not None:
            df = (win.neighbour(fstack) - win.centre(fstack)).square()  # (B,ΣC,h,w)
            if fscale:
                df = torch.cat([df[:, a:z] * win.param(sc) for a, z, sc in fscale], dim=1)
            e = e + df.sum(dim=1, keepdim=True)
        if r2 > 0:
            e = e + win.param(spatial) * r2
        return neg_exp(e)

    def _weight_inplace(win: Window, r2: float) -> Tensor:
        """The same weights without autograd: in place, and on the negated exponent -e, which
        is exact (IEEE rounding is symmetric) and saves neg_exp's negation and its copy."""
        d = win.neighbour(guide_c) - win.centre(guide_c)
        e = d.square_().sum(dim=1, keepdim=True)  # (B,1,h,w)
        if den_i is not None and vmean is not None:
            vj = win.neighbour(vmean)
            if pair_min:
                vc = win.centre(vmean)
                vj = torch.minimum(vc if var_cap == 1 else vc * var_cap, vj)
                den = vj.add_(win.centre(den_i))  # vj is a new tensor; a + b = b + a exactly
            else:
                den = win.centre(den_i) + vj
            e.div_(den)
        e.mul_(win.param(neg_col))  # -e from here on
        if fstack is not None:
            df = win.neighbour(fstack) - win.centre(fstack)  # (B,ΣC,h,w)
            df.square_()
            for a, z, sc in fscale:
                df[:, a:z].mul_(win.param(sc))
            e.sub_(df.sum(dim=1, keepdim=True))
        if r2 > 0:
            e.sub_(win.param(spatial) * r2)
        # neg_exp(e) = (exp(-min(e, cut)) - exp(-cut))⁺, with -min(e, cut) = max(-e, -cut)
        return e.clamp_(min=-cut).exp_().sub_(tiny_w).clamp_min_(0.0)

    return accumulate_weighted(color, weight_fn, k, centre=centre_weight, tile=tile)


class CrossBilateral(nn.Module):
    """Module form of :func:`cross_bilateral` with fixed settings.

    Bandwidths given to the constructor are defaults; :meth:`forward` accepts per-call
    bandwidths (e.g. predicted per pixel by a network), which take precedence.

    Example:
        >>> f = CrossBilateral(kernel_size=5, sigma_spatial=2.0)
        >>> f(torch.rand(1, 3, 8, 8), [torch.rand(1, 3, 8, 8)]).shape
        torch.Size([1, 3, 8, 8])
    """

    def __init__(
        self,
        kernel_size: int = 21,
        sigma_spatial: float = 8.0,
        sigma_color: float = 1.0,
        sigma_features: float | list[float] | dict[str, float] = 1.0,
        *,
        var_pair: Literal["min", "sum"] = "min",
        var_cap: float = 1.0,
        feature_floor: float | list[float] | dict[str, float] = FEATURE_FLOOR,
        feature_gradient: bool = False,
        color_eps: float = COLOR_EPS,
        centre_weight: Literal["one", "max"] = "one",
        tile: int | tuple[int, int] | None = None,
    ) -> None:
        super().__init__()
        self.kernel_size = check_kernel_size(kernel_size)
        self.sigma_spatial = sigma_spatial
        self.sigma_color = sigma_color
        self.sigma_features = sigma_features
        self.var_pair = var_pair
        self.var_cap = var_cap
        self.feature_floor = feature_floor
        self.feature_gradient = feature_gradient
        self.color_eps = color_eps
        self.centre_weight = centre_weight
        self.tile = tile

    def forward(
        self,
        color: Tensor,
        features: Features | None = None,
        *,
        sigma_spatial: Param | None = None,
        sigma_color: Param | None = None,
        sigma_features: Param | list[Param] | dict[str, Param] | None = None,
        color_var: Tensor | None = None,
        feature_vars: list[Tensor | None] | dict[str, Tensor | None] | None = None,
        guide: Tensor | None = None,
    ) -> Tensor:
        """See :func:`cross_bilateral`; ``None`` bandwidths use the constructor's values."""
        return cross_bilateral(
            color,
            features,
            kernel_size=self.kernel_size,
            sigma_spatial=self.sigma_spatial if sigma_spatial is None else sigma_spatial,
            sigma_color=self.sigma_color if sigma_color is None else sigma_color,
            sigma_features=self.sigma_features if sigma_features is None else sigma_features,
            color_var=color_var,
            var_pair=self.var_pair,
            var_cap=self.var_cap,
            feature_vars=feature_vars,
            feature_floor=self.feature_floor,
            feature_gradient=self.feature_gradient,
            color_eps=self.color_eps,
            guide=guide,
            centre_weight=self.centre_weight,
            tile=self.tile,
        )

    def extra_repr(self) -> str:
        return (
            f"kernel_size={self.kernel_size}, sigma_spatial={self.sigma_spatial}, "
            f"sigma_color={self.sigma_color}, sigma_features={self.sigma_features}"
        )
