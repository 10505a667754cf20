"""Tests of mcdenoise.filters.box: in-image box mean and 3x3 median."""

from __future__ import annotations

import pytest
import torch

from mcdenoise.filters.box import box_mean, median3


@pytest.mark.parametrize("r", [0, 1, 3, 31])
def test_box_mean_is_the_mean_over_the_in_image_window(r: int) -> None:
    g = torch.Generator().manual_seed(0)
    x = torch.randn(2, 3, 9, 40, generator=g, dtype=torch.float64)
    got = box_mean(x, r)
    want = torch.empty_like(x)
    for y in range(9):
        for i in range(40):
            want[..., y, i] = x[..., max(0, y - r) : y + r + 1, max(0, i - r) : i + r + 1].mean(
                (-2, -1)
            )
    torch.testing.assert_close(got, want, atol=1e-12, rtol=0)


def test_median3_removes_an_isolated_outlier_and_keeps_a_constant() -> None:
    x = torch.full((1, 2, 6, 7), 0.25)
    assert torch.equal(median3(x), x)
    x[0, 1, 3, 3] = 100.0
    assert float(median3(x).max()) == 0.25


@pytest.mark.parametrize("r", [0, 1, 10, 31])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_box_mean_is_bitwise_the_avg_pool_sum(r: int, dtype: torch.dtype) -> None:
    """The shifted-view sums add the same values in the same order as avg_pool2d (what
    box_mean was before): the Kalantari features must not move (docs/results/kalantari.md)."""
    import torch.nn.functional as F

    def pooled(t: torch.Tensor) -> torch.Tensor:
        k = 2 * r + 1
        t = F.avg_pool2d(F.pad(t, (r, r, 0, 0)), (1, k), stride=1, divisor_override=1)
        return F.avg_pool2d(F.pad(t, (0, 0, r, r)), (k, 1), stride=1, divisor_override=1)

    g = torch.Generator().manual_seed(1)
    x = (torch.randn(1, 3, 37, 70, generator=g) * 10).to(dtype)
    want = pooled(x) / pooled(torch.ones_like(x[:, :1]))
    assert torch.equal(box_mean(x, r), want)
