"""Training losses: hand-computed values, bounds, masks, Vogels' asymmetry, float32 under autocast,
and the one relMSE shared with the evaluation metrics."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from mcdenoise import losses
from mcdenoise.eval import metrics
from mcdenoise.losses import (
    LOSSES,
    RELMSE_EPS,
    SMAPE_EPS,
    asymmetric,
    compute_loss,
    crop_log_relmse,
    l1,
    relative_squared_error,
    relmse,
    relmse_map,
    smape,
    smape_map,
    smape_relmse,
)

#: float32 epsilon. Two float32 means of the same N terms taken by different paths (another
#: reduction, another CPU's vector width) may differ by up to about N * EPS32 relative
#: (Higham's bound for reordering a sum of non-negative terms, (N - 1) * EPS32 / 2, for the
#: sum and again for the value it is compared with); the comparisons below of such means use
#: that, which is still far below any real error they guard against (a wrong mask, slope or
#: precision moves the loss by 1e-3 or more).
EPS32 = torch.finfo(torch.float32).eps


def _pixels(*values: float) -> torch.Tensor:
    """``(1, 3, 1, n)``: one grey pixel per value (the three channels equal)."""
    return torch.tensor(values, dtype=torch.float32).view(1, 1, 1, -1).expand(1, 3, 1, -1)


# --- values on hand-computed examples ------------------------------------------------------


def test_smape_hand_computed() -> None:
    d = _pixels(1.0, 2.0, 0.0, 3.0)
    r = _pixels(0.0, 1.0, 0.0, 3.0)
    # |d - r| / (|d| + |r| + 0.01) per pixel: 1/1.01, 1/3.01, 0 (docs/hard-cases.md item 26), 0
    want = (1 / 1.01 + 1 / 3.01 + 0 + 0) / 4
    assert SMAPE_EPS == 0.01
    assert float(smape(d, r)) == pytest.approx(want, rel=1e-6)
    m = smape_map(d, r)
    assert m.shape == d.shape
    assert m[0, :, 0, 1].tolist() == pytest.approx([1 / 3.01] * 3, rel=1e-6)


def test_relmse_and_l1_hand_computed() -> None:
    d = _pixels(2.0, 0.5, 0.1)
    r = _pixels(1.0, 0.0, 0.1)
    # (d - r)² / (r² + 0.01): 1/1.01, 0.25/0.01 = 25 (a zero reference stays finite), 0
    assert RELMSE_EPS == 0.01
    assert float(relmse(d, r)) == pytest.approx((1 / 1.01 + 25.0 + 0.0) / 3, rel=1e-6)
    assert float(l1(d, r)) == pytest.approx((1.0 + 0.5 + 0.0) / 3, rel=1e-6)


def test_compute_loss_dispatches_by_name() -> None:
    g = torch.Generator().manual_seed(1)
    d, r, x = (torch.rand(2, 3, 4, 4, generator=g) for _ in range(3))
    for name in ("smape", "relmse", "l1"):
        assert torch.equal(compute_loss(name, d, r), LOSSES[name](d, r))
    assert torch.equal(
        compute_loss("asymmetric", d, r, noisy=x, slope=3.0), asymmetric(d, r, x, slope=3.0)
    )
    with pytest.raises(ValueError, match="noisy"):
        compute_loss("asymmetric", d, r)
    with pytest.raises(ValueError, match="unknown loss 'l3'"):
        compute_loss("l3", d, r)
    with pytest.raises(ValueError, match="slope"):
        asymmetric(d, r, x, slope=0.5)


def test_smape_relmse_is_the_sum_and_makes_a_kept_firefly_expensive() -> None:
    g = torch.Generator().manual_seed(3)
    d, r = torch.rand(2, 3, 4, 4, generator=g), torch.rand(2, 3, 4, 4, generator=g)
    assert torch.allclose(compute_loss("smape+relmse", d, r), smape(d, r) + relmse(d, r))
    # one kept firefly among 64 pixels (12.7 where the reference is 0.17: caustics_glass at 64
    # spp): SMAPE charges it < 1/64, the sum (12.53² / (0.17² + 0.01) ≈ 4036) / 64
    ref = torch.full((1, 3, 8, 8), 0.17)
    out = ref.clone()
    out[..., 3, 4] = 12.7
    assert float(smape(out, ref)) < 1 / 64
    assert float(smape_relmse(out, ref)) > 4000 / 64


# --- the one relMSE: per element, per crop, and the same numbers as the metrics ---------------


def test_relmse_map_and_relative_squared_error_hand_computed() -> None:
    d = _pixels(2.0, 0.5, 0.1)
    r = _pixels(1.0, 0.0, 0.1)
    m = relmse_map(d, r)
    assert m.shape == d.shape and m.dtype == torch.float32
    assert m[0, 0, 0].tolist() == pytest.approx([1 / 1.01, 25.0, 0.0], rel=1e-6)
    assert torch.equal(relmse(d, r), m.mean())
    # an estimate of the squared error (e.g. a variance) in relMSE units, against any image
    var = torch.tensor([0.0101, 0.01])
    assert relative_squared_error(var, torch.tensor([1.0, 0.0])).tolist() == pytest.approx(
        [0.01, 1.0], rel=1e-6
    )


def test_the_epsilons_live_in_losses_and_the_metrics_use_them() -> None:
    assert metrics.RELMSE_EPS is losses.RELMSE_EPS and metrics.SMAPE_EPS is losses.SMAPE_EPS
    assert metrics.METRICS["relmse"].epsilon == RELMSE_EPS
    assert metrics.METRICS["smape"].epsilon == SMAPE_EPS


def test_torch_and_numpy_relmse_agree() -> None:
    g = torch.Generator().manual_seed(11)
    out = 10 ** (torch.rand(3, 9, 11, generator=g, dtype=torch.float64) * 6 - 3)
    ref = 10 ** (torch.rand(3, 9, 11, generator=g, dtype=torch.float64) * 6 - 3)
    ref[:, :2] = 0.0  # zero reference pixels stay finite in both
    want = metrics.relmse(out.numpy(), ref.numpy())
    assert math.isfinite(want)
    assert float(relmse(out[None], ref[None])) == pytest.approx(want, rel=1e-12)
    assert relmse_map(out, ref).mean(0).numpy() == pytest.approx(
        metrics.relmse_map(out, ref), rel=1e-12
    )
    sq = (out - ref).square()
    np.testing.assert_array_equal(
        relative_squared_error(sq, ref).numpy(),
        metrics.relative_squared_error(sq.numpy(), ref.numpy()),
    )


def test_relmse_ignores_masked_out_pixels() -> None:
    ref = torch.ones(1, 3, 4, 4)
    out = ref.clone()
    out[..., 0, 0] = 100.0
    mask = torch.ones(1, 1, 4, 4)
    mask[..., 0, 0] = 0
    assert float(relmse(out, ref, mask)) == 0.0
    assert float(relmse(out, ref)) > 0


def test_crop_log_relmse_is_the_mean_log_of_each_crops_masked_relmse() -> None:
    g = torch.Generator().manual_seed(12)
    d, r = torch.rand(3, 3, 6, 6, generator=g), torch.rand(3, 3, 6, 6, generator=g)
    mask = (torch.rand(3, 1, 6, 6, generator=g) < 0.5).float()
    mask[2] = 0.0  # a crop without weight counts as relMSE 0: log(floor)
    per = [float(relmse(d[i : i + 1], r[i : i + 1], mask[i : i + 1])) for i in range(3)]
    assert per[2] == 0.0
    want = sum(math.log(p + 1e-6) for p in per) / 3
    assert float(crop_log_relmse(d, r, mask)) == pytest.approx(want, rel=1e-5)
    assert float(crop_log_relmse(r, r, torch.ones_like(mask), floor=1e-3)) == pytest.approx(
        math.log(1e-3), rel=1e-6
    )
    # every crop counts alike: a crop 100x worse moves the loss by log(100) / 3, not 100x
    d2 = d.clone()
    d2[0] = r[0] + 10 * (d[0] - r[0])
    delta = float(crop_log_relmse(d2, r, mask)) - float(crop_log_relmse(d, r, mask))
    assert delta == pytest.approx(math.log(100) / 3, rel=1e-3)


def test_crop_log_relmse_is_float32_under_bf16_autocast() -> None:
    g = torch.Generator().manual_seed(13)
    d, r = (1e5 * torch.rand(2, 3, 6, 6, generator=g) for _ in range(2))
    mask = torch.ones(2, 1, 6, 6)
    db, rb = d.bfloat16(), r.bfloat16()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = crop_log_relmse(db, rb, mask)
    assert got.dtype == torch.float32
    assert float(got) == pytest.approx(float(crop_log_relmse(db.float(), rb.float(), mask)))


# --- SMAPE bounds ----------------------------------------------------------------------------


def test_smape_is_bounded_in_zero_one() -> None:
    g = torch.Generator().manual_seed(2)
    # HDR-like values over 8 decades, signed (negative outputs happen before clamping), exact zeros
    mag = 10 ** (torch.rand(4, 3, 32, 32, generator=g) * 8 - 4)
    sign = torch.where(torch.rand(mag.shape, generator=g) < 0.2, -1.0, 1.0)
    d = mag * sign
    r = 10 ** (torch.rand(mag.shape, generator=g) * 8 - 4)
    d[0, :, :4] = 0.0
    r[0, :, 2:6] = 0.0
    m = smape_map(d.double(), r.double())
    assert bool((m >= 0).all()) and bool((m < 1).all())
    # in float32 the ε is lost beside values >= 1e6: then the bound is only <= 1, still finite
    big = smape_map(_pixels(1e30, 0.0, 1e7), _pixels(0.0, 1e30, -1e7))
    assert bool(torch.isfinite(big).all()) and bool((big <= 1).all()) and bool((big >= 0).all())
    assert float(smape(d, r)) < 1.0


def test_smape_is_scale_invariant_far_from_epsilon() -> None:
    g = torch.Generator().manual_seed(3)
    d = 1 + torch.rand(1, 3, 8, 8, generator=g)
    r = 1 + torch.rand(1, 3, 8, 8, generator=g)
    a, b = float(smape(d * 100, r * 100)), float(smape(d * 1000, r * 1000))
    assert a == pytest.approx(b, rel=1e-4)
    # near ε the errors of dark pixels are damped (a pair 1e4 times darker costs < 1 %)
    assert float(smape(d * 1e-4, r * 1e-4)) < 0.05 * a


# --- masks -------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["smape", "relmse", "l1"])
def test_mask_averages_over_the_masked_pixels_only(name: str) -> None:
    g = torch.Generator().manual_seed(4)
    d = torch.rand(2, 3, 5, 6, generator=g)
    r = torch.rand(2, 3, 5, 6, generator=g)
    mask = (torch.rand(2, 1, 5, 6, generator=g) < 0.4).float()
    fn = LOSSES[name]
    sel = mask.expand_as(d).bool()
    want = fn(d[sel].view(1, 1, 1, -1), r[sel].view(1, 1, 1, -1))
    assert float(fn(d, r, mask)) == pytest.approx(float(want), rel=1e-5)
    # pixels outside the mask do not matter at all, however wrong
    d2 = torch.where(mask.bool(), d, torch.full_like(d, 1e6))
    assert float(fn(d2, r, mask)) == pytest.approx(float(fn(d, r, mask)), rel=1e-6)
    # an all-ones mask is the unmasked mean; an empty mask is 0, not 0/0
    # (a masked sum against the plain mean: d.numel() terms in two orders, EPS32 above)
    assert float(fn(d, r, torch.ones_like(mask))) == pytest.approx(
        float(fn(d, r)), rel=d.numel() * EPS32
    )
    assert float(fn(d, r, torch.zeros_like(mask))) == 0.0


# --- Vogels' asymmetric loss ---------------------------------------------------------------


def test_asymmetric_with_slope_one_is_smape() -> None:
    g = torch.Generator().manual_seed(5)
    d, r, x = (torch.rand(2, 3, 7, 7, generator=g) for _ in range(3))
    mask = (torch.rand(2, 1, 7, 7, generator=g) < 0.5).float()
    assert torch.equal(asymmetric(d, r, x, slope=1.0), smape(d, r))
    assert torch.equal(asymmetric(d, r, x, mask, slope=1.0), smape(d, r, mask))


# (output d, reference r, noisy x, on the far side of r from x?)
CASES = [
    (2.0, 1.0, 0.0, True),  # x below r, d overshoots above r
    (0.5, 1.0, 2.0, True),  # x above r, d undershoots below r
    (0.5, 1.0, 0.0, False),  # d between x and r: on the noisy input's side
    (1.5, 1.0, 2.0, False),  # the same from above
    (3.0, 1.0, 2.0, False),  # beyond the noisy input, same side
    (2.0, 1.0, 1.0, False),  # x == r: (r - x) = 0, no side
    (1.0, 1.0, 0.0, False),  # d == r: no error at all
    (-0.2, 0.3, 0.9, True),  # negative output below a reference the noise overshot
]


@pytest.mark.parametrize("slope", [2.0, 5.0])
def test_asymmetric_is_larger_exactly_on_the_far_side(slope: float) -> None:
    d = _pixels(*(c[0] for c in CASES))
    r = _pixels(*(c[1] for c in CASES))
    x = _pixels(*(c[2] for c in CASES))
    for i, (_, _, _, far) in enumerate(CASES):
        mask = torch.zeros(1, 1, 1, len(CASES))
        mask[..., i] = 1
        a = float(asymmetric(d, r, x, mask, slope=slope))
        s = float(smape(d, r, mask))
        if far:
            assert s > 0 and a == pytest.approx(slope * s, rel=1e-6), CASES[i]
        else:
            assert a == s, CASES[i]
    # the mean over every case: the far-side pixels' SMAPE counted `slope` times
    m = smape_map(d, r)[0, 0, 0]
    far = torch.tensor([c[3] for c in CASES])
    want = (m * torch.where(far, slope, 1.0)).mean()
    assert float(asymmetric(d, r, x, slope=slope)) == pytest.approx(float(want), rel=1e-6)


def test_asymmetric_on_random_data_matches_its_definition() -> None:
    g = torch.Generator().manual_seed(6)
    d, r, x = (torch.randn(3, 3, 9, 9, generator=g) for _ in range(3))
    far = (d - r) * (r - x) > 0
    assert 0.2 < float(far.float().mean()) < 0.8  # both kinds of pixels are present
    want = (smape_map(d, r) * torch.where(far, 3.0, 1.0)).mean()
    # the mean of d.numel() terms in two orders (EPS32 above)
    assert float(asymmetric(d, r, x, slope=3.0)) == pytest.approx(
        float(want), rel=d.numel() * EPS32
    )
    assert float(asymmetric(d, r, x, slope=3.0)) > float(smape(d, r))


# --- precision ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["smape", "relmse", "l1", "asymmetric"])
def test_losses_are_float32_under_bf16_autocast(name: str) -> None:
    g = torch.Generator().manual_seed(7)
    # HDR values near 1e5 (docs/hard-cases.md item 22): squares overflow half precision, not float32
    d, r, x = (1e5 * torch.rand(2, 3, 6, 6, generator=g) for _ in range(3))
    db, rb, xb = (t.bfloat16() for t in (d, r, x))
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = compute_loss(name, db, rb, noisy=xb)
    assert got.dtype == torch.float32
    assert bool(torch.isfinite(got))
    # equal to the float32 loss of the (rounded) bf16 values: nothing computed in bf16
    want = compute_loss(name, db.float(), rb.float(), noisy=xb.float())
    # a mean of d.numel() float32 terms, possibly by other kernels under autocast (EPS32
    # above); computed in bf16 it would be off by its rounding, 2**-8 = 4e-3
    assert float(got) == pytest.approx(float(want), rel=d.numel() * EPS32)


def test_float64_inputs_stay_float64() -> None:
    d = torch.rand(1, 3, 4, 4, dtype=torch.float64)
    r = torch.rand(1, 3, 4, 4, dtype=torch.float64)
    for name in ("smape", "relmse", "l1"):
        assert compute_loss(name, d, r).dtype == torch.float64
    assert asymmetric(d, r, r * 0.5).dtype == torch.float64


def test_smape_gradient_is_finite_at_zero() -> None:
    d = torch.zeros(1, 3, 2, 2, requires_grad=True)
    r = torch.zeros(1, 3, 2, 2)
    loss = smape(d, r)
    loss.backward()
    assert float(loss.detach()) == 0.0
    assert bool(torch.isfinite(d.grad).all())
