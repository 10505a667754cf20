"""Depth-aware (bilateral) blurs that remove the interleaved-sampling pattern of screen-space AO.

Every screen-space AO method rotates its samples per pixel with a small repeating noise tile
(:func:`mcdenoise.ao.geometry.interleaved_noise`) and then blurs the raw AO over about the
tile's size, stopping at geometric edges so occlusion does not bleed across silhouettes. The
methods differ in the kernel they were published with:

* Crytek SSAO (Mittring 2007) and Chapman's hemisphere SSAO: a 4×4 box over the 4×4 rotation
  tile (:func:`box_offsets`);
* HBAO (Bavoil & Sainz 2008; NVIDIA's HBAO+ keeps it): a cross-bilateral Gaussian, depth
  weighted (:func:`gaussian_offsets`);
* scalable AO (McGuire et al. 2012): a separable bilateral of radius 4 with stride 2 and the
  Gaussian weights 0.153, 0.144, 0.122, 0.092, 0.061 (:data:`SAO_WEIGHTS`), run as a
  horizontal then a vertical pass;
* XeGTAO: a 3×3 edge-aware pass, run one to three times ("sharp" to "soft").

The edge test is the same for all (:func:`bilateral`): a neighbour counts with its kernel
weight times a plane weight ``exp(-(n_i · (P_j - P_i) / (s r))²)`` — how far the neighbour
lies from the centre's tangent plane relative to ``s`` times the AO radius ``r`` — and a normal
weight ``max(0, n_i · n_j)^p``; empty pixels weigh 0 and an empty centre is left as it is.
The plane distance (rather than a depth difference) keeps slanted floors blurred along their
slope, where depth changes fast from pixel to pixel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from mcdenoise.ao.geometry import ViewGBuffer

#: Kernel: (dy, dx, weight) per tap.
Taps = Sequence[tuple[int, int, float]]
#: McGuire et al. 2012 (SAO reference code, ``gaussian[]``): weights of taps 0..4.
SAO_WEIGHTS = (0.153170, 0.144893, 0.122649, 0.092902, 0.061009)


def box_offsets(size: int = 4) -> list[tuple[int, int, float]]:
    """A ``size`` × ``size`` box (taps ``-size//2 .. size - size//2 - 1``, the 4×4 blur of the
    4×4 rotation tile)."""
    lo = -(size // 2)
    return [(dy, dx, 1.0) for dy in range(lo, lo + size) for dx in range(lo, lo + size)]


def gaussian_offsets(radius: int, sigma: float | None = None) -> list[tuple[int, int, float]]:
    """A square Gaussian kernel of ``radius`` (σ = (radius + 1) / 2 by default, the
    HBAO sample's blur)."""
    s = sigma if sigma is not None else (radius + 1) / 2.0
    return [
        (dy, dx, math.exp(-(dx * dx + dy * dy) / (2.0 * s * s)))
        for dy in range(-radius, radius + 1)
        for dx in range(-radius, radius + 1)
    ]


def sao_offsets(horizontal: bool, stride: int = 2) -> list[tuple[int, int, float]]:
    """One pass of the scalable-AO separable blur: taps ``-4..4`` times ``stride``."""
    taps = []
    for k in range(-4, 5):
        w = SAO_WEIGHTS[abs(k)]
        taps.append((0, k * stride, w) if horizontal else (k * stride, 0, w))
    return taps


def _shift(t: Tensor, dy: int, dx: int) -> Tensor:
    """``t`` ``(C, H, W)`` sampled at ``(y + dy, x + dx)``, zero outside."""
    h, w = t.shape[-2:]
    p = max(abs(dy), abs(dx))
    if p == 0:
        return t
    padded = F.pad(t.unsqueeze(0), (p, p, p, p)).squeeze(0)
    return padded[:, p + dy : p + dy + h, p + dx : p + dx + w]


def bilateral(
    ao: Tensor,
    g: ViewGBuffer,
    taps: Taps,
    radius: float,
    *,
    plane_sigma: float = 0.1,
    normal_power: float = 8.0,
) -> Tensor:
    """One depth- and normal-aware blur pass of ``ao`` ``(H, W)`` with kernel ``taps``.

    ``radius`` is the AO radius (scene units); ``plane_sigma`` the tangent-plane distance, as
    a fraction of it, at which a neighbour's weight has fallen to 1/e; ``normal_power`` the
    exponent of the normal weight. Returns ``(H, W)``.
    """
    valid = g.valid.float().unsqueeze(0)
    p, n = g.position, g.normal
    num = torch.zeros_like(ao)
    den = torch.zeros_like(ao)
    scale = 1.0 / max(plane_sigma * radius, 1e-12)
    for dy, dx, w in taps:
        pj = _shift(p, dy, dx)
        nj = _shift(n, dy, dx)
        vj = _shift(valid, dy, dx)[0]
        aj = _shift(ao.unsqueeze(0), dy, dx)[0]
        plane = ((pj - p) * n).sum(0) * scale
        cos = (nj * n).sum(0).clamp_min(0.0)
        wt = w * vj * torch.exp(-plane * plane) * cos.pow(normal_power)
        num = num + wt * aj
        den = den + wt
    out = torch.where(den > 0, num / den.clamp_min(1e-30), ao)
    return torch.where(g.valid, out, ao)


def blur_passes(
    ao: Tensor, g: ViewGBuffer, passes: Sequence[Taps], radius: float, **kwargs: float
) -> Tensor:
    """:func:`bilateral` once per kernel of ``passes`` (a separable blur is two passes)."""
    for taps in passes:
        ao = bilateral(ao, g, taps, radius, **kwargs)
    return ao


__all__ = [
    "SAO_WEIGHTS",
    "bilateral",
    "blur_passes",
    "box_offsets",
    "gaussian_offsets",
    "sao_offsets",
]
