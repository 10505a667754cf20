"""Crytek-style screen-space AO with a normal-oriented hemisphere of sample points.

Mittring's SSAO (Crytek, "Finding next gen: CryEngine 2", SIGGRAPH 2007 course) places
sample points in a sphere around the shaded point and counts those that lie *behind* the
depth buffer; the hemisphere variant (Filion & McNaughton 2008, popularised by J. Chapman's
2011 tutorial) orients the samples along the normal so a flat surface does not occlude
itself (the sphere version gives 0.5 there). What is implemented, per pixel ``P`` with normal
``n`` and AO radius ``r``:

1. ``samples`` kernel points ``k_i = l_i ω_i``: directions ``ω_i`` cosine-distributed
   over the hemisphere (so a point above an open surface stands for a cosine-weighted ray, as
   in the reference ``mcd_ao``), lengths ``l_i = lerp(0.1, 1, (i / N)²)`` (Chapman's scale:
   more points near the centre, where occluders matter most); fixed by ``seed``.
2. Per pixel the kernel is rotated about ``n`` by the angle ``2π ξ`` of the 4×4 interleaved
   noise (Crytek's 4×4 rotation texture) and placed at ``S_i = P + r k_i``.
3. ``S_i`` is projected; the G-buffer surface at that pixel (position ``Q``, normal
   ``n_Q``) occludes it when ``S_i`` lies behind it, ``n_Q · (S_i − Q) < −bias r`` (the
   depth comparison of the original made against the surface's tangent plane at ``Q``
   rather than its depth at the pixel centre: on surfaces seen at grazing angles the depth
   changes by a lot within one pixel, and the plain comparison makes a flat floor occlude
   itself), and ``Q`` is within the radius of the shaded point
   (``|Q - P| < r``: the *range check*, with the reference's step falloff; Chapman's
   ``smoothstep`` version fades instead). Samples off screen or on empty pixels count as open.
4. ``AO = 1 - Σ w_i occluded_i / N`` with ``w_i`` the falloff weight of ``|Q - P|``
   (1 for the step), then the 4×4 depth-aware box blur (:mod:`mcdenoise.ao.blur`).

What it estimates: the fraction of hemisphere *points* in front of the visible surfaces, a
volume measure, not the cosine-weighted fraction of blocked *rays* the reference computes;
open space behind a thin object also counts as occluded (the depth buffer has no thickness).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from mcdenoise.ao.blur import blur_passes, box_offsets
from mcdenoise.ao.geometry import ViewGBuffer, falloff_weight, interleaved_noise, norm3


def hemisphere_kernel(samples: int, seed: int = 0) -> Tensor:
    """``(N, 3)`` kernel points in the unit hemisphere around +z (see the module docstring)."""
    gen = torch.Generator().manual_seed(seed)
    u = torch.rand(samples, 2, generator=gen, dtype=torch.float64)
    # stratify the first coordinate so few samples still cover the hemisphere evenly
    u[:, 0] = (torch.randperm(samples, generator=gen).double() + u[:, 0]) / samples
    rho, phi = torch.sqrt(u[:, 0]), 2.0 * math.pi * u[:, 1]
    omega = torch.stack([rho * torch.cos(phi), rho * torch.sin(phi), torch.sqrt(1 - u[:, 0])], 1)
    i = torch.arange(samples, dtype=torch.float64) / samples
    scale = 0.1 + 0.9 * i * i
    return (omega * scale[:, None]).float()


def tangent_frame(n: Tensor) -> tuple[Tensor, Tensor]:
    """Two unit tangents ``(3, H, W)`` completing ``n`` ``(3, H, W)`` to an orthonormal
    frame (Frisvad-style branch on the larger component, no singularity)."""
    ref = torch.zeros_like(n)
    use_x = n[0].abs() < 0.9
    ref[0] = use_x.float()
    ref[1] = (~use_x).float()
    t = torch.cross(ref, n, dim=0)
    t = t / norm3(t, keepdim=True).clamp_min(1e-12)
    b = torch.cross(n, t, dim=0)
    return t, b


def ssao(
    g: ViewGBuffer,
    radius: float,
    *,
    samples: int = 16,
    bias: float = 0.01,
    falloff: float = 0.0,
    blur: bool = True,
    seed: int = 0,
) -> Tensor:
    """Hemisphere SSAO of the G-buffer ``g``; returns AO ``(H, W)`` in [0, 1], 1 on empty
    pixels (the reference's open-sky background).

    Args:
        radius: AO radius (scene units), the ray-traced AO's.
        samples: kernel points per pixel.
        bias: depth bias as a fraction of ``radius`` (against self-occlusion).
        falloff: fraction of ``radius`` over which occluders fade out (0: step).
        blur: apply the 4×4 depth-aware box blur.
        seed: kernel seed.
    """
    if samples < 1 or not radius > 0:
        raise ValueError(f"ssao: samples must be >= 1 and radius > 0, got {samples}, {radius}")
    h, w = g.shape
    dev = g.position.device
    kernel = hemisphere_kernel(samples, seed).to(dev)
    angle = 2.0 * math.pi * interleaved_noise(h, w, dev)[0]
    t, b = tangent_frame(g.normal)
    c, s = torch.cos(angle), torch.sin(angle)
    t, b = c * t + s * b, c * b - s * t  # rotate the tangent frame about n
    p = g.position
    occluded = torch.zeros(h, w, device=dev)
    for k in kernel.tolist():
        sp = p + radius * (k[0] * t + k[1] * b + k[2] * g.normal)
        u, v = g.project(sp)
        q, nq, ok = g.fetch_with_normal(u, v)
        dist = norm3(q - p)
        hit = ok & ((nq * (sp - q)).sum(0) < -bias * radius)
        occluded = occluded + hit.float() * falloff_weight(dist, radius, falloff)
    ao = 1.0 - occluded / samples
    if blur:
        ao = blur_passes(ao, g, [box_offsets(4)], radius)
    return torch.where(g.valid, ao, torch.ones_like(ao)).clamp(0.0, 1.0)


__all__ = ["hemisphere_kernel", "ssao", "tangent_frame"]
