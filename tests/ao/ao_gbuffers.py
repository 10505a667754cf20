"""Synthetic G-buffers of planes for the AO tests, and the closed forms of the ray-traced AO.

A pinhole camera at the world origin looks along +z (world frame = view frame before the
camera's pitch and roll: x right, y down, z forward, as :mod:`mcdenoise.io.camera`). Planes
``n · x = c`` are intersected exactly per pixel centre; the depth is the ray distance and the
normal the plane's, as ``mcdenoise render`` writes them.
"""

from __future__ import annotations

import math

import torch

from mcdenoise.ao.geometry import ViewGBuffer, ray_directions, view_gbuffer


def rotation(pitch_deg: float = 0.0, roll_deg: float = 0.0) -> torch.Tensor:
    """View -> world rotation: roll about the view axis, then pitch (positive: look down)."""
    a, b = math.radians(pitch_deg), math.radians(roll_deg)
    pitch = torch.tensor([[1, 0, 0], [0, math.cos(a), math.sin(a)], [0, -math.sin(a), math.cos(a)]])
    roll = torch.tensor([[math.cos(b), -math.sin(b), 0], [math.sin(b), math.cos(b), 0], [0, 0, 1]])
    return (pitch @ roll).float()


def planes_gbuffer(
    planes: list[tuple[tuple[float, float, float], float]],
    *,
    height: int = 48,
    width: int = 48,
    fov: float = 60.0,
    pitch: float = 0.0,
    roll: float = 0.0,
    world_normals: bool = True,
) -> tuple[ViewGBuffer, torch.Tensor]:
    """The G-buffer of the planes ``n · x = c`` (world frame) and the world positions
    ``(3, H, W)`` (0 where empty)."""
    f = width / (2.0 * math.tan(math.radians(fov) / 2.0))
    d = ray_directions(height, width, f, torch.device("cpu"))
    rot = rotation(pitch, roll)
    dw = torch.einsum("ij,jhw->ihw", rot, d)
    best = torch.full((height, width), math.inf)
    normal = torch.zeros(3, height, width)
    for n, c in planes:
        nt = torch.tensor(n, dtype=torch.float32)
        den = (dw * nt[:, None, None]).sum(0)
        t = c / torch.where(den.abs() > 1e-9, den, torch.full_like(den, 1e-9))
        hit = (t > 0) & (t < best)
        best = torch.where(hit, t, best)
        normal = torch.where(hit[None], nt[:, None, None].expand(3, height, width), normal)
    depth = torch.where(torch.isfinite(best), best, torch.zeros_like(best))
    g = view_gbuffer(
        depth,
        f,
        normal=normal if world_normals else None,
        world_to_view=rot.T if world_normals else None,
    )
    return g, dw * depth


def corner_ao(distance: torch.Tensor, radius: float) -> torch.Tensor:
    """Ray-traced AO (cosine-weighted, step at ``radius``) of a point on a plane at
    ``distance`` from a perpendicular plane (the inside corner): ``1 − (acos c − c √(1 − c²)) / π``
    with ``c = min(1, distance / radius)`` — the blocked directions are the disk segment
    ``a > c`` of the Malley disk."""
    c = (distance / radius).clamp(0.0, 1.0)
    return 1.0 - (torch.acos(c) - c * torch.sqrt(1.0 - c * c)) / math.pi


def slab_ao(gap: float, radius: float) -> float:
    """Ray-traced AO of a point on a plane under a parallel plane ``gap`` away: the rays with
    ``cos θ > gap / radius`` hit it, a fraction ``1 − c²`` of the cosine-weighted hemisphere."""
    c = min(1.0, gap / radius)
    return c * c
