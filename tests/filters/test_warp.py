"""Tests of mcdenoise.filters.warp: backward warping by motion vectors with a validity mask."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from mcdenoise.errors import InputError
from mcdenoise.filters.warp import bilinear_taps, warp


def _grid(h: int, w: int, dtype: torch.dtype = torch.float64) -> tuple[torch.Tensor, torch.Tensor]:
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=dtype), torch.arange(w, dtype=dtype), indexing="ij"
    )
    return xs, ys


def test_zero_motion_is_the_identity() -> None:
    g = torch.Generator().manual_seed(0)
    img = torch.randn(2, 3, 17, 23, generator=g)
    out, mask = warp(img, torch.zeros(2, 2, 17, 23))
    assert torch.equal(out, img)
    assert bool((mask == 1).all())


@pytest.mark.parametrize("shift", [(0.3, -0.6), (-2.25, 1.75), (4.5, 0.125)])
def test_a_subpixel_translation_is_recovered_away_from_the_border(
    shift: tuple[float, float],
) -> None:
    """Frame t is frame t-1 moved by ``shift`` (pixels, x right, y down): the surface at p
    was at p - shift, so motion = -shift. A linear ramp is reproduced exactly by bilinear
    interpolation; a smooth pattern to within its curvature."""
    h, w = 40, 48
    tx, ty = shift
    xs, ys = _grid(h, w)

    def ramp(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return torch.stack([0.7 * x - 0.3 * y + 2.0, 0.1 * x + 0.9 * y])

    def smooth(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return (torch.sin(0.21 * x) * torch.cos(0.17 * y) + 0.05 * x)[None]

    motion = torch.stack([torch.full_like(xs, -tx), torch.full_like(xs, -ty)])[None]
    m = 6  # away from the border
    # bilinear error <= (f_xx + f_yy) / 8 = (0.21² + 0.17²) / 8 < 0.01 for the smooth one
    for fn, tol in ((ramp, 1e-12), (smooth, 0.01)):
        prev = fn(xs, ys)[None]
        cur = fn(xs - tx, ys - ty)[None]
        out, mask = warp(prev, motion)
        assert bool((mask[..., m:-m, m:-m] == 1).all())
        torch.testing.assert_close(out[..., m:-m, m:-m], cur[..., m:-m, m:-m], atol=tol, rtol=0)
        wrong, _ = warp(prev, -motion)  # the opposite convention is far off
        assert float((wrong - cur)[..., m:-m, m:-m].abs().max()) > 10 * tol


def test_the_convention_is_grid_sample_at_the_displaced_pixel_centre() -> None:
    """Sampling at p + 0.5 + motion in continuous film coordinates (align_corners=False)."""
    g = torch.Generator().manual_seed(1)
    h, w = 20, 24
    img = torch.randn(1, 2, h, w, generator=g, dtype=torch.float64)
    motion = (torch.rand(1, 2, h, w, generator=g, dtype=torch.float64) - 0.5) * 3.0
    out, mask = warp(img, motion)
    xs, ys = _grid(h, w)
    gx = (xs + 0.5 + motion[0, 0]) * (2.0 / w) - 1.0
    gy = (ys + 0.5 + motion[0, 1]) * (2.0 / h) - 1.0
    ref = F.grid_sample(img, torch.stack([gx, gy], -1)[None], mode="bilinear", align_corners=False)
    inner = (slice(None), slice(None), slice(3, -3), slice(3, -3))
    torch.testing.assert_close(out[inner], ref[inner], atol=1e-12, rtol=0)
    assert bool((mask[inner] == 1).all())


def test_out_of_frame_taps_are_dropped_and_the_weights_renormalised() -> None:
    img = torch.arange(1.0, 13.0, dtype=torch.float64).view(1, 1, 3, 4)
    motion = torch.zeros(1, 2, 3, 4, dtype=torch.float64)
    motion[:, 0] = -0.5  # half a pixel left: column 0 straddles the film's edge
    out, mask = warp(img, motion)
    torch.testing.assert_close(out[..., 0], img[..., 0])  # only its in-film tap, weight 1
    torch.testing.assert_close(out[..., 1:], 0.5 * (img[..., :-1] + img[..., 1:]))
    motion[:, 0] = 10.0  # everything leaves the film
    out, mask = warp(img, motion)
    assert bool((mask == 0).all()) and bool((out == 0).all())


@pytest.mark.parametrize("poison", [float("nan"), float("inf"), 1e38])
def test_invalid_pixels_are_never_read(poison: float) -> None:
    """NaN, Inf or a huge value on source pixels marked invalid, and under output pixels
    whose motion_valid is 0, changes nothing: the result is finite and identical."""
    g = torch.Generator().manual_seed(2)
    h, w = 16, 18
    img = torch.rand(1, 3, h, w, generator=g)
    motion = (torch.rand(1, 2, h, w, generator=g) - 0.5) * 4.0
    source_valid = torch.ones(1, 1, h, w)
    source_valid[..., 5:9, 4:10] = 0
    valid = torch.ones(1, 1, h, w)
    valid[..., 0:3, :] = 0
    clean, clean_mask = warp(img, motion, valid=valid, source_valid=source_valid)
    bad = img.clone()
    bad[..., 5:9, 4:10] = poison
    out, mask = warp(bad, motion, valid=valid, source_valid=source_valid)
    assert bool(torch.isfinite(out).all())
    assert torch.equal(out, clean) and torch.equal(mask, clean_mask)
    assert bool((mask[..., 0:3, :] == 0).all()) and bool((out[..., 0:3, :] == 0).all())
    # Output pixels with motion_valid = 0 read nothing, even the pixel under them.
    zero = torch.zeros(1, 2, h, w)
    hole = img.clone()
    hole[..., 0:3, :] = poison
    out, mask = warp(hole, zero, valid=valid)
    assert bool(torch.isfinite(out).all())
    torch.testing.assert_close(out[..., 3:, :], img[..., 3:, :], atol=0, rtol=0)


def test_tap_valid_drops_single_taps() -> None:
    img = torch.tensor([[[[1.0, 3.0]]]], dtype=torch.float64)  # one row, two pixels
    motion = torch.zeros(1, 2, 1, 2, dtype=torch.float64)
    motion[:, 0, 0, 0] = 0.25  # pixel 0 reads 0.75 * img[0] + 0.25 * img[1]
    out, _ = warp(img, motion)
    assert float(out[0, 0, 0, 0]) == pytest.approx(1.5)
    tap_valid = torch.ones(1, 4, 1, 2, dtype=torch.bool)
    tap_valid[:, 1] = False  # the (1, 0) tap
    out, mask = warp(img, motion, tap_valid=tap_valid)
    assert float(out[0, 0, 0, 0]) == 1.0 and bool(mask.all())


def test_non_finite_motion_reads_nothing() -> None:
    motion = torch.zeros(1, 2, 4, 4)
    motion[0, 0, 1, 1] = float("nan")
    motion[0, 1, 2, 2] = float("inf")
    motion[0, 0, 3, 3] = 1e30
    out, mask = warp(torch.ones(1, 1, 4, 4), motion)
    assert bool(torch.isfinite(out).all())
    assert mask[0, 0, 1, 1] == 0 and mask[0, 0, 2, 2] == 0 and mask[0, 0, 3, 3] == 0
    assert int(mask.sum()) == 13


def test_gradcheck_wrt_the_image() -> None:
    g = torch.Generator().manual_seed(3)
    h, w = 5, 6
    img = torch.randn(1, 2, h, w, generator=g, dtype=torch.float64, requires_grad=True)
    motion = (torch.rand(1, 2, h, w, generator=g, dtype=torch.float64) - 0.5) * 3.0
    valid = (torch.rand(1, 1, h, w, generator=g) > 0.2).double()
    source_valid = (torch.rand(1, 1, h, w, generator=g) > 0.2).double()
    assert torch.autograd.gradcheck(
        lambda x: warp(x, motion, valid=valid, source_valid=source_valid)[0], (img,)
    )


def test_gradcheck_wrt_the_motion_inside_the_film() -> None:
    g = torch.Generator().manual_seed(4)
    h, w = 6, 7
    img = torch.randn(1, 2, h, w, generator=g, dtype=torch.float64)
    # fractional parts in [0.2, 0.8]: no tap crosses a pixel boundary under the probe
    base = torch.rand(1, 2, h, w, generator=g, dtype=torch.float64) * 0.6 + 0.2
    xs, ys = _grid(h, w)
    # keep every tap on the film: move towards the centre
    base[:, 0] = base[:, 0] - (xs > w / 2).double()
    base[:, 1] = base[:, 1] - (ys > h / 2).double()
    motion = base.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda m: warp(img, m)[0], (motion,))


def test_bad_shapes_are_one_line_errors() -> None:
    with pytest.raises(InputError, match="motion"):
        warp(torch.zeros(1, 3, 4, 4), torch.zeros(1, 3, 4, 4))
    with pytest.raises(InputError, match="does not fit"):
        warp(torch.zeros(1, 3, 4, 4), torch.zeros(1, 2, 4, 5))
    with pytest.raises(InputError, match="valid"):
        warp(torch.zeros(1, 3, 4, 4), torch.zeros(1, 2, 4, 4), valid=torch.ones(1, 4, 4))


def test_taps_are_falcors_floor_and_frac() -> None:
    motion = torch.tensor([1.25, -0.5]).view(1, 2, 1, 1).expand(1, 2, 3, 3).contiguous()
    taps = bilinear_taps(motion)
    # pixel (1, 1): sample at x = 2.25, y = 0.5 -> taps (2, 0), (3, 0), (2, 1), (3, 1)
    assert taps.x[0, :, 1, 1].tolist() == [2, 3, 2, 3]
    assert taps.y[0, :, 1, 1].tolist() == [0, 0, 1, 1]
    torch.testing.assert_close(taps.weight[0, :, 1, 1], torch.tensor([0.375, 0.125, 0.375, 0.125]))
    assert taps.inside[0, :, 1, 1].tolist() == [True, False, True, False]


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu() -> None:
    g = torch.Generator().manual_seed(5)
    img = torch.randn(1, 3, 32, 40, generator=g)
    motion = (torch.rand(1, 2, 32, 40, generator=g) - 0.5) * 6.0
    valid = (torch.rand(1, 1, 32, 40, generator=g) > 0.1).float()
    a, ma = warp(img, motion, valid=valid)
    b, mb = warp(img.cuda(), motion.cuda(), valid=valid.cuda())
    torch.testing.assert_close(b.cpu(), a, atol=1e-6, rtol=1e-6)
    assert torch.equal(mb.cpu(), ma)
