"""Alchemy ambient obscurance (McGuire, Osman, Bukowski & Hennessy, HPG 2011) sampled as
scalable AO does (McGuire, Mara & Luebke, "Scalable ambient obscurance", HPG 2012).

Alchemy AO estimates obscurance from ``s`` points ``Q_i`` of the depth buffer taken on a
screen-space disk around the shaded point ``P`` (the projection of the world-space radius
``r``), with ``v_i = Q_i − P``:

    ``A = max(0, 1 − (2σ / s) Σ_i max(0, v_i · n − β z) / (v_i · v_i + ε))^k``

— the paper's estimator, whose ``v · n / v · v`` term comes from changing the
cosine-weighted AO integral from solid angle to the area of the occluding surface seen in the
disk. Scalable AO keeps the estimator and changes the sampling: a spiral of ``s`` taps,
``τ`` turns, tap ``i`` at screen radius ``α_i r_px`` with ``α_i = (i + 0.5) / s``, rotated per
pixel (McGuire's hash; here the 4×4 interleaved noise), then a separable bilateral blur
(radius 4, stride 2, SAO's Gaussian weights, :mod:`mcdenoise.ao.blur`). SAO's mip-mapped depth
("scalable") only speeds up the fetches of a GPU; here every tap reads the full-resolution
depth, which gives the same values at this project's image sizes.

Choices made here:

* Falloff: taps with ``|v| ≥ r`` are dropped (the reference's step), as Alchemy's paper does
  ("only points within the radius count"); SAO's smooth ``(r² − v·v)³`` weight is not the
  ray-traced AO's falloff.
* Units: ``v · n / v · v`` has units of 1/length; it is multiplied by ``r`` so that
  ``intensity`` (the paper's σ) is dimensionless. ``intensity`` = 1 (the paper's σ and SAO's default intensity) serves every scene scale;
  ``β = bias`` is a fraction of ``r`` (SAO's ``bias`` 0.01 m at ``r`` = 1 m),
  ``ε = 0.01 r²`` (SAO's ``epsilon`` 0.01 m²), ``k = 1``. On the inside corner of two planes
  (``tests/ao/test_ao_closed_forms.py``) σ = 0.5, 1, 2 give mean absolute errors 0.111, 0.111,
  0.138 against the closed form: the estimator's shape, not σ, limits it there.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from mcdenoise.ao.blur import blur_passes, sao_offsets
from mcdenoise.ao.geometry import ViewGBuffer, falloff_weight, interleaved_noise

#: SAO's spiral turns for a tap count (McGuire's table gives 7 for 12 or 11 taps); taps must
#: not line up from one ring to the next.
SPIRAL_TURNS = 7


def alchemy(
    g: ViewGBuffer,
    radius: float,
    *,
    samples: int = 12,
    intensity: float = 1.0,
    bias: float = 0.01,
    falloff: float = 0.0,
    blur: bool = True,
) -> Tensor:
    """Alchemy / scalable AO of the G-buffer ``g``; returns AO ``(H, W)`` in [0, 1], 1 on
    empty pixels.

    Args:
        radius: AO radius (scene units), the ray-traced AO's.
        samples: spiral taps per pixel.
        intensity: σ of the estimator (dimensionless here, see the module docstring).
        bias: β, as a fraction of ``radius``.
        falloff: fraction of ``radius`` over which occluders fade out (0: step).
        blur: apply the separable SAO bilateral blur.
    """
    if samples < 1 or not radius > 0:
        raise ValueError("alchemy: samples >= 1 and radius > 0 required")
    h, w = g.shape
    dev = g.position.device
    p, n = g.position, g.normal
    spin = 2.0 * math.pi * interleaved_noise(h, w, dev)[0]
    u0, v0 = g.pixel_grid()
    r_px = g.focal * radius / p[2].clamp_min(1e-6)
    eps = 0.01 * radius * radius
    total = torch.zeros(h, w, device=dev)
    for i in range(samples):
        alpha = (i + 0.5) / samples
        angle = alpha * SPIRAL_TURNS * 2.0 * math.pi + spin
        ss_r = alpha * r_px
        u = u0 + ss_r * torch.cos(angle)
        v = v0 + ss_r * torch.sin(angle)
        q, ok = g.fetch(u, v)
        vec = q - p
        vv = (vec * vec).sum(0)
        vn = (vec * n).sum(0)
        term = (vn - bias * radius).clamp_min(0.0) / (vv + eps) * radius
        total = total + term * falloff_weight(vv.sqrt(), radius, falloff) * ok.float()
    ao = (1.0 - 2.0 * intensity / samples * total).clamp_min(0.0)
    if blur:
        ao = blur_passes(ao, g, [sao_offsets(True), sao_offsets(False)], radius)
    return torch.where(g.valid, ao, torch.ones_like(ao)).clamp(0.0, 1.0)


__all__ = ["SPIRAL_TURNS", "alchemy"]
