"""NFOR: nonlinearly weighted first-order regression across two half buffers (Bitterli et al. 2016).

Bitterli, Rousselle, Moon, Iglesias-Guitián, Adler, Mitchell, Jarosz, Novák, "Nonlinearly
Weighted First-order Regression for Denoising Monte Carlo Renderings", CGF 35(4), 2016. This
module follows the public re-implementation by the first author, Tungsten's ``src/denoiser``
(``denoiser.cpp`` ``nforDenoiser``, ``Regression.cpp``, ``NlMeans.hpp``, commit 9117fdd), step
for step, in vectorised torch (CPU and CUDA). The renderer writes two half buffers ``A`` and
``B``: the means of two disjoint halves of each pixel's samples, so their noise is independent.

1. **Feature prefiltering** (paper 5.1): every feature channel of half ``A`` is filtered by
   NL-means whose weights come from the *other* half's patches (``B``), and vice versa
   (3×3... here 7×7 patches, 11×11 window, ``k = 0.5``; Tungsten's ``SimdNlMeans.denoise(3, 5,
   0.5, 2)``). A defocused or motion-blurred feature is as noisy as the colour.
2. **First-order regression** (5.2, :func:`collaborative_regression`): for every pixel ``i``
   a weighted least-squares fit of the colour of half ``A`` over the 19×19 window, on the
   design ``[1, Δx, Δy, f_j - f_i]`` (the prefiltered features of ``B``), with NL-means weights
   from ``B``'s colour patches (7×7, the minimum over channels of the per-channel weights).
   Every window's fit predicts all its pixels, and each pixel's output is the weighted mean of
   the predictions of every window that contains it ("collaborative" regression). Data and
   weights come from different halves, so the weights are not correlated with the noise they
   average (the cross-filtering of Rousselle et al. 2012). Done for ``A`` and ``B`` and for
   each bandwidth ``k`` of the candidate set (Tungsten: ``{0.5, 1}``).
3. **Selection by the two-buffer error** (5.3): for a candidate, ``(B - Â)² - Var(B)`` is an
   unbiased estimate of ``(Â - μ)²`` because ``Â`` does not depend on ``B``'s noise; with
   the same for ``B̂`` and the identity
   ``((Â + B̂)/2 - μ)² = ((Â - μ)² + (B̂ - μ)²)/2 - (Â - B̂)²/4`` this estimates the error of
   the candidate's output ``(Â + B̂)/2``, whatever the distribution of the noise. The estimates
   are smoothed by NL-means (3×3 patches, 19×19 window, ``k = 1``, guided by the full colour),
   each pixel and channel picks the candidate with the lowest estimate, the binary selection
   maps are smoothed by the same filter, and the candidates are blended by them.
4. **Second pass** (5.4): the blended halves are averaged, their half difference gives the
   variance ``(B - A)²/4`` of that average, the features are averaged and filtered once more
   (5×5 window), and one more regression (``k = 1``) on the combined buffer gives the output.

Departures from Tungsten, and why:

* Tungsten solves each window's system with a column-pivoted QR (rank-deficient windows --
  a feature constant over the window -- get a basic solution). Here each system is solved
  batched, in float64, after scaling every column to unit weighted RMS, with a small ridge
  (``ridge``) on every coefficient but the intercept, and a floor (``floor``, in units of the
  image's feature range) below which a feature's spread over the window counts as flat: a
  column that does not vary is shrunk to 0, as a pivoted QR drops it, and the residual noise
  of a flat prefiltered feature is not fitted.
* Features are scaled to a unit robust range over the image before the regression (the fit
  is invariant to that, the ridge and the floor are not).
* The candidate set and all radii are parameters; with more than two candidates the
  selection map becomes one map per candidate (one-hot, smoothed), which for two is
  Tungsten's ``lerp``.

Tungsten's own README warns that its re-implementation shows some residual noise and banding
from the depth feature; the figures of this implementation are in ``docs/results/nfor.md``.

Memory: every operator runs on output tiles with a halo as wide as its footprint (the result
does not depend on the tile size), so a 1-megapixel frame needs ``O(tile²)`` working memory
besides a few whole-image maps (the regression keeps each window offset's weights from its
moment pass for its reconstruction pass: 361 float32 maps of a 298² crop, 128 MB per tile,
bounded by :data:`WEIGHT_CACHE_BYTES`); tiles are shared by worker threads on the CPU
(:mod:`mcdenoise.filters.parallel`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor
from torch.nn import functional as F

from mcdenoise.errors import InputError
from mcdenoise.filters._common import check_image, check_same_size
from mcdenoise.filters.kernels import neg_exp
from mcdenoise.filters.nfor_weights import (
    TILE,
    WEIGHT_CACHE_BYTES,
    _distance,
    _offsets,
    _shifted,
    _tiled,
    check_inputs,
    nl_means,
)


@dataclass(frozen=True)
class NforSettings:
    """Parameters of :func:`nfor` (defaults: Tungsten's ``nforDenoiser``).

    Attributes:
        bandwidths: the candidate NL-means bandwidths ``k`` of the first regression pass.
        patch_radius: ``F`` of the regression weights (7×7 patches).
        search_radius: ``R`` of the regression window (19×19).
        prefilter_radius: search radius of the cross feature prefilter (11×11).
        prefilter_patch: patch radius of the feature prefilter.
        prefilter_k: bandwidth of the feature prefilter.
        error_patch: patch radius of the NL-means that smooths the error estimates and the
            selection maps (3×3; its window is ``search_radius``).
        error_k: bandwidth of that filter.
        second_pass: run the final regression on the combined halves (paper 5.4).
        final_k: bandwidth of the second regression.
        final_feature_radius: search radius of the second feature filter (5×5).
        ridge: ridge added to every scaled coefficient but the intercept.
        floor: squared feature spread (in units of the feature's range over the image) below
            which a feature counts as flat in a window.
        tile: output tile edge of every operator (memory bound; no effect on the result).
    """

    bandwidths: tuple[float, ...] = (0.5, 1.0)
    patch_radius: int = 3
    search_radius: int = 9
    prefilter_radius: int = 5
    prefilter_patch: int = 3
    prefilter_k: float = 0.5
    error_patch: int = 1
    error_k: float = 1.0
    second_pass: bool = True
    final_k: float = 1.0
    final_feature_radius: int = 2
    ridge: float = 1e-3
    floor: float = 1e-4
    tile: int = TILE


# --------------------------------------------------------------------------- NL-means weights


# ------------------------------------------------------------------------ first-order regression


def _upper(nf: int) -> tuple[Tensor, Tensor]:
    """Row and column indices of the upper triangle (diagonal included) of an ``nf × nf``."""
    return torch.triu_indices(nf, nf)


def _regression_crop(
    image: Tensor,
    guide: Tensor,
    var: Tensor,
    feats: Tensor,
    f: int,
    r: int,
    k: float,
    var_scale: float,
    ridge: float,
    floor: float,
) -> Tensor:
    """Tungsten's ``collaborativeRegression`` on one crop (see :func:`collaborative_regression`).

    The normal equations of the window of ``i`` use centred features ``f_j - f_i``; they are
    assembled from the window moments ``Σ w z_j`` of per-pixel products
    ``z = [1, f, y, f fᵀ, f yᵀ]`` (and ``Σ w Δx z``, ``Σ w Δy z`` for the linear ones), one
    float64 multiply-add per offset instead of forming the products per offset; centring
    then subtracts the ``f_i`` terms. Features are centred on the crop's mean first, so the
    moments stay of the order of the features' spread.
    """
    b, _, h, w = image.shape
    nf = feats.shape[1]
    d = 3 + nf
    feats = feats - feats.mean(dim=(2, 3), keepdim=True)
    f64 = feats.double()
    y64 = image.double()
    iu, ju = _upper(nf)
    ff = f64[:, iu] * f64[:, ju]  # (B, nf(nf+1)/2, H, W)
    fy = (f64[:, :, None] * y64[:, None]).flatten(1, 2)  # (B, 3 nf, H, W)
    ones = f64.new_ones((b, 1, h, w))
    z = torch.cat([ones, f64, y64, ff, fy], dim=1)  # (B, Z, H, W)
    nlin = 1 + nf + 3
    acc = torch.zeros_like(z)  # Σ w z
    acc_x = z.new_zeros((b, nlin, h, w))  # Σ w Δx [1, f, y]
    acc_y = z.new_zeros((b, nlin, h, w))  # Σ w Δy [1, f, y]
    acc_o = z.new_zeros((b, 3, h, w))  # Σ w Δx², Σ w Δx Δy, Σ w Δy²
    scale = 1.0 / max(r, 1)

    var_s = var * var_scale
    # The weights of every offset are kept from the moment pass for the reconstruction pass
    # (the same w_ij), unless they would exceed WEIGHT_CACHE_BYTES; then they are recomputed.
    cache: dict[tuple[int, int], tuple[Tensor, slice, slice] | None] | None = (
        {} if (2 * r + 1) ** 2 * b * h * w * image.element_size() <= WEIGHT_CACHE_BYTES else None
    )

    def weights(dy: int, dx: int) -> tuple[Tensor, slice, slice] | None:
        if cache is not None and (dy, dx) in cache:
            return cache.pop((dy, dx))
        got = _distance(guide, var_s, dy, dx, f, k, 1.0)
        res = None
        if got is not None:
            dist, ys, xs = got  # min over channels of exp(-d): Tungsten's convertWeight
            res = neg_exp(dist.amax(dim=1, keepdim=True).clamp_min_(0.0)), ys, xs
        if cache is not None:
            cache[(dy, dx)] = res
        return res

    offsets = _offsets(r)
    lin = [(dx * scale, dy * scale) for dy, dx in offsets]
    quads = z.new_tensor([[ox * ox, ox * oy, oy * oy] for ox, oy in lin]).view(-1, 1, 3, 1, 1)
    for o, (dy, dx) in enumerate(offsets):
        got = weights(dy, dx)
        if got is None:
            continue
        wt, ys, xs = got
        yj, xj = _shifted(ys, xs, dy, dx)
        ox, oy = dx * scale, dy * scale
        w64 = wt.double()
        acc[..., ys, xs].addcmul_(z[..., yj, xj], w64)
        if ox:
            acc_x[..., ys, xs].addcmul_(z[:, :nlin, yj, xj], w64, value=ox)
        if oy:
            acc_y[..., ys, xs].addcmul_(z[:, :nlin, yj, xj], w64, value=oy)
        if ox or oy:
            acc_o[..., ys, xs].addcmul_(w64.expand(-1, 3, -1, -1), quads[o])

    # Normal equations per pixel, design [1, Δx, Δy, f_j - f_i].
    n = b * h * w

    def rows(t: Tensor) -> Tensor:  # (B, C, H, W) -> (N, C)
        return t.permute(0, 2, 3, 1).reshape(n, t.shape[1])

    m, mx, my, mo, fi = rows(acc), rows(acc_x), rows(acc_y), rows(acc_o), rows(f64)
    s0, sf, sy = m[:, 0], m[:, 1 : 1 + nf], m[:, 1 + nf : nlin]
    sff = m[:, nlin : nlin + len(iu)]
    sfy = m[:, nlin + len(iu) :].view(n, nf, 3)
    a_mat = m.new_zeros((n, d, d))
    rhs = m.new_zeros((n, d, 3))
    a_mat[:, 0, 0] = s0
    a_mat[:, 0, 1] = a_mat[:, 1, 0] = mx[:, 0]
    a_mat[:, 0, 2] = a_mat[:, 2, 0] = my[:, 0]
    a_mat[:, 1, 1], a_mat[:, 1, 2], a_mat[:, 2, 2] = mo[:, 0], mo[:, 1], mo[:, 2]
    a_mat[:, 2, 1] = mo[:, 1]
    rhs[:, 0], rhs[:, 1], rhs[:, 2] = sy, mx[:, 1 + nf :], my[:, 1 + nf :]
    if nf:
        cf = sf - s0[:, None] * fi  # Σ w (f_j - f_i)
        a_mat[:, 0, 3:] = a_mat[:, 3:, 0] = cf
        a_mat[:, 1, 3:] = a_mat[:, 3:, 1] = mx[:, 1 : 1 + nf] - mx[:, :1] * fi
        a_mat[:, 2, 3:] = a_mat[:, 3:, 2] = my[:, 1 : 1 + nf] - my[:, :1] * fi
        full = m.new_zeros((n, nf, nf))
        full[:, iu, ju] = sff
        full[:, ju, iu] = sff
        # Σ w (f_j - f_i)(f_j - f_i)ᵀ = Σ w f fᵀ - s_f f_iᵀ - f_i s_fᵀ + s0 f_i f_iᵀ
        outer = fi[:, :, None] * fi[:, None, :]
        cov = full - sf[:, :, None] * fi[:, None, :] - fi[:, :, None] * sf[:, None, :]
        a_mat[:, 3:, 3:] = cov + s0[:, None, None] * outer
        rhs[:, 3:] = sfy - fi[:, :, None] * sy[:, None, :]
    beta = _solve(a_mat, rhs, ridge, floor)  # (N, d, 3)

    # Collaborative reconstruction: pixel j gets Σ_i w_ij β_iᵀ [1, Δx, Δy, f_j - f_i]
    # = Σ_i w_ij (c_i + Δx β_i1 + Δy β_i2) + (Σ_i w_ij β_if)ᵀ f_j, with c_i = β_i0 - β_ifᵀ f_i.
    bf = beta[:, 3:]  # (N, nf, 3)
    c = beta[:, 0] - (bf * fi[:, :, None]).sum(dim=1)

    def grid(t: Tensor) -> Tensor:  # (N, C) -> (B, C, H, W)
        return t.reshape(b, h, w, -1).permute(0, 3, 1, 2).to(image.dtype).contiguous()

    gc, g1, g2 = grid(c), grid(beta[:, 1]), grid(beta[:, 2])
    gf = grid(bf.reshape(n, 3 * nf)) if nf else None
    out = torch.zeros_like(image)
    outf = image.new_zeros((b, 3 * nf, h, w)) if nf else None
    wsum = image.new_zeros((b, 1, h, w))
    for dy, dx in _offsets(r):
        got = weights(dy, dx)
        if got is None:
            continue
        wt, ys, xs = got
        yj, xj = _shifted(ys, xs, dy, dx)
        pred = gc[..., ys, xs]
        if dx:
            pred = pred + g1[..., ys, xs] * (dx * scale)
        if dy:
            pred = pred + g2[..., ys, xs] * (dy * scale)
        out[..., yj, xj].addcmul_(pred, wt)
        if outf is not None and gf is not None:
            outf[..., yj, xj].addcmul_(gf[..., ys, xs], wt)
        wsum[..., yj, xj].add_(wt)
    if outf is not None:
        out = out + (outf.view(b, nf, 3, h, w) * feats.unsqueeze(2)).sum(dim=1)
    return out / wsum  # every pixel's own window gives it weight 1


def _solve(a_mat: Tensor, rhs: Tensor, ridge: float, floor: float) -> Tensor:
    """``β`` of the weighted least-squares systems ``A β = c`` ``(N, d, d)``, ``(N, d, 3)``.

    Columns are scaled to unit weighted RMS (not below ``floor`` times the weight sum), a ridge
    is added to every scaled coefficient but the intercept, and the system is solved by a
    Cholesky factorisation; a system that still fails (not expected: the scaled matrix plus
    the ridge is positive definite) falls back to the weighted mean.
    """
    diag = a_mat.diagonal(dim1=1, dim2=2)
    w0 = diag[:, :1].clamp_min(1e-30)
    lim = torch.cat([w0, (w0 * floor).expand(-1, diag.shape[1] - 1)], dim=1)
    s = torch.maximum(diag, lim).sqrt()  # (N, d)
    scaled = a_mat / (s[:, :, None] * s[:, None, :])
    reg = torch.full_like(s, ridge)
    reg[:, 0] = 0.0
    scaled = scaled + torch.diag_embed(reg)
    chol, info = torch.linalg.cholesky_ex(scaled)
    beta = torch.cholesky_solve(rhs / s[:, :, None], chol) / s[:, :, None]
    bad = (info != 0) | ~torch.isfinite(beta).flatten(1).all(dim=1)
    if bool(bad.any()):
        fallback = torch.zeros_like(beta)
        fallback[:, 0] = rhs[:, 0] / w0
        beta = torch.where(bad[:, None, None], fallback, beta)
    return beta


def collaborative_regression(
    image: Tensor,
    guide: Tensor,
    var: Tensor,
    features: Tensor | None,
    *,
    k: float,
    patch_radius: int = 3,
    search_radius: int = 9,
    var_scale: float = 2.0,
    ridge: float = 1e-3,
    floor: float = 1e-4,
    tile: int = TILE,
) -> Tensor:
    """First-order regression with NL-means weights, collaborative (Tungsten's
    ``collaborativeRegression``; paper section 5.2).

    For every pixel ``i``, ``β_i`` minimises ``Σ_j w_ij |y_j - β^T x_ij|²`` over the
    ``(2R+1)²`` window, ``x_ij = [1, (j - i)/R, f_j - f_i]``, with the NL-means weights ``w_ij``
    of ``guide`` (minimum over its channels). Each pixel ``j`` is then the ``w``-weighted mean
    of the predictions ``β_i^T x_ij`` of every window containing it.

    Args:
        image: ``(B, C, H, W)`` linear values to regress (a half buffer's colour).
        guide: ``(B, C_g, H, W)`` whose patches give the weights (the other half).
        var: ``(B, 1 or C_g, H, W)`` variance of the mean of ``guide`` (times ``var_scale``;
            Tungsten passes the full buffer's variance with 2).
        features: ``(B, F, H, W)`` regression features (prefiltered), or ``None``.
        k: NL-means bandwidth.
        patch_radius, search_radius: ``F`` (3) and ``R`` (9).
        ridge, floor: see :func:`_solve` and :class:`NforSettings`.
        tile: output tile edge (no effect on the result).

    Returns:
        ``(B, C, H, W)`` in ``image``'s dtype.

    Example:
        >>> x = torch.linspace(0, 1, 16).expand(1, 3, 16, 16).contiguous()
        >>> out = collaborative_regression(x, x, torch.full((1, 1, 16, 16), 1e-4), None,
        ...                                k=1.0, search_radius=3, patch_radius=1)
        >>> torch.allclose(out, x, atol=1e-4)  # a linear ramp is fitted exactly
        True
    """
    image, guide, var = check_inputs(image, guide, var)
    if var.shape[1] not in (1, guide.shape[1]):
        raise InputError(f"var must have 1 or {guide.shape[1]} channels, got {var.shape[1]}")
    var = var.expand(-1, guide.shape[1], -1, -1)
    feats = image.new_zeros((image.shape[0], 0, *image.shape[2:]))
    if features is not None and features.shape[1]:
        feats = check_image(features, "features").to(image.dtype)
        check_same_size(image, feats, "features", "image")
    if not (k > 0):
        raise InputError(f"k must be > 0, got {k!r}")

    def run(img: Tensor, g: Tensor, v: Tensor, ft: Tensor) -> Tensor:
        return _regression_crop(
            img, g, v, ft, patch_radius, search_radius, k, var_scale, ridge, floor
        )

    # A centre's fit reads R + F around it and predicts R around it: halo 2R + F.
    return _tiled(run, [image, guide, var, feats], 2 * search_radius + patch_radius, tile)


# ------------------------------------------------------------------------------------- tiling


# ------------------------------------------------------------------------------------- NFOR


def _feature_scale(f: Tensor) -> Tensor:
    """``(B, F, 1, 1)``: 1 / the robust range (1st to 99th percentile) of each channel."""
    flat = f.flatten(2)
    if flat.shape[-1] > 65536:  # a strided subsample is enough for two percentiles
        flat = flat[..., :: flat.shape[-1] // 65536 + 1]
    q = torch.quantile(flat, torch.tensor([0.01, 0.99], dtype=f.dtype, device=f.device), dim=-1)
    rng = (q[1] - q[0]).clamp_min(1e-3 * flat.abs().amax(dim=-1).clamp_min(1e-6))
    return (1.0 / rng)[..., None, None]


def nfor(
    color_a: Tensor,
    color_b: Tensor,
    var_a: Tensor,
    var_b: Tensor,
    features_a: Tensor | None = None,
    features_b: Tensor | None = None,
    feature_var_a: Tensor | None = None,
    feature_var_b: Tensor | None = None,
    *,
    guide: Tensor | None = None,
    guide_var: Tensor | None = None,
    settings: NforSettings | None = None,
) -> Tensor:
    """Denoise two half buffers with NFOR (see the module docstring for the steps).

    Args:
        color_a, color_b: ``(B, 3, H, W)`` linear HDR colour of the two halves, finite.
        var_a, var_b: ``(B, 1 or 3, H, W)`` variance of the mean of each half (about twice
            the full buffer's).
        features_a, features_b: ``(B, F, H, W)`` the feature channels of each half (albedo,
            normal, depth, ...; a noise-free feature is the same tensor in both), or ``None``.
        feature_var_a, feature_var_b: ``(B, F, H, W)`` their half variances; a feature with
            variance 0 is not prefiltered. ``None``: estimated from the halves,
            ``(A - B)²/2`` averaged over 3×3.
        guide, guide_var: the full buffer's colour and variance for the error filter
            (default ``(A + B)/2`` and ``(var_a + var_b)/4``).
        settings: :class:`NforSettings` (default: Tungsten's values).

    Returns:
        ``(B, 3, H, W)`` the denoised colour (not clamped).

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> clean = torch.full((1, 3, 24, 24), 0.5)
        >>> a = clean + 0.1 * torch.randn(1, 3, 24, 24, generator=g)
        >>> b = clean + 0.1 * torch.randn(1, 3, 24, 24, generator=g)
        >>> v = torch.full((1, 1, 24, 24), 0.01)
        >>> out = nfor(a, b, v, v, settings=NforSettings(search_radius=4))
        >>> bool((out - clean).square().mean() < ((a + b) / 2 - clean).square().mean() / 4)
        True
    """
    s = settings or NforSettings()
    if not s.bandwidths:
        raise InputError("nfor needs at least one bandwidth")
    ca = check_image(color_a, "color_a", channels=3)
    cb = check_image(color_b, "color_b", channels=3).to(ca.dtype)
    check_same_size(ca, cb, "color_b", "color_a")
    va = check_image(var_a, "var_a").to(ca.dtype)
    vb = check_image(var_b, "var_b").to(ca.dtype)
    for name, t in (("var_a", va), ("var_b", vb)):
        check_same_size(ca, t, name, "color_a")
        if t.shape[1] not in (1, 3):
            raise InputError(f"{name} must have 1 or 3 channels, got {t.shape[1]}")
    va, vb = va.expand(-1, 3, -1, -1).clamp_min(0), vb.expand(-1, 3, -1, -1).clamp_min(0)
    full = (ca + cb) * 0.5 if guide is None else check_image(guide, "guide").to(ca.dtype)
    full_var = (va + vb) * 0.25 if guide_var is None else check_image(guide_var, "guide_var")
    full_var = full_var.to(ca.dtype).expand(-1, 3, -1, -1)
    tile = s.tile

    # 1. Cross-prefiltered features (section 5.1).
    fa, fb = _prefiltered_features(ca, features_a, features_b, feature_var_a, feature_var_b, s)
    scale = _feature_scale((fa + fb) * 0.5) if fa.shape[1] else None
    fa_n = fa * scale if scale is not None else fa
    fb_n = fb * scale if scale is not None else fb

    def regress(img: Tensor, g: Tensor, v: Tensor, ft: Tensor, k: float) -> Tensor:
        return collaborative_regression(
            img, g, v, ft, k=k, patch_radius=s.patch_radius, search_radius=s.search_radius,
            var_scale=1.0, ridge=s.ridge, floor=s.floor, tile=tile,
        )  # fmt: skip

    # 2. Regression of each half with the other's weights and features, per bandwidth (5.2).
    outs_a, outs_b, errors = [], [], []
    for k in s.bandwidths:
        ra = regress(ca, cb, vb, fb_n, k)
        rb = regress(cb, ca, va, fa_n, k)
        # 3. Two-buffer error of (ra + rb) / 2 (section 5.3).
        mse_a = (cb - ra).square() - vb
        mse_b = (ca - rb).square() - va
        errors.append((mse_a + mse_b) * 0.5 - (rb - ra).square() * 0.25)
        outs_a.append(ra)
        outs_b.append(rb)
    if len(s.bandwidths) == 1:
        res_a, res_b = outs_a[0], outs_b[0]
    else:

        def smooth(x: Tensor) -> Tensor:
            return nl_means(
                x, full, full_var, patch_radius=s.error_patch, search_radius=s.search_radius,
                k=s.error_k, tile=tile,
            )  # fmt: skip

        err = smooth(torch.cat(errors, dim=1))  # (B, K·3, H, W)
        b, _, h, w = err.shape
        pick = err.view(b, -1, 3, h, w).argmin(dim=1, keepdim=True)
        onehot = torch.zeros_like(err.view(b, -1, 3, h, w)).scatter_(1, pick, 1.0)
        sel = smooth(onehot.view(b, -1, h, w)).view(b, -1, 3, h, w)
        sel = sel / sel.sum(dim=1, keepdim=True).clamp_min(1e-12)
        res_a = (torch.stack(outs_a, dim=1) * sel).sum(dim=1)
        res_b = (torch.stack(outs_b, dim=1) * sel).sum(dim=1)
    combined = (res_a + res_b) * 0.5
    if not s.second_pass:
        return combined

    # 4. Second pass on the combined buffer (section 5.4).
    comb_var = (res_b - res_a).square() * 0.25
    feats = fa.new_zeros(fa.shape)
    if fa.shape[1]:
        fmean = (fa + fb) * 0.5
        fvar = (fb - fa).square() * 0.25
        feats = nl_means(
            fmean, fmean, fvar, patch_radius=s.prefilter_patch,
            search_radius=s.final_feature_radius, k=s.prefilter_k, tile=tile,
        )  # fmt: skip
        feats = feats * scale
    return collaborative_regression(
        combined, combined, comb_var, feats, k=s.final_k, patch_radius=s.patch_radius,
        search_radius=s.search_radius, var_scale=2.0, ridge=s.ridge, floor=s.floor, tile=tile,
    )  # fmt: skip


def _prefiltered_features(
    like: Tensor,
    fa: Tensor | None,
    fb: Tensor | None,
    va: Tensor | None,
    vb: Tensor | None,
    s: NforSettings,
) -> tuple[Tensor, Tensor]:
    """The features of each half, NL-means filtered with the other half's weights."""
    if fa is None and fb is None:
        empty = like.new_zeros((like.shape[0], 0, *like.shape[2:]))
        return empty, empty
    if fa is None or fb is None:
        raise InputError("features_a and features_b must be given together")
    fa = check_image(fa, "features_a").to(like.dtype)
    fb = check_image(fb, "features_b").to(like.dtype)
    check_same_size(like, fa, "features_a", "color_a")
    if fa.shape != fb.shape:
        raise InputError(f"features_a {tuple(fa.shape)} and features_b {tuple(fb.shape)} differ")
    if va is None or vb is None:
        est = _box3((fa - fb).square() * 0.5)
        va = est if va is None else va
        vb = est if vb is None else vb
    va = check_image(va, "feature_var_a").to(like.dtype).expand_as(fa).clamp_min(0)
    vb = check_image(vb, "feature_var_b").to(like.dtype).expand_as(fb).clamp_min(0)
    noisy = ((va.flatten(2).amax(-1) > 0) | (vb.flatten(2).amax(-1) > 0)).any(0)  # (F,)
    idx = noisy.nonzero().flatten()
    if not len(idx):
        return fa, fb
    out_a, out_b = fa.clone(), fb.clone()

    def filt(img: Tensor, g: Tensor, v: Tensor) -> Tensor:
        return nl_means(
            img, g, v, patch_radius=s.prefilter_patch, search_radius=s.prefilter_radius,
            k=s.prefilter_k, tile=s.tile,
        )  # fmt: skip

    out_a[:, idx] = filt(fa[:, idx], fb[:, idx], vb[:, idx])
    out_b[:, idx] = filt(fb[:, idx], fa[:, idx], va[:, idx])
    return out_a, out_b


def _box3(x: Tensor) -> Tensor:
    return F.avg_pool2d(x, 3, stride=1, padding=1, count_include_pad=False)


__all__ = ["NforSettings", "collaborative_regression", "nfor"]
