"""Ground-truth-based ambient occlusion (Jimenez, Wu, Pesce & Jarabo, "Practical real-time
strategies for accurate indirect occlusion", SIGGRAPH 2016 course), following Intel's
XeGTAO (``Source/Rendering/Shaders/XeGTAO.hlsli``, ``XeGTAO_MainPass``), the clean public
implementation of the paper's Algorithm 1.

The hemisphere is cut into ``slices`` planes that contain the view vector (screen-space
directions ``φ = π (k + ξ) / slices``). In each slice the normal is projected into the
plane (length ``‖n_p‖``, angle ``γ`` from the view vector); ``steps`` samples on each side,
at screen distances ``s² r_px`` (XeGTAO's sample distribution power 2) snapped to pixel
centres, raise the two horizon cosines ``cos h₀``, ``cos h₁`` (a sample counts with the
falloff weight of its distance, blending towards the low horizon ``cos(γ ∓ π/2)``). The
visible arc is then integrated *cosine-weighted* in closed form,

    ``â = ‖n_p‖ Σ_{i=0,1} (cos γ + 2 h_i sin γ − cos(2 h_i − γ)) / 4``,

and the AO is the mean over slices: the same cosine-weighted visibility the ray-traced
``mcd_ao`` estimates, under the assumption that everything below a horizon is occluded
(a height field: thin objects occlude the space behind them, the method's known error).

Choices relative to XeGTAO's defaults (theirs are tuned for a look, ours for agreement with
the reference): radius multiplier 1 (not 1.457), falloff range 0 (the reference's step; XeGTAO
0.615, ``falloff`` here), final power 1 (not 2.2), no 0.03 floor, no "small radius fade",
no ``‖n_p‖`` fudge towards 1, the horizon clamp to ``γ ± π/2`` kept (XeGTAO disables it for
speed), full-resolution depth (no mip chain), off-screen samples ignored (XeGTAO clamps them
to the border). Noise: 4×4 interleaved slice rotation and R2-offset step jitter; denoising:
XeGTAO's 3×3 edge-aware pass, twice ("medium").
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from mcdenoise.ao.blur import blur_passes, gaussian_offsets
from mcdenoise.ao.geometry import ViewGBuffer, falloff_weight, interleaved_noise, norm3

#: XeGTAO: the first sample is pushed this many pixels out (the centre pixel says nothing).
PIXEL_TOO_CLOSE = 1.3
#: XeGTAO's default sample distribution power (samples denser near the centre).
DISTRIBUTION_POWER = 2.0


def gtao(
    g: ViewGBuffer,
    radius: float,
    *,
    slices: int = 4,
    steps: int = 4,
    falloff: float = 0.0,
    blur: bool = True,
) -> Tensor:
    """GTAO of the G-buffer ``g``; returns AO ``(H, W)`` in [0, 1], 1 on empty pixels.

    Args:
        radius: AO radius (scene units), the ray-traced AO's.
        slices: slice directions per pixel (XeGTAO "high" uses 3, "ultra" 9).
        steps: samples per side of a slice (XeGTAO: 3).
        falloff: fraction of ``radius`` over which occluders fade out (0: step).
        blur: apply two 3×3 edge-aware passes.
    """
    if slices < 1 or steps < 1 or not radius > 0:
        raise ValueError("gtao: slices, steps >= 1 and radius > 0 required")
    h, w = g.shape
    dev = g.position.device
    p, n = g.position, g.normal
    noise = interleaved_noise(h, w, dev)
    u0, v0 = g.pixel_grid()
    view = -p / norm3(p, keepdim=True).clamp_min(1e-12)  # (3, H, W), towards the camera
    r_px = g.focal * radius / p[2].clamp_min(1e-6)
    min_s = PIXEL_TOO_CLOSE / r_px.clamp_min(1e-6)
    visibility = torch.zeros(h, w, device=dev)
    for k in range(slices):
        phi = math.pi * (k + noise[0]) / slices
        cos_phi, sin_phi = torch.cos(phi), torch.sin(phi)
        direction = torch.stack([cos_phi, sin_phi, torch.zeros_like(phi)])
        ortho = direction - (direction * view).sum(0, keepdim=True) * view
        axis = torch.cross(ortho, view, dim=0)
        axis = axis / norm3(axis, keepdim=True).clamp_min(1e-12)
        n_proj = n - axis * (n * axis).sum(0, keepdim=True)
        sign = torch.sign((ortho * n_proj).sum(0))
        n_len = norm3(n_proj).clamp_min(1e-12)
        cos_n = ((n_proj * view).sum(0) / n_len).clamp(0.0, 1.0)
        gamma = sign * torch.acos(cos_n)
        low0 = torch.cos(gamma + math.pi / 2)
        low1 = torch.cos(gamma - math.pi / 2)
        hc0, hc1 = low0.clone(), low1.clone()
        for j in range(steps):
            jitter = torch.remainder(noise[1] + (k + j * steps) * 0.6180339887498948, 1.0)
            s = ((j + jitter) / steps) ** DISTRIBUTION_POWER + min_s
            du = torch.round(s * r_px * cos_phi)
            dv = torch.round(s * r_px * sin_phi)
            for side, low in ((1.0, low0), (-1.0, low1)):
                q, ok = g.fetch(u0 + side * du, v0 + side * dv)
                delta = q - p
                dist = norm3(delta)
                shc = (delta * view).sum(0) / dist.clamp_min(1e-12)
                wgt = falloff_weight(dist, radius, falloff) * ok.float()
                shc = low + (shc - low) * wgt
                if side > 0:
                    hc0 = torch.maximum(hc0, shc)
                else:
                    hc1 = torch.maximum(hc1, shc)
        h0 = -torch.acos(hc1.clamp(-1.0, 1.0))
        h1 = torch.acos(hc0.clamp(-1.0, 1.0))
        h0 = gamma + (h0 - gamma).clamp(-math.pi / 2, math.pi / 2)
        h1 = gamma + (h1 - gamma).clamp(-math.pi / 2, math.pi / 2)
        sin_g = torch.sin(gamma)
        arc0 = (cos_n + 2.0 * h0 * sin_g - torch.cos(2.0 * h0 - gamma)) / 4.0
        arc1 = (cos_n + 2.0 * h1 * sin_g - torch.cos(2.0 * h1 - gamma)) / 4.0
        visibility = visibility + n_len * (arc0 + arc1)
    ao = visibility / slices
    if blur:
        box3 = gaussian_offsets(1, sigma=1e6)  # 3×3, equal weights: the edges do the work
        ao = blur_passes(ao, g, [box3, box3], radius)
    return torch.where(g.valid, ao, torch.ones_like(ao)).clamp(0.0, 1.0)


__all__ = ["DISTRIBUTION_POWER", "PIXEL_TOO_CLOSE", "gtao"]
