"""Fireflies: pixels whose value is one rare, very bright sample, found and clamped before filtering.

A firefly is a pixel where one of a handful of samples found a rare, high-energy path (a
caustic through glass, a small light seen in a glossy lobe). Its value is ``X / n`` for that
sample's radiance ``X`` and ``n`` samples per pixel, orders of magnitude above the pixels
around it; its estimated variance of the mean is about its value squared. Left in, it defeats
the filters: the feature terms of a pixel on a curved glass surface refuse every neighbour,
so the pixel keeps its own value (``nlm`` at 2 spp on the demo's ``caustics_glass``: relMSE
43, the noisy input's 45), and a cross-bilateral pixel next to it takes a share of it.

**What is detected** (:func:`detect_fireflies`), per pixel, on the luminance ``L`` (channel
mean) of the colour -- of the irradiance ``colour / (albedo + ε)`` when there is an albedo, so
that a texture edge is not taken for an outlier and the statistic is the one the filters
average -- and its variance of the mean ``v``:

* ``L > ref``, with ``ref = ref_factor × q75`` and ``q75`` the 75th percentile of ``L`` over
  the ``(2·radius + 1)²`` window (5×5, the pixel included). A percentile is robust to up to a
  quarter of the window being outliers (6 of 25 pixels), and a factor 2 over the upper
  quartile leaves ordinary Monte Carlo noise and texture alone;
* and the pixel's own noise does not vouch for its value: ``L - sigmas · √v < ref`` (3σ).
  A legitimate highlight -- a small light, the bright side of a sharp edge -- is bright *and*
  precise (all its samples agree, ``v ≈ 0``), so the reference level is far outside its
  confidence interval and it is kept; a firefly's ``√v`` is about its value (one sample of
  ``n`` carries it), so the reference level is inside the interval.

**Dense outliers are the region's noise, not fireflies.** At 2 spp a region lit through a
narrow opening or a small glossy reflection gets its light from rare bright samples: on the
robust subset's ``interior_door`` 14 % of the pixels pass both tests (2364 of 16384), most of
them only 10-25× their surroundings. Clamping them all takes the region's light away (``nlm``
relMSE 0.061, 12× OIDN's; 0.015 with no clamp at all), while the filters average them well
once they are left in. A detected pixel is therefore left alone where more than
:data:`DENSE_FRACTION` (10 %) of the ``(2·DENSE_RADIUS + 1)²`` window (15×15) around it is
detected too, unless it still holds more than :data:`EXTREME_FACTOR` / 49 of its 7×7
window's energy (its luminance over the 7×7 mean, itself included, above 8): the caustic's
fireflies, 100-1000× their surroundings, are clamped however dense they are. Only at
:data:`~mcdenoise.prep.variance.MAX_SPP` (8) samples per pixel or fewer (or an unknown count):
at 16 spp it changed the clamp of one held-out image in 35 (``random_s2000_00002``: 147
pixels -> 91), and that image's relMSE rose 1-3.5 % for the four methods that clamp. Measured,
``nlm`` / ``cross-bilateral`` relMSE, 2 spp: ``interior_door`` 0.0606/0.0749 ->
0.0193/0.0331, ``caustics_glass`` 0.0323/0.0375 -> 0.0303/0.0361; 4 spp: 0.0131/0.0233 ->
0.0093/0.0186 and 0.0229/0.0281 -> 0.0227/0.0280 (``docs/results/robustness.md``). Either
rule alone fails: by density only, the caustic at 2 spp went to 0.50 (its fireflies are dense
too); by the energy share only, the caustics at 32 spp went from 0.025 to 0.74 (two fireflies
side by side share a window's energy).

This is the rule of Blender Cycles' former NLM denoiser (``kernel_filter_detect_outliers`` in
``intern/cycles/kernel/filter/filter_prefilter.h``, Cycles 2.8x: 5×5 window, twice the 75th
percentile, 3σ), without its second trigger (a variance above 9× the largest neighbour's,
with an absolute offset tuned to Cycles' radiance units), which would also fire on the
anti-aliased edge of a light. With one sample per pixel the renderer's variance is 0 or absent;
the caller then passes :func:`~mcdenoise.prep.inputs.estimate_variance`'s estimate, which
gives a pixel brighter than its 3×3 median by 4 noise levels the squared excess as its
variance, so the same test applies.

Per-sample methods are out of reach: Zirr, Hanika and Dachsbacher 2018 ("Re-weighting
firefly samples for improved finite-sample Monte Carlo estimates") split the samples into
buffers by their luminance as they are rendered, and DeCoro, Weyrich and Rusinkiewicz 2010
("Density-based outlier rejection in Monte Carlo rendering") need the samples themselves; an
EXR holds the per-pixel mean and variance only.

**What is done** with a detected pixel (:func:`remove_fireflies`, ``mode``):

* ``"clamp"``: its colour is scaled by ``ref / L`` (the hue is kept), its variance by the
  square of that factor (Cycles does the same). Energy bias: the excess ``(1 - ref / L)·c`` is
  dropped; it is negative, and its size is the energy the image's fireflies carry above the
  reference level -- the rare-path energy the render has sampled only by those pixels.
  Measured in ``docs/results/bias.md`` ("Fireflies").
* ``"keep-energy"``: the same clamp, and the excess is added to the pixels of the
  ``(2·spread + 1)²`` window around it (itself excluded) in proportion to their similarity in
  albedo and normal (``exp(-|Δa|² / 2σ_a² - |Δn|² / 2σ_n²)``, the filters' bandwidths 0.1 and
  0.3), so that it stays on the surface it landed on and does not bleed across an albedo
  edge. The sum of the colour over the image is unchanged up to rounding (its bias is 0
  before the filter runs); the price is a blotch of ``excess / (window pixels)`` per pixel
  around each firefly, which the filter smooths but cannot remove.
* ``"off"``: nothing.

The classical filters (``nlm``, ``cross-bilateral``) and the Kalantari models
(``kalantari-nlm``, ``kalantari-xbf``) run with ``"clamp"`` by default (``-p
fireflies=...``): a single pixel's energy spread or kept costs far more error than the energy
is worth to the images of the demo (``docs/results/bias.md``). ``kpcn`` (trained end to end on
unclamped inputs) and OIDN (which handles its own outliers) do not use it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.albedo import ALBEDO_EPS
from mcdenoise.filters.box import box_mean

#: The modes of :func:`remove_fireflies` (``-p fireflies=...``).
FIREFLY_MODES: tuple[str, ...] = ("clamp", "keep-energy", "off")
#: Window radius of the reference statistic (5×5, as Cycles).
RADIUS = 2
#: Percentile of the window the reference is a multiple of, and that multiple.
REF_QUANTILE = 0.75
REF_FACTOR = 2.0
#: A pixel whose value the reference level lies within this many standard deviations of is
#: an outlier (if it is above the reference).
SIGMAS = 3.0
#: Radius of the window (15×15) whose share of detected pixels decides whether they are the
#: region's noise, and that share (see the module docstring).
DENSE_RADIUS = 7
DENSE_FRACTION = 0.1
#: A detected pixel whose luminance is above this multiple of its 7×7 mean (itself included:
#: at most 49) is clamped however dense the detections around it are.
EXTREME_RADIUS = 3
EXTREME_FACTOR = 8.0
#: Radius of the window the excess energy goes to in ``"keep-energy"`` mode (15×15).
SPREAD = 7
#: Albedo and normal bandwidths of the ``"keep-energy"`` weights (the filters' defaults).
SIGMA_ALBEDO = 0.1
SIGMA_NORMAL = 0.3
#: Rows processed at a time by the window statistics (memory: 25 taps of a band).
_BAND_ROWS = 256


@dataclass
class FireflyResult:
    """What :func:`remove_fireflies` did.

    Attributes:
        color: ``(B, 3, H, W)`` the colour with the fireflies handled.
        variance: ``(B, 1, H, W)`` its variance of the mean (clamped pixels scaled by the
            square of their factor).
        mask: ``(B, 1, H, W)`` bool, the detected pixels.
        removed: ``(B, 3)`` colour summed over the image that was taken out of detected
            pixels (before any redistribution).
    """

    color: Tensor
    variance: Tensor
    mask: Tensor
    removed: Tensor

    @property
    def count(self) -> int:
        """Number of detected pixels."""
        return int(self.mask.sum())


def check_mode(mode: str) -> str:
    """``mode`` if it is one of :data:`FIREFLY_MODES`, else an :class:`InputError`."""
    if mode not in FIREFLY_MODES:
        raise InputError(f"fireflies={mode!r}: expected one of {', '.join(FIREFLY_MODES)}")
    return mode


def _taps(x: Tensor, radius: int) -> Tensor:
    """``((2r+1)², B, C, H, W)`` the window's values, mirrored at the border (the border
    pixel itself is not repeated, so a firefly in a corner is counted once)."""
    h, w = x.shape[-2:]
    mode = "reflect" if min(h, w) > radius else "replicate"
    p = F.pad(x, (radius, radius, radius, radius), mode=mode)
    k = 2 * radius + 1
    return torch.stack([p[..., dy : dy + h, dx : dx + w] for dy in range(k) for dx in range(k)])


def window_quantile(x: Tensor, q: float, radius: int = RADIUS) -> Tensor:
    """The ``q`` quantile (lower order statistic, as Cycles: the value at index
    ``floor(q · n)`` of the sorted ``n`` window values) of each ``(2r+1)²`` window of the
    ``(B, C, H, W)`` tensor, computed a band of rows at a time."""
    n = (2 * radius + 1) ** 2
    kth = min(n, int(q * n) + 1)  # 1-based rank for kthvalue
    h = x.shape[-2]
    out = torch.empty_like(x)
    for y0 in range(0, h, _BAND_ROWS):
        y1 = min(h, y0 + _BAND_ROWS)
        c0, c1 = max(0, y0 - radius), min(h, y1 + radius)
        band = x[..., c0:c1, :]
        taps = _taps(band, radius)
        out[..., y0:y1, :] = taps.kthvalue(kth, dim=0).values[..., y0 - c0 : y1 - c0, :]
    return out


def detect_fireflies(
    lum: Tensor,
    var: Tensor,
    *,
    radius: int = RADIUS,
    ref_factor: float = REF_FACTOR,
    sigmas: float = SIGMAS,
) -> tuple[Tensor, Tensor]:
    """``(mask, ref)``, both ``(B, 1, H, W)``: the outlier pixels of the luminance ``lum``
    given its variance of the mean ``var``, and the reference level (see the module
    docstring)."""
    ref = ref_factor * window_quantile(lum, REF_QUANTILE, radius)
    mask = (lum > ref) & (lum - sigmas * var.clamp_min(0).sqrt() < ref)
    return mask, ref


def dense_noise(mask: Tensor, lum: Tensor) -> Tensor:
    """``(B, 1, H, W)`` bool: detected pixels (``mask``) that are the region's noise rather than
    fireflies -- more than :data:`DENSE_FRACTION` of their 15×15 window is detected, and they
    hold at most :data:`EXTREME_FACTOR` times their 7×7 window's mean luminance ``lum`` (see
    the module docstring)."""
    if not bool(mask.any()):
        return mask
    dense = box_mean(mask.to(lum.dtype), DENSE_RADIUS) > DENSE_FRACTION
    moderate = lum <= EXTREME_FACTOR * box_mean(lum, EXTREME_RADIUS)
    return mask & dense & moderate


def remove_fireflies(
    color: Tensor,
    var: Tensor,
    mode: str = "clamp",
    *,
    albedo: Tensor | None = None,
    normal: Tensor | None = None,
    albedo_eps: float = ALBEDO_EPS,
    spread: int = SPREAD,
    dense: bool = True,
) -> FireflyResult:
    """Detect and handle the fireflies of ``color`` (see the module docstring).

    Args:
        color: ``(B, 3, H, W)`` finite, non-negative linear colour.
        var: ``(B, 1, H, W)`` its (channel-mean) variance of the mean.
        mode: one of :data:`FIREFLY_MODES`.
        albedo: ``(B, 3, H, W)`` detection on the demodulated irradiance, and the
            ``"keep-energy"`` weights; optional.
        normal: ``(B, 3, H, W)`` for the ``"keep-energy"`` weights; optional.
        albedo_eps: the demodulation offset.
        spread: radius of the ``"keep-energy"`` window.
        dense: leave the dense, moderate detections alone (:func:`dense_noise`);
            :func:`~mcdenoise.prep.inputs.prepare_inputs` asks for it at 8 spp or fewer.

    Returns:
        A :class:`FireflyResult` (the inputs themselves, unchanged, when ``mode="off"``).
    """
    check_mode(mode)
    b = color.shape[0]
    if mode == "off":
        none = torch.zeros_like(var, dtype=torch.bool)
        return FireflyResult(color, var, none, color.new_zeros(b, color.shape[1]))
    lum = color.mean(dim=1, keepdim=True)
    mask, ref = detect_fireflies(lum, var)
    fac = ref / lum.clamp_min(1e-30)
    if albedo is not None:
        factor = albedo + albedo_eps
        irr = (color / factor).mean(dim=1, keepdim=True)
        irr_var = var / factor.square().mean(dim=1, keepdim=True)
        mask_irr, ref_irr = detect_fireflies(irr, irr_var)
        mask &= mask_irr
        fac = torch.minimum(fac, ref_irr / irr.clamp_min(1e-30))
        lum = irr
    if dense:
        mask &= ~dense_noise(mask, lum)
    fac = torch.where(mask, fac, torch.ones_like(fac))
    clamped = color * fac
    excess = color - clamped
    out_var = var * fac.square()
    removed = excess.sum(dim=(-2, -1))
    if mode == "keep-energy" and bool(mask.any()):
        clamped = clamped + _spread(excess, mask, albedo, normal, spread)
    return FireflyResult(clamped, out_var, mask, removed)


def _spread(
    excess: Tensor, mask: Tensor, albedo: Tensor | None, normal: Tensor | None, r: int
) -> Tensor:
    """The excess of each masked pixel shared among the ``(2r+1)²`` window's other in-image
    pixels, in proportion to their albedo and normal similarity; ``(B, 3, H, W)``."""
    _, c, h, w = excess.shape
    bi, _, yi, xi = mask.nonzero(as_tuple=True)
    d = torch.arange(-r, r + 1, device=excess.device)
    dy, dx = torch.meshgrid(d, d, indexing="ij")
    keep = (dy != 0) | (dx != 0)
    dy, dx = dy[keep], dx[keep]
    ys, xs = yi[:, None] + dy[None], xi[:, None] + dx[None]  # (N, K)
    inside = (ys >= 0) & (ys < h) & (xs >= 0) & (xs < w)
    ysc, xsc = ys.clamp(0, h - 1), xs.clamp(0, w - 1)
    bb = bi[:, None].expand_as(ys)
    logw = torch.zeros(ys.shape, dtype=excess.dtype, device=excess.device)
    for guide, sigma in ((albedo, SIGMA_ALBEDO), (normal, SIGMA_NORMAL)):
        if guide is None:
            continue
        g = guide.permute(0, 2, 3, 1)  # (B, H, W, C)
        diff = g[bb, ysc, xsc] - g[bi, yi, xi][:, None]
        logw -= diff.square().sum(-1) / (2 * sigma * sigma)
    wts = torch.where(inside, logw.exp(), torch.zeros_like(logw))
    total = wts.sum(dim=1, keepdim=True)
    # A firefly with no similar in-image neighbour (total 0) keeps its excess where it is.
    alone = total[:, 0] <= 0
    wts = wts / total.clamp_min(1e-30)
    out = torch.zeros_like(excess)
    src = excess.permute(0, 2, 3, 1)[bi, yi, xi]  # (N, C)
    share = src[:, None, :] * wts[..., None]  # (N, K, C)
    flat = out.permute(0, 2, 3, 1)  # a view: (B, H, W, C)
    flat.index_put_((bb.flatten(), ysc.flatten(), xsc.flatten()), share.reshape(-1, c), True)
    if bool(alone.any()):
        flat.index_put_((bi[alone], yi[alone], xi[alone]), src[alone], True)
    return out


def params_mode(params: Mapping[str, object], default: str = "clamp") -> str:
    """The ``fireflies`` entry of a method's parameters, checked."""
    return check_mode(str(params.get("fireflies", default)))


__all__ = [
    "FIREFLY_MODES",
    "FireflyResult",
    "check_mode",
    "dense_noise",
    "detect_fireflies",
    "params_mode",
    "remove_fireflies",
    "window_quantile",
]
