"""SVGF's history: reprojection of frame t-1 (``SVGFReproject``: bilinear taps kept when they
pass the depth and normal tests, Falcor's 3x3 fallback) and the exponential accumulation of
the illumination and its moments. Steps 2 and 3 of :mod:`mcdenoise.filters.svgf`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from mcdenoise.filters.svgf_guides import (
    MAX_LUMINANCE,
    Guides,
    SvgfSettings,
    luminance,
)
from mcdenoise.filters.warp import MIN_WEIGHT, TAP_OFFSETS, bilinear_taps, gather_flat, warp


# --------------------------------------------------------------------------------------------
# History
# --------------------------------------------------------------------------------------------
@dataclass
class History:
    """What frame ``t`` leaves to frame ``t + 1`` (all ``(B, C, H, W)``).

    Attributes:
        illumination: the feedback illumination (3 channels).
        moments: the accumulated luminance moments ``(m1, m2)``.
        length: the history length (1 channel).
        guides: the frame's :class:`Guides` (for the consistency tests).
    """

    illumination: Tensor
    moments: Tensor
    length: Tensor
    guides: Guides


def _tap_tests(
    g: Guides, prev: Guides, gathered: Callable[[Tensor], Tensor], s: SvgfSettings
) -> Tensor | None:
    """``isReprjValid`` for one set of taps: bool ``(B, 1, H, W)``, or ``None`` when there
    is nothing to test. ``gathered(t)`` reads a previous-frame tensor at the taps."""
    ok: Tensor | None = None
    if g.depth is not None and prev.depth is not None:
        assert g.depth_fwidth is not None
        zp = gathered(prev.depth)
        bg, bgp = g.depth <= 0, zp <= 0
        tol = s.depth_test * (g.depth_fwidth + s.depth_floor * g.depth)
        close = (zp - g.depth).abs() <= tol
        ok = (bg & bgp) | (~bg & ~bgp & close)
    if g.normal is not None and prev.normal is not None:
        assert g.normal_fwidth is not None
        npv = gathered(prev.normal)
        dist = (g.normal - npv).square().sum(1, keepdim=True).sqrt()
        near = dist <= s.normal_test * (g.normal_fwidth + 1e-2)
        ok = near if ok is None else ok & near
    return ok


def consistent_taps(
    g: Guides, prev: Guides, motion: Tensor, s: SvgfSettings, taps=None
) -> Tensor | None:
    """``isReprjValid`` per bilinear tap of ``motion``: bool ``(B, 4, H, W)`` (in
    :data:`~mcdenoise.filters.warp.TAP_OFFSETS` order), True where the previous frame's
    surface at the tap (``prev``'s depth and normal) is frame ``t``'s surface (``g``'s);
    ``None`` when neither frame has depth or normal. Used as the ``tap_valid`` of
    :func:`~mcdenoise.filters.warp.warp` by SVGF and by the temporal kpcn's own
    disocclusion test."""
    if taps is None:
        taps = bilinear_taps(motion, motion.dtype)
    tests = []
    for k in range(len(TAP_OFFSETS)):
        t = _tap_tests(g, prev, lambda x, k=k: gather_flat(x, taps.index[:, k]), s)
        if t is None:
            return None
        tests.append(t)
    return torch.cat(tests, 1)


def reproject(
    history: History,
    g: Guides,
    motion: Tensor,
    motion_valid: Tensor | None,
    s: SvgfSettings,
) -> tuple[Tensor, Tensor]:
    """The history of frame ``t - 1`` brought to frame ``t`` (``loadPrevData``).

    Returns:
        ``(values, ok)``: ``(B, 6, H, W)`` illumination (3), moments (2) and history length
        (1), 0 where there is none, and the ``(B, 1, H, W)`` bool mask of pixels with a
        history.
    """
    prev = history.guides
    packed = torch.cat([history.illumination, history.moments, history.length], 1)
    taps = bilinear_taps(motion, packed.dtype)
    tap_valid = consistent_taps(g, prev, motion, s, taps)
    # Falcor tests the screen bounds on the nearest previous pixel (``iposPrev``), for the
    # bilinear taps and the fallback alike: a pixel that comes from off the film has no history.
    trusted = _nearest_on_film(motion)
    if motion_valid is not None:
        trusted = trusted & (motion_valid > 0.5)
    values, mask = warp(
        packed,
        motion,
        valid=trusted.to(packed.dtype),
        tap_valid=tap_valid,
        taps=taps,
        min_weight=MIN_WEIGHT,
    )
    ok = mask > 0.5
    need = trusted & ~ok
    if bool(need.any()):
        values, ok = _fallback(values, ok, need, packed, g, prev, motion, s)
    return values, ok


def _nearest_on_film(motion: Tensor) -> Tensor:
    """``(B, 1, H, W)`` bool: the nearest previous pixel ``floor(p + motion + 0.5)`` is on the
    film (and the motion finite)."""
    _, _, h, w = motion.shape
    xs = torch.arange(w, dtype=motion.dtype, device=motion.device).view(1, 1, w)
    ys = torch.arange(h, dtype=motion.dtype, device=motion.device).view(1, h, 1)
    qx = torch.floor(xs + motion[:, 0] + 0.5)
    qy = torch.floor(ys + motion[:, 1] + 0.5)
    inside = (qx >= 0) & (qx <= w - 1) & (qy >= 0) & (qy <= h - 1)  # False for NaN
    return inside.unsqueeze(1)


def _fallback(
    values: Tensor,
    ok: Tensor,
    need: Tensor,
    packed: Tensor,
    g: Guides,
    prev: Guides,
    motion: Tensor,
    s: SvgfSettings,
) -> tuple[Tensor, Tensor]:
    """Falcor's fallback where the motion is trusted but no bilinear tap passed: the mean of
    the taps of the 3×3 block around the nearest previous pixel that pass the tests. Only
    the pixels in ``need`` are computed (a flat list)."""
    b, c, h, w = packed.shape
    flat = need.reshape(b, h * w)
    bi, pi = flat.nonzero(as_tuple=True)
    py, px = pi // w, pi % w
    m = motion.reshape(b, 2, h * w)[bi, :, pi].to(packed.dtype)  # (N, 2)
    qx = torch.floor(px.to(packed.dtype) + m[:, 0] + 0.5).clamp(-4, w + 4).long()
    qy = torch.floor(py.to(packed.dtype) + m[:, 1] + 0.5).clamp(-4, h + 4).long()

    def at(t: Tensor, bb: Tensor, yy: Tensor, xx: Tensor) -> Tensor:  # (N, C)
        return t[bb, :, yy, xx]

    def cur(t: Tensor | None) -> Tensor | None:
        return None if t is None else at(t, bi, py, px)

    total = torch.zeros(bi.shape[0], c, dtype=packed.dtype, device=packed.device)
    count = torch.zeros(bi.shape[0], 1, dtype=packed.dtype, device=packed.device)
    z, zf, n, nf = cur(g.depth), cur(g.depth_fwidth), cur(g.normal), cur(g.normal_fwidth)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            ty, tx = qy + dy, qx + dx
            inside = (tx >= 0) & (tx < w) & (ty >= 0) & (ty < h)
            cy, cx = ty.clamp(0, h - 1), tx.clamp(0, w - 1)
            good = inside
            if z is not None and prev.depth is not None and zf is not None:
                zp = at(prev.depth, bi, cy, cx)[:, 0]
                zc = z[:, 0]
                bg, bgp = zc <= 0, zp <= 0
                tol = s.depth_test * (zf[:, 0] + s.depth_floor * zc)
                good = good & ((bg & bgp) | (~bg & ~bgp & ((zp - zc).abs() <= tol)))
            if n is not None and prev.normal is not None and nf is not None:
                npv = at(prev.normal, bi, cy, cx)
                dist = (n - npv).square().sum(1).sqrt()
                good = good & (dist <= s.normal_test * (nf[:, 0] + 1e-2))
            v = at(packed, bi, cy, cx)
            total = total + torch.where(good[:, None], v, torch.zeros_like(v))
            count = count + good[:, None].to(packed.dtype)
    found = count[:, 0] > 0
    avg = total / count.clamp_min(1.0)
    values = values.clone()
    ok = ok.clone()
    sel_b, sel_p = bi[found], pi[found]
    vflat = values.reshape(b, c, h * w)
    vflat[sel_b, :, sel_p] = avg[found]
    ok.reshape(b, h * w)[sel_b, sel_p] = True
    return values, ok


def accumulate(
    illumination: Tensor, reprojected: Tensor, ok: Tensor, s: SvgfSettings
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Temporal integration (``SVGFReproject``: ``main``).

    Returns ``(illumination, moments, variance, length)`` of the frame: the EMA'd
    illumination ``(B, 3, H, W)``, moments ``(B, 2, H, W)``, variance and history length
    ``(B, 1, H, W)``.
    """
    prev_illum, prev_m, prev_len = reprojected[:, :3], reprojected[:, 3:5], reprojected[:, 5:6]
    length = torch.where(ok, (prev_len + 1.0).clamp_max(s.max_history), torch.ones_like(prev_len))
    inv = 1.0 / length
    one = torch.ones_like(length)
    alpha = torch.where(ok, inv.clamp_min(s.alpha), one)
    alpha_m = torch.where(ok, inv.clamp_min(s.moments_alpha), one)
    lum = luminance(illumination).clamp(0.0, MAX_LUMINANCE)
    cur_m = torch.cat([lum, lum.square()], 1)
    moments = prev_m + alpha_m * (cur_m - prev_m)
    variance = (moments[:, 1:2] - moments[:, 0:1].square()).clamp_min(0.0)
    illum = prev_illum + alpha * (illumination - prev_illum)
    return illum, moments, variance, length
