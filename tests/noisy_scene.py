"""A seeded synthetic noisy scene for the filter, preparation and method tests (made in the run).

Imported by the conftests of tests/filters, tests/prep and tests/methods (``tests/`` is on
``sys.path`` through its own conftest).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch


@dataclass
class NoisyScene:
    """A seeded synthetic 'render': piecewise-constant reflectance under smooth shading.

    All tensors are ``(1, C, H, W)`` float64; ``noisy = clean + N(0, var)`` per pixel with a
    heteroscedastic (intensity-proportional) variance, like Monte Carlo noise.
    """

    clean: torch.Tensor
    noisy: torch.Tensor
    var: torch.Tensor  # (1, 1, H, W) variance of the mean
    albedo: torch.Tensor
    normal: torch.Tensor
    depth: torch.Tensor


def make_scene(h: int = 32, w: int = 32, seed: int = 0, noise: float = 0.3) -> NoisyScene:
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(
        torch.linspace(0, 1, h, dtype=torch.float64),
        torch.linspace(0, 1, w, dtype=torch.float64),
        indexing="ij",
    )
    region = (xx > 0.45).long() + (yy > 0.6).long() * 2  # 4 regions with straight edges
    palette = torch.tensor(
        [[0.8, 0.2, 0.2], [0.2, 0.7, 0.3], [0.3, 0.3, 0.9], [0.9, 0.9, 0.6]], dtype=torch.float64
    )
    albedo = palette[region].permute(2, 0, 1).unsqueeze(0)
    normals = torch.tensor(
        [[0, 0, 1], [0, 0.6, 0.8], [0.6, 0, 0.8], [0, 0, 1]], dtype=torch.float64
    )
    normal = normals[region].permute(2, 0, 1).unsqueeze(0)
    depth = (1.0 + 0.5 * (region >= 2).double() + 0.1 * xx).unsqueeze(0).unsqueeze(0)
    shading = (0.5 + 1.5 * xx * (1 - 0.5 * yy)).unsqueeze(0).unsqueeze(0)
    clean = albedo * shading
    var = (noise**2) * clean.mean(dim=1, keepdim=True)  # brighter -> noisier
    noisy = clean + var.sqrt() * torch.randn(clean.shape, generator=g, dtype=torch.float64)
    noisy = noisy.clamp_min(0.0)
    return NoisyScene(clean, noisy, var, albedo, normal, depth)


def relmse(x: torch.Tensor, ref: torch.Tensor) -> float:
    """mean((x - r)² / (r² + 0.01)), as in the evaluation code."""
    return float(((x - ref) ** 2 / (ref**2 + 0.01)).mean())


def lognormal_constant(seed: int = 0):
    """A constant grey seen through 4 lognormal samples per pixel: ``(colour of the mean, its
    variance (1, 1, H, W), true value)``. Skewed like Monte Carlo noise: a pixel that drew a
    bright sample is both brighter and has a larger variance estimate."""
    g = torch.Generator().manual_seed(seed)
    s = torch.exp(torch.randn(4, 1, 1, 32, 32, generator=g, dtype=torch.float64))
    s = s.expand(4, 1, 3, 32, 32)
    return s.mean(0), s.var(0).mean(1, keepdim=True) / 4, math.exp(0.5)
