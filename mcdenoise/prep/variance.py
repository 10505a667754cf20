"""A colour variance the filters can steer by at 1-4 samples per pixel.

The renderer's variance of the mean at a pixel is the sample variance of its ``n`` samples
over ``n``: an estimate with ``n - 1`` degrees of freedom. At 2 spp it is one squared
difference (relative standard deviation √2 for Gaussian samples, far worse for the skewed
samples of path tracing): most pixels get a value near 0 -- their two samples happened to
agree -- and a few a huge one. A pixel whose estimate came out near 0 refuses every
neighbour (its patch distance is divided by almost nothing), and a bright pixel whose two
samples agreed keeps its value: on the demo's ``caustics_glass`` at 2 spp, the sparse bright
samples of the caustic are neither averaged nor spread, and the region comes out at a third
of its brightness.

:func:`low_spp_variance` shrinks the pixel's estimate towards a **pooled** one, weighted by
degrees of freedom as a conjugate prior is (a scaled inverse-χ² prior worth ``ν₀`` degrees of
freedom, Gelman et al., *Bayesian Data Analysis*, section 3.3)::

    v = ((n - 1) · v_pixel + ν₀ · v_pooled) / (n - 1 + ν₀)

The methods ``nlm`` and ``cross-bilateral`` run with ``ν₀ = 3`` (``-p variance_prior``): the
pooled value has 3 times the pixel's weight at 2 spp, 1 time at 4, 0.43 at 8. Above
:data:`MAX_SPP` (8) the pixel's own estimate (15 or more degrees of freedom) is used as it
is: the NLM on the demo's ``caustics_glass`` at 16 spp went from relMSE 0.027 to 0.061 with
the prior (``docs/results/bias.md``). The pooled value (:func:`pooled_variance`) is the
weighted mean over the 7×7 window of

* **relative** variances ``v / (L̃² + ε)``, multiplied back by the pixel's own ``L̃²`` (``L̃``
  the 3×3 median of the luminance): Monte Carlo variance grows with the signal, so a dark
  pixel beside a light must not borrow the light's edge noise in absolute terms (it would
  then take the light in);
* weighted by similarity of albedo, normal and level ``log L̃`` (bandwidths 0.1, 0.3, 1): a
  light sharing the ceiling's albedo (the sample ``cornell``) lends nothing to the ceiling
  and borrows nothing from it (with the level term ``cross-bilateral`` on ``cornell_spp4``
  goes from relMSE 0.021 to 0.0050);
* not the clamped fireflies (:mod:`mcdenoise.prep.fireflies`, which runs first): what is left
  of their variance says how far off that pixel is, not how noisy its surface is.

A mean (not a median) is pooled because the variance of heavy-tailed noise lives in its rare
large values (a median would put the χ²'s median, 0.45 of its mean, everywhere). With 1 spp
there is no per-pixel estimate at all, and the image's noise-level function
(:func:`~mcdenoise.prep.inputs.estimate_variance`) is used as before. The feature variances
(albedo, normal, depth, position) are pooled the same way, without the level term.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
import torch.nn.functional as F
from torch import Tensor

from mcdenoise.filters.box import median3

#: Degrees of freedom the pooled variance is worth by default (see the module docstring).
PRIOR_DOF = 3.0
#: Above this many samples per pixel the per-pixel estimate is used as it is (see the module
#: docstring).
MAX_SPP = 8
#: ε of the relative variance ``v / (L̄² + ε)`` (a luminance of 0.01 is "dark").
REL_EPS = 1e-4
#: Radius of the pooling window (7×7).
POOL_RADIUS = 3
#: Bandwidths of the pooling weights per guide (the filters' defaults for albedo and normal).
POOL_SIGMAS: dict[str, float] = {"albedo": 0.1, "normal": 0.3, "level": 1.0}


def pooled_variance(
    var: Tensor,
    guides: Mapping[str, Tensor] | None = None,
    radius: int = POOL_RADIUS,
    exclude: Tensor | None = None,
    scale: Tensor | None = None,
    level: Tensor | None = None,
) -> Tensor:
    """Weighted mean ``(B, 1, H, W)`` of ``var`` over each ``(2r+1)²`` window (in-image
    pixels only), weight ``exp(-Σ_g |g_i - g_j|² / 2σ_g²)`` over the guides given (albedo,
    normal; :data:`POOL_SIGMAS`), 1 without guides. Pixels of the bool mask ``exclude``
    (``(B, 1, H, W)``, the clamped fireflies) lend nothing to their neighbours: what is left
    of a firefly's variance after the clamp says how far off that one pixel is, not how noisy
    the surface around it is (lent, it lets the neighbours take the clamped pixel in).

    ``scale`` (``(B, 1, H, W)``, > 0): what is pooled is ``var / scale``, multiplied back by the
    borrower's ``scale`` (:func:`low_spp_variance` passes the squared local luminance, so
    relative variances are pooled)."""
    if scale is not None:
        return pooled_variance(var / scale, guides, radius, exclude, None, level) * scale
    h, w = var.shape[-2:]
    used = {n: g for n, g in (guides or {}).items() if n in POOL_SIGMAS}
    if level is not None:
        used["level"] = level
    pad = (radius, radius, radius, radius)
    pv = F.pad(var, pad)
    lend = torch.ones_like(var) if exclude is None else (~exclude).to(var.dtype)
    inside = F.pad(lend, pad)
    pg = {n: F.pad(g, pad, mode="replicate") for n, g in used.items()}
    num = torch.zeros_like(var)
    den = torch.zeros_like(var)
    k = 2 * radius + 1
    for dy in range(k):
        for dx in range(k):
            wt = inside[..., dy : dy + h, dx : dx + w].clone()
            if dy == radius and dx == radius:
                wt.fill_(1.0)  # the pixel's own estimate always counts
            for n, g in used.items():
                d = (pg[n][..., dy : dy + h, dx : dx + w] - g).square().sum(1, keepdim=True)
                wt.mul_(torch.exp(d.mul_(-0.5 / POOL_SIGMAS[n] ** 2)))
            num.addcmul_(wt, pv[..., dy : dy + h, dx : dx + w])
            den.add_(wt)
    return num / den  # den >= 1: the centre's own weight


def low_spp_variance(
    var: Tensor,
    spp: float | None,
    guides: Mapping[str, Tensor] | None = None,
    *,
    prior_dof: float = PRIOR_DOF,
    radius: int = POOL_RADIUS,
    exclude: Tensor | None = None,
    luminance: Tensor | None = None,
    max_spp: float = MAX_SPP,
) -> Tensor:
    """The pixel's variance of the mean shrunk towards the pooled one by degrees of freedom
    (see the module docstring); ``var`` itself when ``spp`` is unknown, above ``max_spp``, or
    ``prior_dof`` is 0.

    Args:
        var: ``(B, 1, H, W)`` per-pixel variance of the mean (from ``spp`` samples).
        spp: samples per pixel (``None``: unknown).
        guides: raw ``albedo`` / ``normal`` ``(B, 3, H, W)`` when present.
        exclude: ``(B, 1, H, W)`` bool, pixels that lend no variance (see
            :func:`pooled_variance`).
        luminance: ``(B, 1, H, W)`` the colour's luminance: when given, relative variances
            ``v / (L̃² + ε)`` are pooled (``L̃`` its 3×3 median: a dark pixel beside a light
            keeps a dark level, where a mean would take in the light), so a dark pixel next
            to a light does not borrow the light's edge noise in absolute terms (it would
            then take the light in).
    """
    if spp is None or prior_dof <= 0 or spp > max_spp:
        return var
    own = max(float(spp) - 1.0, 0.0)
    scale = level = None
    if luminance is not None:
        med = median3(luminance)
        scale = med.square() + REL_EPS
        level = 0.5 * scale.log()
    pooled = pooled_variance(var, guides, radius, exclude, scale, level)
    return (own * var + prior_dof * pooled) / (own + prior_dof)


__all__ = [
    "MAX_SPP",
    "POOL_RADIUS",
    "POOL_SIGMAS",
    "PRIOR_DOF",
    "low_spp_variance",
    "pooled_variance",
]
