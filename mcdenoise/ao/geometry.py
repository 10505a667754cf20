"""View-space G-buffer for screen-space AO: positions and normals from depth and a camera.

Screen-space AO methods work on what a rasteriser's G-buffer holds: per pixel the view-space
position of the visible surface and its normal. :func:`view_gbuffer` rebuilds them from the
buffers mcdenoise reads (depth = distance along the ray, world-space shading normal) and the
camera (:class:`mcdenoise.io.camera.CameraInfo` supplies ``focal`` and ``world_to_view``).

View space is the computer-vision frame of :mod:`mcdenoise.io.camera`: +x right, +y down,
+z forward; pixel ``(i, j)`` has its centre at ``(i + 0.5, j + 0.5)`` and a point
``(x, y, z)`` projects to ``u = f x / z + W / 2``, ``v = f y / z + H / 2``. Tensors are
``(C, H, W)`` float32 on any device; a pixel whose ray escaped (depth 0) is *empty*:
``valid`` is False there and no method reads its position as an occluder.

Normals face the viewer (the ray-traced ``mcd_ao`` also flips the shading normal towards the
viewer: surfaces are two-sided). Without a world-to-view rotation (an input from another
renderer with only a field of view), or where a normal is missing, the normal is
reconstructed from the positions of the neighbours, taking on each axis the one-sided
difference with the smaller depth step (XeGTAO's ``XeGTAO_CalculateNormal`` uses the same
edge-aware choice), so a depth discontinuity does not tilt it.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

#: Normals shorter than this (a pixel averaging opposite normals, or none) are rebuilt.
MIN_NORMAL_LENGTH = 0.2


def norm3(v: Tensor, keepdim: bool = False) -> Tensor:
    """Euclidean length over the first axis of ``v`` ``(3, ...)``, written out: on CPU
    ``Tensor.norm(dim=0)`` of a ``(3, H, W)`` tensor (a strided reduction) was measured 20-30×
    slower and took two thirds of GTAO's time (torch profiler, 256²)."""
    n = torch.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return n.unsqueeze(0) if keepdim else n


@dataclass
class ViewGBuffer:
    """View-space G-buffer of one image.

    Attributes:
        position: ``(3, H, W)`` view-space positions (scene units), 0 where empty.
        normal: ``(3, H, W)`` unit normals facing the viewer, 0 where empty.
        valid: ``(H, W)`` bool, a surface is seen.
        focal: focal length in pixels (``u = f x / z + W / 2``).
    """

    position: Tensor
    normal: Tensor
    valid: Tensor
    focal: float

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.valid.shape[0]), int(self.valid.shape[1])

    def pixel_grid(self) -> tuple[Tensor, Tensor]:
        """Pixel-centre coordinates ``(u, v)``, each ``(H, W)``."""
        h, w = self.shape
        dev = self.position.device
        v, u = torch.meshgrid(
            torch.arange(h, device=dev, dtype=torch.float32) + 0.5,
            torch.arange(w, device=dev, dtype=torch.float32) + 0.5,
            indexing="ij",
        )
        return u, v

    def project(self, q: Tensor) -> tuple[Tensor, Tensor]:
        """Continuous pixel coordinates ``(u, v)`` of view-space points ``q`` ``(3, ...)``;
        points at or behind the camera get ``-1`` (off screen)."""
        h, w = self.shape
        z = q[2]
        front = z > 1e-6
        zs = torch.where(front, z, torch.ones_like(z))
        u = torch.where(front, self.focal * q[0] / zs + w / 2.0, torch.full_like(z, -1.0))
        v = torch.where(front, self.focal * q[1] / zs + h / 2.0, torch.full_like(z, -1.0))
        return u, v

    def fetch(self, u: Tensor, v: Tensor) -> tuple[Tensor, Tensor]:
        """The G-buffer position at the pixels containing ``(u, v)`` (nearest, no
        interpolation: interpolating depth across an edge invents surfaces).

        Returns ``(position (3, ...), ok (...))``; ``ok`` is False off screen and on empty
        pixels, where the position is 0.
        """
        idx, ok = self._index(u, v)
        return self._gather(self.position, idx) * ok, ok

    def fetch_with_normal(self, u: Tensor, v: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """As :meth:`fetch`, plus the normal there: ``(position, normal, ok)``."""
        idx, ok = self._index(u, v)
        return self._gather(self.position, idx) * ok, self._gather(self.normal, idx) * ok, ok

    def _index(self, u: Tensor, v: Tensor) -> tuple[Tensor, Tensor]:
        h, w = self.shape
        i = torch.floor(u)
        j = torch.floor(v)
        inside = (i >= 0) & (i < w) & (j >= 0) & (j < h)
        idx = (j.clamp(0, h - 1) * w + i.clamp(0, w - 1)).long()
        return idx, inside & self.valid.reshape(-1)[idx]

    @staticmethod
    def _gather(t: Tensor, idx: Tensor) -> Tensor:
        # index_select: about 3x faster than advanced indexing on CPU (measured, 512²)
        return torch.index_select(t.reshape(3, -1), 1, idx.reshape(-1)).reshape(3, *idx.shape)


def ray_directions(height: int, width: int, focal: float, device: torch.device) -> Tensor:
    """Unit view-space directions through the pixel centres, ``(3, H, W)``."""
    v, u = torch.meshgrid(
        torch.arange(height, device=device, dtype=torch.float32) + 0.5,
        torch.arange(width, device=device, dtype=torch.float32) + 0.5,
        indexing="ij",
    )
    d = torch.stack([(u - width / 2.0) / focal, (v - height / 2.0) / focal, torch.ones_like(u)])
    return d / norm3(d, keepdim=True)


def normals_from_positions(position: Tensor, valid: Tensor) -> Tensor:
    """Unit normals ``(3, H, W)`` facing the viewer, from view-space ``position`` ``(3, H, W)``:
    cross product of the horizontal and vertical one-sided differences, each taken on the side
    with the smaller depth step (and on a valid neighbour). 0 where nothing can be formed."""
    p = position
    z = p[2]
    big = torch.finfo(p.dtype).max

    def side(dim: int) -> Tensor:
        fwd = torch.zeros_like(p)
        bwd = torch.zeros_like(p)
        ok_f = torch.zeros_like(valid)
        ok_b = torch.zeros_like(valid)
        if dim == 2:
            fwd[:, :, :-1] = p[:, :, 1:] - p[:, :, :-1]
            ok_f[:, :-1] = valid[:, 1:] & valid[:, :-1]
            bwd[:, :, 1:] = p[:, :, 1:] - p[:, :, :-1]
            ok_b[:, 1:] = valid[:, 1:] & valid[:, :-1]
        else:
            fwd[:, :-1, :] = p[:, 1:, :] - p[:, :-1, :]
            ok_f[:-1, :] = valid[1:, :] & valid[:-1, :]
            bwd[:, 1:, :] = p[:, 1:, :] - p[:, :-1, :]
            ok_b[1:, :] = valid[1:, :] & valid[:-1, :]
        cost_f = torch.where(ok_f, fwd[2].abs(), torch.full_like(z, big))
        cost_b = torch.where(ok_b, bwd[2].abs(), torch.full_like(z, big))
        return torch.where((cost_f <= cost_b).unsqueeze(0), fwd, bwd)

    dx, dy = side(2), side(1)
    n = torch.cross(dx, dy, dim=0)
    length = norm3(n, keepdim=True)
    n = torch.where(length > 0, n / length.clamp_min(1e-30), torch.zeros_like(n))
    return _face_viewer(n, position) * valid


def _face_viewer(normal: Tensor, position: Tensor) -> Tensor:
    """Flip normals that point away from the camera (two-sided surfaces, as ``mcd_ao``)."""
    away = (normal * position).sum(0, keepdim=True) > 0
    return torch.where(away, -normal, normal)


def view_gbuffer(
    depth: Tensor,
    focal: float,
    *,
    normal: Tensor | None = None,
    world_to_view: Tensor | None = None,
) -> ViewGBuffer:
    """The view-space G-buffer from ``depth`` and (optionally) world-space ``normal``.

    Args:
        depth: ``(1, H, W)`` or ``(H, W)`` distance along the ray (scene units), 0 (or not
            finite) where the ray escaped.
        focal: focal length in pixels (:meth:`~mcdenoise.io.camera.CameraInfo.focal_pixels`).
        normal: ``(3, H, W)`` world-space normals, or ``None`` (rebuilt from depth).
        world_to_view: ``(3, 3)`` rotation world -> view (needed with ``normal``).

    Raises:
        ValueError: shapes disagree, or ``normal`` is given without ``world_to_view``.
    """
    if depth.dim() == 3:
        if depth.shape[0] != 1:
            raise ValueError(f"depth must be (1, H, W) or (H, W), got {tuple(depth.shape)}")
        depth = depth[0]
    if depth.dim() != 2:
        raise ValueError(f"depth must be (1, H, W) or (H, W), got {tuple(depth.shape)}")
    if not focal > 0:
        raise ValueError(f"focal length must be > 0 pixels, got {focal}")
    h, w = depth.shape
    depth = depth.float()
    valid = torch.isfinite(depth) & (depth > 0)
    t = torch.where(valid, depth, torch.zeros_like(depth))
    position = ray_directions(h, w, focal, depth.device) * t
    rebuilt = normals_from_positions(position, valid)
    if normal is None:
        n = rebuilt
    else:
        if normal.shape != (3, h, w):
            raise ValueError(f"normal must be (3, {h}, {w}), got {tuple(normal.shape)}")
        if world_to_view is None:
            raise ValueError("world-space normals need the world_to_view rotation")
        rot = world_to_view.to(device=depth.device, dtype=torch.float32)
        n = torch.einsum("ij,jhw->ihw", rot, normal.float())
        length = norm3(n, keepdim=True)
        good = torch.isfinite(length) & (length > MIN_NORMAL_LENGTH)
        n = torch.where(good, n / length.clamp_min(1e-30), rebuilt)
        n = _face_viewer(n, position) * valid
    return ViewGBuffer(position=position, normal=n, valid=valid, focal=float(focal))


def falloff_weight(dist: Tensor, radius: float, falloff: float = 0.0) -> Tensor:
    """Weight of an occluder at distance ``dist`` from the shaded point: with ``falloff = 0``
    the ray-traced AO's step (1 within ``radius``, 0 beyond; ``mcd_ao`` counts a hit within
    ``radius`` and nothing after), else 1 up to ``(1 - falloff) radius`` and linear to 0 at
    ``radius`` (XeGTAO's ``EffectFalloffRange``, which is 0.615 there)."""
    if falloff <= 0.0:
        return (dist < radius).float()
    return ((radius - dist) / (falloff * radius)).clamp(0.0, 1.0)


def interleaved_noise(height: int, width: int, device: torch.device, tile: int = 4) -> Tensor:
    """Two per-pixel numbers in [0, 1), ``(2, H, W)``, repeating every ``tile`` × ``tile``
    pixels (interleaved sampling, the 4×4 rotation texture of Crytek's SSAO and of HBAO): each
    of the ``tile²`` pixels of a tile gets its own stratum, so a ``tile``-wide blur sees every
    rotation once. The first is the pixel's Bayer stratum ``(b + 0.5) / tile²``; the second,
    ``frac(α₁ · first + α₂ b / tile²)`` with the R2 constants ``α₁ = 0.7548…``, ``α₂ = 0.5698…``,
    takes ``tile²`` distinct values in another order, so the jitter of steps (the second) is not
    aligned with the rotation (the first); XeGTAO likewise draws slice and step noise from
    R-sequences."""
    k = tile * tile
    order = torch.tensor(_bayer(tile), dtype=torch.float32, device=device)  # (tile, tile)
    first = (order + 0.5) / k
    second = torch.remainder(first * 0.7548776662466927 + 0.5698402909980532 * order / k, 1.0)
    reps = (-(-height // tile), -(-width // tile))
    both = torch.stack([first, second]).repeat(1, *reps)
    return both[:, :height, :width]


def _bayer(n: int) -> list[list[int]]:
    """The ``n`` × ``n`` Bayer ordered-dither matrix (``n`` a power of 2): values 0..n²-1."""
    m = [[0]]
    size = 1
    while size < n:
        m = [
            [
                4 * m[y % size][x % size] + [[0, 2], [3, 1]][y // size][x // size]
                for x in range(2 * size)
            ]
            for y in range(2 * size)
        ]
        size *= 2
    return m


__all__ = [
    "ViewGBuffer",
    "falloff_weight",
    "interleaved_noise",
    "norm3",
    "normals_from_positions",
    "ray_directions",
    "view_gbuffer",
]
