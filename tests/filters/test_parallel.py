"""Tiles and row bands on worker threads (mcdenoise.filters.parallel): the same results as one
thread, bit for bit, and the caller's thread count restored."""

from __future__ import annotations

import pytest
import torch

from mcdenoise.filters.cross_bilateral import cross_bilateral
from mcdenoise.filters.nlm import non_local_means
from mcdenoise.filters.parallel import parallel_map, single_threaded_ops, workers


@pytest.fixture
def two_threads():
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(before)


def _inputs(h: int = 70, w: int = 90):
    g = torch.Generator().manual_seed(3)
    c = torch.rand(1, 3, h, w, generator=g)
    v = torch.rand(1, 1, h, w, generator=g) * 0.01
    f = {
        "albedo": torch.rand(1, 3, h, w, generator=g),
        "depth": torch.rand(1, 1, h, w, generator=g),
    }
    s = torch.rand(1, 1, h, w, generator=g) * 4 + 1
    return c, v, f, s


def _filters(tile):
    c, v, f, s = _inputs()
    with torch.no_grad():
        xbf = cross_bilateral(
            c,
            f,
            kernel_size=9,
            sigma_spatial=s,
            color_var=v,
            feature_vars={"albedo": v, "depth": None},
            tile=tile,
        )
        nlm = non_local_means(
            c, search_radius=3, patch_radius=3, color_var=v, features=f, tile=tile
        )
        robust = {"centre_weight": "max", "tile": tile}
        xbf_max = cross_bilateral(c, f, kernel_size=7, color_var=v, **robust)
        nlm_trim = non_local_means(
            c, search_radius=3, patch_radius=2, color_var=v, patch_trim=0.5, **robust
        )
    return xbf, nlm, xbf_max, nlm_trim


@pytest.mark.parametrize("tile", [32, (16, 50)])
def test_threaded_tiles_equal_one_thread(tile, two_threads) -> None:
    torch.set_num_threads(1)
    one = _filters(tile)
    torch.set_num_threads(2)
    two = _filters(tile)
    assert torch.get_num_threads() == 2  # restored
    for a, b in zip(one, two):
        assert torch.equal(a, b)


def test_parallel_map_keeps_order_raises_and_restores(two_threads) -> None:
    with torch.no_grad():
        assert parallel_map(lambda i: i * i, range(7)) == [i * i for i in range(7)]

        def boom(i: int) -> int:
            if i == 3:
                raise ValueError("three")
            return i

        with pytest.raises(ValueError, match="three"):
            parallel_map(boom, range(6))
    assert torch.get_num_threads() == 2


def test_single_threaded_ops_keeps_the_worker_count(two_threads) -> None:
    with single_threaded_ops() as n:
        assert n == 2 and torch.get_num_threads() == 1 and workers() == 2
        with single_threaded_ops() as inner:  # nested: no-op
            assert inner == 2
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == 2 and workers() == 2


def test_autograd_runs_serially_and_keeps_gradients(two_threads) -> None:
    c, v, f, s = _inputs(20, 24)
    s.requires_grad_(True)
    out = cross_bilateral(c, f, kernel_size=5, sigma_spatial=s, color_var=v, tile=8)
    out.sum().backward()
    assert s.grad is not None and bool(torch.isfinite(s.grad).all())
