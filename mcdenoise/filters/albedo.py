"""Albedo demodulation: filter the irradiance ``c / (albedo + ε)``, multiply the albedo back.

Texture detail then never has to survive the filter: the albedo (a noise-free or nearly
noise-free buffer) carries it past. The classical filters, the Kalantari models and the kpcn
network all demodulate with the first two; the fixed filters' methods remodulate with
:func:`remodulate`.
"""

from __future__ import annotations

import torch
from torch import Tensor

#: Albedo offset ``ε`` of the demodulation (keeps black texels from dividing by zero).
ALBEDO_EPS = 0.01


def demodulate(
    color: Tensor, albedo: Tensor | None, eps: float = ALBEDO_EPS
) -> tuple[Tensor, Tensor]:
    """``(irradiance, factor)``: ``color / factor`` with ``factor = albedo + eps``.

    Args:
        color: ``(B, 3, H, W)`` linear HDR colour.
        albedo: ``(B, 3, H, W)`` reflectance, or ``None`` (then ``factor`` is ones and the
            irradiance is the colour itself, bit for bit).

    Returns:
        The irradiance and the remodulation factor, both ``(B, 3, H, W)``.
    """
    factor = torch.ones_like(color) if albedo is None else albedo + eps
    return color / factor, factor


def demodulated_variance(color_var: Tensor, factor: Tensor) -> Tensor:
    """Variance of the irradiance ``c / factor``, ``(B, 1, H, W)``.

    The albedo is treated as exact: ``var(c / a) ≈ var(c) / mean_ch(a²)`` (dominated by the
    largest channel, so a saturated albedo with a zero channel does not inflate it).
    """
    return color_var / factor.square().mean(dim=1, keepdim=True)


def remodulate(out: Tensor, factor: Tensor | None) -> Tensor:
    """``(3, H, W)`` of a filtered ``(1, 3, H, W)`` irradiance: times ``factor``, clamped at 0."""
    if factor is not None:
        out = out * factor
    return out.clamp_min(0.0)[0]


__all__ = ["ALBEDO_EPS", "demodulate", "demodulated_variance", "remodulate"]
