"""SVGF's settings and its edge-stopping guides: per-pixel depth and normal slopes (``fwidth``),
luminance, and the settings' defaults with the reasons for each (in :class:`SvgfSettings`).
The filter itself is :mod:`mcdenoise.filters.svgf`; the deviations from Falcor listed there
for ``fwidth`` and the depth floor are implemented here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.albedo import ALBEDO_EPS

#: Rec. 709 luminance weights (Falcor's ``luminance()``).
LUMINANCE = (0.2126, 0.7152, 0.0722)


#: Luminances are clamped here so that their squares stay finite in float32.
MAX_LUMINANCE = 1e15


@dataclass(frozen=True)
class SvgfSettings:
    """Parameters of :class:`Svgf` (defaults: Falcor's ``SVGFPass`` and the paper).

    Attributes:
        alpha: minimum EMA weight of the new illumination (Falcor ``mAlpha`` 0.05).
        moments_alpha: minimum EMA weight of the new moments (``mMomentsAlpha`` 0.2).
        max_history: cap of the history length (32 in ``SVGFReproject``).
        spatial_history: below this history length the variance is estimated spatially
            (4 in ``SVGFFilterMoments``).
        spatial_radius: radius of that spatial estimate (3: 7×7).
        iterations: à-trous levels (5 in the paper; Falcor's default is 4).
        feedback_tap: the level whose output is the next frame's history (0 in the paper,
            Falcor's default 1; -1: the unfiltered accumulated illumination).
        phi_color: luminance edge-stopping, in standard deviations (Falcor's ``mPhiColor``
            is 10; 2 here, see the module doc).
        phi_normal: normal edge-stopping power (``mPhiNormal`` 128).
        depth_test: reprojection depth tolerance, in fwidths (10 in ``isReprjValid``).
        normal_test: reprojection normal tolerance, in fwidths (16 in ``isReprjValid``).
        depth_floor: relative floor of the depth test's fwidth (see the module doc).
        demodulate: divide by ``albedo + albedo_eps`` before filtering (when an albedo is given).
        albedo_eps: the demodulation offset.
        use_color_var: steer the warm-up filter by the renderer's variance when the input
            has ``color_var`` (a deviation from Falcor, see the module doc).
    """

    alpha: float = 0.05
    moments_alpha: float = 0.2
    max_history: float = 32.0
    spatial_history: float = 4.0
    spatial_radius: int = 3
    iterations: int = 5
    feedback_tap: int = 0
    phi_color: float = 2.0
    phi_normal: float = 128.0
    depth_test: float = 10.0
    normal_test: float = 16.0
    depth_floor: float = 0.01
    demodulate: bool = True
    albedo_eps: float = ALBEDO_EPS
    use_color_var: bool = True

    def checked(self) -> SvgfSettings:
        """``self`` when every value is in range, else :class:`InputError` (one line)."""
        for name in ("alpha", "moments_alpha"):
            v = getattr(self, name)
            if not 0.0 < v <= 1.0:
                raise InputError(f"svgf: {name} must be in (0, 1], got {v}")
        positive = ("max_history", "phi_color", "phi_normal", "depth_test", "normal_test")
        for name in positive:
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"svgf: {name} must be a positive number, got {v}")
        for name in ("spatial_history", "depth_floor", "albedo_eps"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"svgf: {name} must be >= 0, got {v}")
        if not 0 <= self.iterations <= 12:
            raise InputError(f"svgf: iterations must be in 0..12, got {self.iterations}")
        if not 0 <= self.spatial_radius <= 8:
            raise InputError(f"svgf: spatial_radius must be in 0..8, got {self.spatial_radius}")
        if self.feedback_tap < -1:
            raise InputError(f"svgf: feedback_tap must be >= -1, got {self.feedback_tap}")
        return self


# --------------------------------------------------------------------------------------------
# Guides: depth, normal and their screen-space derivatives
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Guides:
    """The geometry of one frame, prepared for the edge-stopping functions.

    Attributes:
        depth: ``(B, 1, H, W)`` distance to the first hit (0: background), or ``None``.
        depth_fwidth: ``(B, 1, H, W)`` its screen-space derivative ``|ddx| + |ddy|``.
        normal: ``(B, 3, H, W)`` unit normals (0: background), or ``None``.
        normal_fwidth: ``(B, 1, H, W)`` length of the normal's ``|ddx| + |ddy|``.
        hit: ``(B, 1, H, W)`` bool, a surface was hit (``depth > 0``; all true without depth).
    """

    depth: Tensor | None
    depth_fwidth: Tensor | None
    normal: Tensor | None
    normal_fwidth: Tensor | None
    hit: Tensor


def _one_sided(x: Tensor, dim: int, usable: Tensor) -> Tensor:
    """Per pixel, the smaller absolute difference to the previous and the next pixel along
    ``dim`` where both pixels are ``usable`` (``inf`` where neither side is)."""
    n = x.shape[dim]
    inf = torch.full_like(x, math.inf)
    if n < 2:
        return inf.amin(dim=1, keepdim=True)
    d = (x.narrow(dim, 1, n - 1) - x.narrow(dim, 0, n - 1)).abs().amax(dim=1, keepdim=True)
    ok = usable.narrow(dim, 1, n - 1) & usable.narrow(dim, 0, n - 1)
    d = torch.where(ok, d, torch.full_like(d, math.inf))
    pad = torch.full_like(d.narrow(dim, 0, 1), math.inf)
    forward = torch.cat([d, pad], dim)
    backward = torch.cat([pad, d], dim)
    return torch.minimum(forward, backward)


def _fwidth(x: Tensor, usable: Tensor) -> Tensor:
    """``|ddx| + |ddy|`` from one-sided differences (see the module doc); 0 where a pixel
    has no usable neighbour along an axis."""
    total = torch.zeros_like(x[:, :1])
    for dim in (2, 3):
        d = _one_sided(x, dim, usable)
        total = total + torch.where(torch.isfinite(d), d, torch.zeros_like(d))
    return total


def _normal_fwidth(n: Tensor, usable: Tensor) -> Tensor:
    """Length of the per-component ``|ddx| + |ddy|`` of the normal (Falcor:
    ``length(fwidth(normal))``)."""
    comps = []
    for c in range(n.shape[1]):
        comps.append(_fwidth(n[:, c : c + 1], usable))
    return torch.cat(comps, 1).square().sum(1, keepdim=True).sqrt()


def make_guides(depth: Tensor | None, normal: Tensor | None, like: Tensor) -> Guides:
    """:class:`Guides` of a frame whose colour is ``like`` ``(B, 3, H, W)``."""
    b, _, h, w = like.shape
    hit = (
        depth > 0
        if depth is not None
        else torch.ones(b, 1, h, w, dtype=torch.bool, device=like.device)
    )
    z = zf = n = nf = None
    if depth is not None:
        z = depth.to(like.dtype).clamp_min(0.0)
        zf = _fwidth(z, hit)
    if normal is not None:
        raw = normal.to(like.dtype)
        length = raw.square().sum(1, keepdim=True).sqrt()
        n = torch.where(length > 1e-8, raw / length.clamp_min(1e-8), torch.zeros_like(raw))
        nf = _normal_fwidth(n, hit)
    return Guides(z, zf, n, nf, hit)


def luminance(x: Tensor) -> Tensor:
    """Rec. 709 luminance ``(B, 1, H, W)`` of ``(B, 3, H, W)`` linear RGB."""
    r, g, b = LUMINANCE
    return r * x[:, 0:1] + g * x[:, 1:2] + b * x[:, 2:3]


def with_overrides(settings: SvgfSettings, overrides: dict[str, object]) -> SvgfSettings:
    """``settings`` with some fields replaced (unknown names: :class:`InputError`)."""
    known = SvgfSettings.__dataclass_fields__
    bad = [k for k in overrides if k not in known]
    if bad:
        raise InputError(f"svgf: unknown setting(s) {bad}; known: {sorted(known)}")
    return replace(settings, **overrides).checked()  # type: ignore[arg-type]
