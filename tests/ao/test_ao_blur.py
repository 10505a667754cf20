"""The depth-aware blurs of mcdenoise.ao.blur: they smooth within a surface and stop at edges."""

from __future__ import annotations

import pytest
import torch
from ao_gbuffers import planes_gbuffer

from mcdenoise.ao.blur import (
    bilateral,
    box_offsets,
    gaussian_line_offsets,
    gaussian_offsets,
    sao_offsets,
)
from mcdenoise.ao.geometry import view_gbuffer

KERNELS = {
    "box4": [box_offsets(4)],
    "gauss4": [gaussian_offsets(4)],
    "gauss4-separable": [gaussian_line_offsets(4, True), gaussian_line_offsets(4, False)],
    "sao": [sao_offsets(True), sao_offsets(False)],
}


def _apply(ao, g, passes):
    for taps in passes:
        ao = bilateral(ao, g, taps, 0.5)
    return ao


@pytest.mark.parametrize("kernel", sorted(KERNELS))
def test_constant_stays_constant_and_sky_untouched(kernel):
    g, _ = planes_gbuffer([((0, 1, 0), 1.0)], pitch=10, height=24, width=24)
    ao = torch.where(g.valid, torch.full_like(g.valid, 0.7, dtype=torch.float32), 0.25)
    out = _apply(ao, g, KERNELS[kernel])
    # a weighted mean of 0.7 over each pass's taps, to its float32 rounding on any CPU: up to
    # taps * eps32 relative (Higham's reordering bound; 81 taps: 6.8e-6); the sky (0.25)
    # leaking in with 2e-5 of the weight or more still fails
    taps = sum(len(t) for t in KERNELS[kernel])
    tol = 0.7 * taps * torch.finfo(torch.float32).eps
    assert torch.allclose(out[g.valid], torch.tensor(0.7), atol=tol, rtol=0)
    assert out[~g.valid].eq(0.25).all()


@pytest.mark.parametrize("kernel", sorted(KERNELS))
def test_no_bleeding_across_a_depth_discontinuity(kernel):
    g, _ = planes_gbuffer([((0, 1, 0), 1.0)], pitch=20, height=32, width=32)
    depth = g.position.pow(2).sum(0).sqrt()  # distance along the ray
    depth[8:24, 8:24] = 0.5  # a near square in front of the floor
    g2 = view_gbuffer(depth, g.focal)
    near = torch.zeros_like(g2.valid)
    near[8:24, 8:24] = True
    ao = torch.where(near, torch.zeros_like(depth), torch.ones_like(depth))
    noisy = ao + 0.1 * torch.randn(ao.shape, generator=torch.Generator().manual_seed(0))
    out = _apply(noisy, g2, KERNELS[kernel])
    assert out[near].mean() < 0.05 and out[~near & g2.valid].mean() > 0.95
    # and it smooths: the noise within each surface goes down
    assert (out - ao)[near].std() < 0.6 * (noisy - ao)[near].std()
