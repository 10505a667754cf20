"""Non-local means with variance-normalised patch distances (Rousselle, Knaus, Zwicker 2012).

For each pixel ``i`` and each neighbour ``j`` of its ``(2r+1)²`` search window::

    d²(i, j) = 1/|P| Σ_{p ∈ P} [mean_ch (u_{i+p} - u_{j+p})² - α (v_{i+p} + min(v_{i+p}, v_{j+p}))]
                                 / (ε + v_{i+p} + v_{j+p})  /  k_i²
    w_ij     = exp(-max(0, d²(i, j)))
    ĉ_i      = Σ_j w_ij c_j / Σ_j w_ij

``P`` is the ``(2f+1)²`` patch, ``u`` the guide (the colour by default), ``v`` its variance of
the mean averaged over channels (channels are reduced first, so the variance terms cost one
channel), α the variance-cancellation strength and ``k`` the (per-pixel) bandwidth. ``k²`` is
factored out of the patch sum, which is exact for ε → 0; ε only guards 0/0 where the variance
is 0 (noise-free pixels then keep their own value, as they should). Near the border a patch
only counts the pixel pairs that are inside the image.

Without a variance (``color_var=None``) the classic normalisation is used:
``d² = mean_{p,ch} (u_{i+p} - u_{j+p})² / h_i²`` -- pass ``h``; to get noise-aware weights from
a colour-only image, estimate a variance (the preparation layer, ``prep/inputs.py``, does) and use the
variance form.

``var_pair="min"`` replaces ``v_{j+p}`` by ``min(κ v_{i+p}, v_{j+p})`` in the denominator (κ =
``var_cap``, default 1), which keeps a much noisier neighbour (the edge of a visible light) out
of a clean dark patch. With κ = 1 it costs energy: a patch that drew bright samples (high
values, high variance estimates) accepts darker patches while they refuse it, so the image
darkens (``docs/results/bias.md``); κ > 1 lets a neighbour up to κ times noisier than the
centre count with its own noise.

Cost: per offset, the squared-difference map is computed once (channels reduced first) and
box-filtered with separable cumulative sums, so the cost per offset does not grow with the
patch size; for ``f <= 2`` the ``2f`` shifted additions per axis are cheaper than a scan and
replace it (same sums). Terms are clamped at a value whose weight is below ``e^-50`` before
the box filter, so one huge difference (a firefly) neither overflows nor swamps the precision
of the cumulative sums.

Robustness to one outlier (``patch_trim`` = τ, off by default): a firefly in the patch of a
pixel makes that patch unlike every other (its term is thousands of noise units), so the pixel
refuses all its neighbours and keeps its own noisy value; and a firefly that is itself the
centre sits in a patch that matches nothing, so it keeps its value too. With τ the largest term
of the patch other than the pair's own (``p ≠ 0``) counts at most τ per channel::

    Σ_p t_p  →  Σ_p t_p - (max_{p≠0} t_p - C τ)⁺

(a trimmed distance, one term: several mismatched pixels -- an edge crossing the patch -- still
separate the patches). The pair's own term is never capped, so a firefly is still refused as
a neighbour. The nearest rule of the classic literature, a centre weight equal to the largest
weight of the other neighbours (Buades, Coll, Morel 2005; ``centre_weight="max"``), is offered
too; on the demo renders it raised the error of clean scenes (``docs/results/filters.md``).

Optional feature terms (Rousselle, Manzi, Zwicker 2013): per-pixel feature distances
``D_f = mean_ch (f_i - f_j)² / (k_f,i² max(τ_f, var_f,i, |∇f_i|²))`` with
``w_f = exp(-D_f)``; the final weight is ``min(w_colour, min_f w_f)`` (``combine="min"``, as in
the paper) or the product of all of them (``combine="product"``).

With α > 0 a pair of patches that differ by less than the noise gets weight 1 whatever ``k``
(that is the point of variance cancellation); ``h → 0`` in the classic form, or ``k → 0`` with
α = 0, gives the identity.
"""

from __future__ import annotations

import math
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from mcdenoise.errors import InputError
from mcdenoise.filters._common import (
    Features,
    Param,
    bandwidth_floor,
    check_image,
    check_param,
    check_radius,
    check_same_size,
    check_var_cap,
    check_variance,
    feature_normalizer,
    named_features,
    param_max,
    per_feature,
)
from mcdenoise.filters.kernels import Window, accumulate_weighted, exp_cut, neg_exp

#: ε of the variance-normalised distance (Rousselle 2012 use 1e-10).
NLM_EPS = 1e-10
#: A patch distance above this (weight ``e^-50`` ≈ 2e-22 relative to the centre's 1) is 0 weight.
_MAX_DIST = 50.0


def non_local_means(
    color: Tensor,
    *,
    search_radius: int = 10,
    patch_radius: int = 3,
    k: Param = 0.45,
    alpha: float = 4.0,
    color_var: Tensor | None = None,
    var_pair: Literal["sum", "min"] = "sum",
    var_cap: float = 1.0,
    h: Param | None = None,
    guide: Tensor | None = None,
    features: Features | None = None,
    feature_k: Param | list[Param] | dict[str, Param] = 1.0,
    feature_vars: list[Tensor | None] | dict[str, Tensor | None] | None = None,
    feature_floor: float | list[float] | dict[str, float] = 1e-3,
    feature_gradient: bool = True,
    combine: Literal["min", "product"] = "min",
    eps: float = NLM_EPS,
    centre_weight: Literal["one", "max"] = "one",
    patch_trim: float = math.inf,
    tile: int | tuple[int, int] | None = None,
) -> Tensor:
    """Filter ``color`` with (feature-augmented) non-local means.

    Args:
        color: ``(B, C, H, W)`` noisy linear HDR colour (or demodulated irradiance), finite,
            float32/float64; the output keeps its dtype.
        search_radius: ``r``; the search window is ``(2r+1)²`` (default 21×21).
        patch_radius: ``f``; patches are ``(2f+1)²`` (Rousselle 2012: f = 3).
        k: bandwidth of the variance-normalised distance, float or per-pixel tensor.
        alpha: variance cancellation α ≥ 0 (Rousselle 2012: 4 for the first pass).
        color_var: ``(B, 1 or C, H, W)`` variance of the mean of the guide; enables the
            variance-normalised distance. ``None`` requires ``h`` (classic NLM).
        var_pair: denominator of the variance-normalised distance: ``"sum"`` is the paper's
            ``ε + v_i + v_j``; ``"min"`` uses ``ε + v_i + min(v_i, v_j)``, which does not let a
            much noisier neighbour (the anti-aliased edge of a visible light source) look
            similar to a dark, clean centre -- on renders with visible lights it is far more
            robust (the ``nlm`` method uses it by default).
        var_cap: κ >= 1 of ``"min"``: the denominator is ``ε + v_i + min(κ v_i, v_j)``; 1 is
            the plain minimum, ``inf`` gives ``"sum"``. Ignored with ``"sum"``.
        h: bandwidth of the classic distance (colour units), float or per-pixel tensor; only
            without ``color_var``.
        guide: ``(B, C_g, H, W)`` image whose patches are compared (default: ``color``), e.g. a
            variance-stabilised or prefiltered colour. The averaged values are ``color``'s.
        features: optional guide features (sequence or name -> ``(B, C_k, H, W)`` mapping).
        feature_k: ``k_f`` per feature (one value for all, a list, or a dict), float or tensor.
        feature_vars: per-feature variance of the mean ``(B, 1 or C_k, H, W)`` or ``None``.
        feature_floor: τ_f, floor of each feature normaliser.
        feature_gradient: include ``|∇f_i|²`` in the feature normaliser (Rousselle 2013).
        combine: ``"min"`` or ``"product"`` of the colour and feature weights.
        eps: ε of the variance-normalised denominator.
        centre_weight: ``"one"``: the pixel's own weight is 1 (its patch distance to itself
            is 0); ``"max"``: the largest weight of its other neighbours (Buades 2005), so a
            pixel whose patch matches nothing (a firefly) is averaged with its best matches
            instead of keeping its value.
        patch_trim: τ >= 0 (``inf``: off, the paper's distance): with ``color_var``, the largest
            term of each patch other than the compared pair's own counts at most τ per channel
            (in noise units: two equal pixels score about ``1 - α``), so one outlier inside a
            patch -- a firefly next to the pixel -- cannot make every patch around it unlike
            every other, nor hide a neighbour whose patch holds it. The pair's own term stays
            whole: it decides whether ``c_j`` may be averaged into ``c_i``, and a firefly must
            stay refused as a neighbour. Measured (and what it costs in energy):
            ``docs/results/filters.md``.
        tile: output tile of the kernel loop (memory bound); the result does not depend on it
            beyond float rounding of the cumulative sums.

    Returns:
        ``(B, C, H, W)`` filtered colour, same dtype/device as ``color``.

    Example:
        >>> c = torch.full((1, 3, 9, 9), 2.0)
        >>> torch.allclose(non_local_means(c, search_radius=2, patch_radius=1, h=0.1), c)
        True
    """
    color = check_image(color, "color")
    r = check_radius(search_radius, "search_radius")
    f = check_radius(patch_radius, "patch_radius")
    dtype = color.dtype
    g = color
    if guide is not None:
        g = check_image(guide, "guide").to(dtype)
        check_same_size(color, g, "guide")
    var = check_variance(color_var, g, "color_var")
    if var is not None and h is not None:
        raise InputError("give either color_var (variance-normalised NLM, with k) or h, not both")
    if var is None and h is None:
        raise InputError(
            "nlm needs color_var (variance-normalised distance) or h (classic distance)"
        )
    if not (isinstance(alpha, int | float) and not isinstance(alpha, bool) and alpha >= 0):
        raise InputError(f"alpha must be a number >= 0, got {alpha!r}")
    if not (isinstance(eps, int | float) and eps > 0):
        raise InputError(f"eps must be > 0, got {eps!r}")
    if var_pair not in ("sum", "min"):
        raise InputError(f"var_pair must be 'sum' or 'min', got {var_pair!r}")
    pair_min = var_pair == "min"
    var_cap = check_var_cap(var_cap)
    pair_min = pair_min and var_cap != float("inf")  # min(∞ · v_i, v_j) is v_j (0 · ∞ is NaN)
    if combine not in ("min", "product"):
        raise InputError(f"combine must be 'min' or 'product', got {combine!r}")
    if centre_weight not in ("one", "max"):
        raise InputError(f"centre_weight must be 'one' or 'max', got {centre_weight!r}")
    if isinstance(patch_trim, bool) or not isinstance(patch_trim, int | float):
        raise InputError(f"patch_trim must be a number >= 0 (inf: off), got {patch_trim!r}")
    if not patch_trim >= 0:
        raise InputError(f"patch_trim must be >= 0 (inf: off), got {patch_trim!r}")
    trim = var is not None and f > 0 and patch_trim != math.inf
    bw = check_param(k if var is not None else h, "k" if var is not None else "h", color)

    # Colour distance: d² = box(t) / (count · bw_i²); t is clamped at `upper` before the box
    # so that every clamped patch still has d² >= _MAX_DIST for every pixel.
    floor = bandwidth_floor(dtype)
    bw_max = max(param_max(bw), floor)
    n_patch = (2 * f + 1) ** 2
    a = float(alpha) if var is not None else 0.0
    upper = n_patch * (_MAX_DIST * bw_max * bw_max + a)
    inv_bw2: Param = (
        bw.clamp_min(floor).pow(-2) if isinstance(bw, Tensor) else 1.0 / max(bw, floor) ** 2
    )
    vmean = var.mean(dim=1, keepdim=True) if var is not None else None  # (B,1,H,W)
    vden = vmean + eps if vmean is not None else None
    n_ch = g.shape[1]
    upper_c = upper * n_ch  # the terms below are summed (not averaged) over channels
    tau_c = float(patch_trim) * n_ch  # cap of the largest context term (channels summed)
    cut = exp_cut(dtype)
    _, _, height, width = color.shape

    feats = _feature_terms(
        color, features, feature_k, feature_vars, feature_floor, feature_gradient, combine
    )
    # In-place arithmetic on per-offset temporaries when nothing needs a gradient (fewer
    # allocations); out-of-place otherwise, so autograd keeps the values it saved.
    inplace = not torch.is_grad_enabled() or not any(
        isinstance(t, Tensor) and t.requires_grad for t in (color, g, var, bw)
    )

    def colour_distance(win: Window) -> Tensor:
        """Patch distance d²(i, j) of the window's centre pixels, ``(B, 1, h, w)``."""
        dy, dx = win.dy, win.dx
        # Valid rows/cols of this offset: both i and j = i + (dy, dx) inside the image.
        vy0, vy1 = max(0, -dy), min(height, height - dy)
        vx0, vx1 = max(0, -dx), min(width, width - dx)
        y0, y1, x0, x1 = win.yi.start, win.yi.stop, win.xi.start, win.xi.stop
        # Patch region: one extra leading row/col is the cumulative sums' baseline.
        py0, py1 = max(y0 - f - 1, vy0), min(y1 + f, vy1)
        px0, px1 = max(x0 - f - 1, vx0), min(x1 + f, vx1)
        ui = g[:, :, py0:py1, px0:px1]
        uj = g[:, :, py0 + dy : py1 + dy, px0 + dx : px1 + dx]
        d = uj - ui
        t = (d.square_() if inplace else d.square()).sum(dim=1, keepdim=True)  # (B,1,·,·)
        if vmean is not None and vden is not None:
            vi = vmean[:, :, py0:py1, px0:px1]
            vj = vmean[:, :, py0 + dy : py1 + dy, px0 + dx : px1 + dx]
            vmin = torch.minimum(vi, vj)
            if pair_min and var_cap != 1:
                vj = torch.minimum(vi * var_cap, vj)
            den = vden[:, :, py0:py1, px0:px1] + (vmin if pair_min and var_cap == 1 else vj)
            # C · (mean Δ² - α (v_i + min)) / (ε + v_i + (min or v_j))
            if inplace:
                t.add_(vmin.add_(vi), alpha=-a * n_ch).div_(den)
            else:
                t = torch.add(t, vi + vmin, alpha=-a * n_ch) / den
        t = t.clamp_(max=upper_c) if inplace else t.clamp(max=upper_c)
        pad = (px0 - (x0 - f - 1), (x1 + f) - px1, py0 - (y0 - f - 1), (y1 + f) - py1)
        if any(pad):
            t = F.pad(t, pad)  # zero terms outside the valid region
        if trim:  # Σ_p t_p - (max_{p≠0} t_p - τ)⁺
            if inplace:
                ring = _ring_max(t, f, inplace=True).sub_(tau_c).clamp_min_(0.0)
                t = _box_sums(t, f).sub_(ring)
            else:
                t = _box_sums(t, f) - (_ring_max(t, f) - tau_c).clamp_min(0.0)
        else:
            t = _box_sums(t, f)  # (B,1,h,w)
        # Number of valid pairs in each clipped patch (separable), folded into one scale.
        cy = _counts(y0, y1, f, vy0, vy1, t)
        cx = _counts(x0, x1, f, vx0, vx1, t)
        scale = win.param(inv_bw2) * (1.0 / n_ch)
        if cy is None and cx is None:
            return t * (scale / n_patch)
        n = 2 * f + 1
        ry = (1.0 / cy).view(-1, 1) if cy is not None else 1.0 / n
        rx = (1.0 / cx).view(1, -1) if cx is not None else 1.0 / n
        return t * (ry * rx * scale)

    refuse = centre_weight == "max"

    def weight_fn(win: Window) -> Tensor:
        e = colour_distance(win).clamp(0.0, cut)
        if refuse:
            # Distances at or above _MAX_DIST are where the clamp of the terms put them, not
            # what they are: they count as 0, so that a pixel whose neighbours are all refused
            # keeps its own value instead of taking the centre weight of tied refusals.
            e = torch.where(e >= _MAX_DIST, cut, e)
        if feats is not None:
            e = feats(win, e)
        return neg_exp(e)

    return accumulate_weighted(color, weight_fn, 2 * r + 1, centre=centre_weight, tile=tile)


def _box_sums(t: Tensor, f: int) -> Tensor:
    """Sums over ``(2f+1)²`` windows of ``t`` ``(B, 1, h + 2f + 1, w + 2f + 1)`` -> ``(B, 1, h, w)``.

    The first row and column of ``t`` are a baseline that no window includes. Separable
    cumulative sums (cost independent of ``f``); for ``f <= 2`` the ``2f`` shifted additions per
    axis are cheaper than a scan and are used instead (same sums, different rounding).
    """
    n = 2 * f + 1
    if f <= 2:
        w = t.shape[-1] - n
        acc = t[..., 1 : 1 + w]
        for m in range(2, n + 1):
            acc = acc + t[..., m : m + w]
        h = acc.shape[-2] - n
        out = acc[:, :, 1 : 1 + h]
        for m in range(2, n + 1):
            out = out + acc[:, :, m : m + h]
        return out
    cs = t.cumsum(dim=3)
    t = cs[..., n:] - cs[..., :-n]  # horizontal box sums
    cs = t.cumsum(dim=2)
    return cs[:, :, n:] - cs[:, :, :-n]


def _ring_max(t: Tensor, f: int, inplace: bool = False) -> Tensor:
    """Largest term of each ``(2f+1)²`` window of ``t`` (laid out as for :func:`_box_sums`)
    except its centre, ``(B, 1, h, w)``: running maxima of shifted views (the rows above and
    below the centre from one horizontal ``2f+1`` maximum, then the centre row's two sides),
    about as cheap as the box sums; ``max_pool2d`` was 3x slower on these small maps. With
    ``inplace`` the running maxima overwrite their own new buffers (no autograd)."""
    n = 2 * f + 1
    h, w = t.shape[-2] - n, t.shape[-1] - n

    def fold(acc: Tensor, other: Tensor) -> Tensor:
        return torch.maximum(acc, other, out=acc) if inplace else torch.maximum(acc, other)

    row = torch.maximum(t[..., 1 : 1 + w], t[..., 2 : 2 + w])
    for m in range(3, n + 1):
        row = fold(row, t[..., m : m + w])  # max over the window's columns
    rows = [*range(1, f + 1), *range(f + 2, n + 1)]  # the rows above and below the centre
    out = torch.maximum(row[:, :, rows[0] : rows[0] + h], row[:, :, rows[1] : rows[1] + h])
    for m in rows[2:]:
        out = fold(out, row[:, :, m : m + h])
    mid = t[:, :, f + 1 : f + 1 + h]
    for m in rows:  # the centre row, centre excluded (the same offsets, along x)
        out = fold(out, mid[..., m : m + w])
    return out


def _counts(a0: int, a1: int, f: int, v0: int, v1: int, like: Tensor) -> Tensor | None:
    """Patch extent along one axis for outputs ``a0..a1-1`` clipped to ``[v0, v1)``; ``None``
    when no patch is clipped (every count is ``2f+1``)."""
    if a0 - f >= v0 and a1 - 1 + f < v1:
        return None
    pos = torch.arange(a0, a1, device=like.device, dtype=like.dtype)
    lo = (pos - f).clamp_min(v0)
    hi = (pos + f).clamp_max(v1 - 1)
    return hi - lo + 1


def _feature_terms(
    color: Tensor,
    features: Features | None,
    feature_k: object,
    feature_vars: object,
    feature_floor: object,
    feature_gradient: bool,
    combine: str,
):
    """Build ``fn(win, e) -> e'`` combining the colour exponent ``e`` with feature exponents."""
    feats = named_features(features)
    if not feats:
        return None
    names = [n for n, _ in feats]
    ks = per_feature(feature_k, names, "feature_k")
    fvars = per_feature(feature_vars, names, "feature_vars")
    floors = per_feature(feature_floor, names, "feature_floor")
    dtype = color.dtype
    floor = bandwidth_floor(dtype)
    # All features are stacked into one tensor, so the difference and its square cost one op
    # each whatever the number of features; then per feature: channel sum, per-pixel scale
    # 1/(C_f k_f² N_f,i), max (or sum). (Measured fastest on CPU: a grouped 1×1 convolution
    # for the per-feature sums was 10x slower on these strided tiles.)
    f_list: list[Tensor] = []
    scales: list[Tensor] = []
    b, _, h, w = color.shape
    for (name, ft), kf, fv, fl in zip(feats, ks, fvars, floors):
        ft = check_image(ft, name).to(dtype)
        check_same_size(color, ft, name)
        kp = check_param(kf, f"feature_k[{name}]", color)
        fvar = check_variance(fv, ft, f"feature_vars[{name}]") if fv is not None else None
        fl_v = check_param(fl, f"feature_floor[{name}]", color)
        norm = feature_normalizer(ft, fvar, float(fl_v), use_gradient=feature_gradient)
        inv_k2 = (
            kp.clamp_min(floor).pow(-2) if isinstance(kp, Tensor) else 1.0 / max(kp, floor) ** 2
        )
        sc = inv_k2 / (norm * ft.shape[1])  # float, 0-d, (B,1,1,1) or (B,1,H,W)
        sc = sc.expand(b, 1, h, w) if isinstance(sc, Tensor) else color.new_full((b, 1, h, w), sc)
        f_list.append(ft)
        scales.append(sc)
    fstack = torch.cat(f_list, dim=1)  # (B, ΣC, H, W)
    fscale = torch.cat(scales, dim=1)  # (B, F, H, W)
    bounds: list[tuple[int, int]] = []
    c0 = 0
    for ft in f_list:
        bounds.append((c0, c0 + ft.shape[1]))
        c0 += ft.shape[1]

    def apply(win: Window, e: Tensor) -> Tensor:
        d = win.neighbour(fstack) - win.centre(fstack)  # (B,ΣC,h,w)
        d = d.square() if d.requires_grad else d.mul_(d)
        sc = win.centre(fscale)  # (B,F,h,w)
        for i, (a, z) in enumerate(bounds):
            per = d[:, a:z].sum(dim=1, keepdim=True) if z - a > 1 else d[:, a:z]
            per = per * sc[:, i : i + 1]
            e = torch.maximum(e, per) if combine == "min" else e + per
        return e

    return apply


class NonLocalMeans(nn.Module):
    """Module form of :func:`non_local_means` with fixed settings.

    Bandwidths given to the constructor are defaults; :meth:`forward` accepts per-call
    (e.g. per-pixel, network-predicted) ``k`` / ``h`` / ``feature_k``.

    Example:
        >>> m = NonLocalMeans(search_radius=2, patch_radius=1)
        >>> x = torch.rand(1, 3, 8, 8)
        >>> m(x, color_var=torch.full((1, 1, 8, 8), 0.01)).shape
        torch.Size([1, 3, 8, 8])
    """

    def __init__(
        self,
        search_radius: int = 10,
        patch_radius: int = 3,
        k: float = 0.45,
        alpha: float = 4.0,
        *,
        h: float | None = None,
        var_pair: Literal["sum", "min"] = "sum",
        var_cap: float = 1.0,
        feature_k: float | list[float] | dict[str, float] = 1.0,
        feature_floor: float | list[float] | dict[str, float] = 1e-3,
        feature_gradient: bool = True,
        combine: Literal["min", "product"] = "min",
        eps: float = NLM_EPS,
        centre_weight: Literal["one", "max"] = "one",
        patch_trim: float = math.inf,
        tile: int | tuple[int, int] | None = None,
    ) -> None:
        super().__init__()
        self.search_radius = check_radius(search_radius, "search_radius")
        self.patch_radius = check_radius(patch_radius, "patch_radius")
        self.k = k
        self.alpha = alpha
        self.h = h
        self.var_pair = var_pair
        self.var_cap = var_cap
        self.feature_k = feature_k
        self.feature_floor = feature_floor
        self.feature_gradient = feature_gradient
        self.combine = combine
        self.eps = eps
        self.centre_weight = centre_weight
        self.patch_trim = patch_trim
        self.tile = tile

    def forward(
        self,
        color: Tensor,
        *,
        color_var: Tensor | None = None,
        k: Param | None = None,
        h: Param | None = None,
        guide: Tensor | None = None,
        features: Features | None = None,
        feature_k: Param | list[Param] | dict[str, Param] | None = None,
        feature_vars: list[Tensor | None] | dict[str, Tensor | None] | None = None,
    ) -> Tensor:
        """See :func:`non_local_means`; ``None`` bandwidths use the constructor's values."""
        return non_local_means(
            color,
            search_radius=self.search_radius,
            patch_radius=self.patch_radius,
            k=self.k if k is None else k,
            alpha=self.alpha,
            color_var=color_var,
            var_pair=self.var_pair,
            var_cap=self.var_cap,
            h=(self.h if h is None else h) if color_var is None else None,
            guide=guide,
            features=features,
            feature_k=self.feature_k if feature_k is None else feature_k,
            feature_vars=feature_vars,
            feature_floor=self.feature_floor,
            feature_gradient=self.feature_gradient,
            combine=self.combine,
            eps=self.eps,
            centre_weight=self.centre_weight,
            patch_trim=self.patch_trim,
            tile=self.tile,
        )

    def extra_repr(self) -> str:
        return (
            f"search_radius={self.search_radius}, patch_radius={self.patch_radius}, "
            f"k={self.k}, alpha={self.alpha}, h={self.h}, combine={self.combine!r}"
        )
