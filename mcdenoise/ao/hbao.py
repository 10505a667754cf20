"""Horizon-based ambient occlusion (Bavoil, Sainz & Dimitrov, "Image-space horizon-based
ambient occlusion", SIGGRAPH 2008 talk; Bavoil & Sainz, ShaderX7 2009).

HBAO treats the depth buffer as a height field around the shaded point ``P`` and, along
``directions`` screen-space directions, marches ``steps`` samples out to the projection of the
AO radius ``r`` (``r_px = f r / z`` pixels). In each direction it tracks the *horizon*: the
highest elevation angle ``h`` of a sample above the tangent plane. The paper's occlusion of a
direction is ``sin h − sin t`` (``t`` the tangent angle), accumulated incrementally with an
attenuation ``W`` each time a sample raises the horizon:
``AO_dir = Σ W(|H_i|) (sin h_i − sin h_{i−1})``, and ``AO = 1 − mean over directions``.

Choices made here:

* The tangent plane comes from the G-buffer normal (HBAO+'s "normal" variant): the elevation
  of a sample ``Q`` is ``sin h = n · (Q − P) / |Q − P|``, so ``t = 0``; the running horizon
  starts at ``sin h = bias`` (NVIDIA's angle bias against tessellation self-occlusion).
* ``W`` is the reference's step (samples beyond ``r`` are ignored) unless ``falloff`` > 0;
  Bavoil's ``1 − ρ²/R²`` attenuation is not the ray-traced AO's falloff.
* Directions are rotated and steps jittered per pixel by the 4×4 interleaved noise, samples
  are snapped to pixel centres, and the result gets HBAO's cross-bilateral Gaussian blur
  (radius 4, separable as in HBAO+, :mod:`mcdenoise.ao.blur`).

What it estimates: ``sin h`` weights the hemisphere by solid angle (``dω = cos α dα dφ`` in
elevation ``α``), not by the cosine to the normal as the reference does: for a horizon at
elevation ``h`` the cosine-weighted occlusion would be ``sin² h``, so HBAO over-darkens
partial occlusion (the documented bias of the closed-form tests).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from mcdenoise.ao.blur import blur_passes, gaussian_line_offsets
from mcdenoise.ao.geometry import ViewGBuffer, falloff_weight, interleaved_noise, norm3


def hbao(
    g: ViewGBuffer,
    radius: float,
    *,
    directions: int = 8,
    steps: int = 4,
    bias: float = 0.05,
    falloff: float = 0.0,
    blur: bool = True,
) -> Tensor:
    """HBAO of the G-buffer ``g``; returns AO ``(H, W)`` in [0, 1], 1 on empty pixels.

    Args:
        radius: AO radius (scene units), the ray-traced AO's.
        directions: screen-space directions per pixel.
        steps: samples per direction.
        bias: sine of the angle bias (a horizon must rise above it to occlude).
        falloff: fraction of ``radius`` over which occluders fade out (0: step).
        blur: apply the depth-aware Gaussian blur (radius 4, an x and a y pass).
    """
    if directions < 1 or steps < 1 or not radius > 0:
        raise ValueError("hbao: directions, steps >= 1 and radius > 0 required")
    h, w = g.shape
    dev = g.position.device
    p, n = g.position, g.normal
    noise = interleaved_noise(h, w, dev)
    u0, v0 = g.pixel_grid()
    z = p[2].clamp_min(1e-6)
    r_px = g.focal * radius / z  # (H, W)
    occlusion = torch.zeros(h, w, device=dev)
    for d in range(directions):
        phi = 2.0 * math.pi * (d + noise[0]) / directions
        du, dv = torch.cos(phi), torch.sin(phi)
        sin_h = torch.full((h, w), bias, device=dev)
        ao_dir = torch.zeros(h, w, device=dev)
        for s in range(steps):
            frac = (s + noise[1]) / steps
            off = torch.clamp(frac * r_px, min=1.0)
            u = torch.round(u0 - 0.5 + du * off) + 0.5
            v = torch.round(v0 - 0.5 + dv * off) + 0.5
            q, ok = g.fetch(u, v)
            hv = q - p
            dist = norm3(hv)
            sin_new = (hv * n).sum(0) / dist.clamp_min(1e-12)
            wgt = falloff_weight(dist, radius, falloff) * ok.float()
            rise = (sin_new > sin_h) & (wgt > 0)
            ao_dir = ao_dir + torch.where(rise, wgt * (sin_new - sin_h), torch.zeros_like(ao_dir))
            sin_h = torch.where(rise, sin_new, sin_h)
        occlusion = occlusion + ao_dir
    ao = 1.0 - occlusion / directions
    if blur:
        ao = blur_passes(
            ao, g, [gaussian_line_offsets(4, True), gaussian_line_offsets(4, False)], radius
        )
    return torch.where(g.valid, ao, torch.ones_like(ao)).clamp(0.0, 1.0)


__all__ = ["hbao"]
