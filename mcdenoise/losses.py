"""Training losses on linear HDR colour: SMAPE, relMSE, L1 and Vogels' asymmetric loss.

Every loss takes ``output`` and ``reference`` of shape ``(B, 3, H, W)`` (linear HDR RGB, the
remodulated colour, not tonemapped) and an optional ``mask`` ``(B, 1, H, W)`` of 0/1 weights
(the crop centre away from borders); the mean is over the masked pixels and the channels.
They are computed in float32 (or float64 if the inputs are) even under autocast.

* ``smape``: ``|d - r| / (|d| + |r| + 0.01)`` (Vogels et al. 2018; OIDN's training uses the
  same ε). Scale-invariant and bounded by 1, so one bright firefly cannot dominate a batch.
* ``relmse``: ``(d - r)² / (r² + 0.01)`` (the evaluation metric of this package; the numpy
  twin used for evaluation is :func:`mcdenoise.eval.metrics.relmse`, with the same ε).
* ``smape+relmse``: their sum. SMAPE alone lets a network keep a rare isolated firefly (its
  cost is bounded by 1 per pixel); the relMSE term makes it expensive, while SMAPE keeps the
  bright, textured regions weighted (relMSE alone favours the dark ones).
* ``l1``: ``|d - r|``.
* ``asymmetric``: Vogels 2018, eq. 9: ``smape · (1 + (λ - 1) · H((d - r)(r - x)))`` with ``x``
  the noisy input and ``H`` the Heaviside step: a result on the *far side* of the reference from
  the noisy input (over-smoothed past it) costs λ times more, so the network keeps closer to the
  input where it is unsure: more detail, a little more residual noise. λ = 1 is SMAPE.

:func:`crop_log_relmse` (the ``log-relmse`` training loss) is the mean over the crops of a batch
of ``log(floor + relMSE of the crop)``: every crop counts alike, whatever its brightness.

This module owns the ε of every loss (:data:`RELMSE_EPS`, :data:`SMAPE_EPS`); the evaluation
metrics import them from here, so a loss and its metric cannot drift apart.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

#: ε of relMSE (Rousselle et al. 2011, Bako et al. 2017): keeps a zero reference finite.
RELMSE_EPS = 0.01
#: ε of SMAPE (Vogels et al. 2018; OIDN's training uses the same).
SMAPE_EPS = 0.01


def _masked_mean(err: Tensor, mask: Tensor | None) -> Tensor:
    if mask is None:
        return err.mean()
    mask = mask.to(err.dtype)
    return (err * mask).sum() / (mask.sum() * err.shape[1]).clamp_min(1.0)


def _f32(t: Tensor) -> Tensor:
    return t if t.dtype == torch.float64 else t.float()


def smape_map(output: Tensor, reference: Tensor) -> Tensor:
    """Per-element SMAPE ``|d - r| / (|d| + |r| + ε)``, same shape as the inputs."""
    d, r = _f32(output), _f32(reference)
    return (d - r).abs() / (d.abs() + r.abs() + SMAPE_EPS)


def smape(output: Tensor, reference: Tensor, mask: Tensor | None = None) -> Tensor:
    """Mean SMAPE over the masked pixels (scalar)."""
    with torch.autocast(output.device.type, enabled=False):
        return _masked_mean(smape_map(output, reference), mask)


def relative_squared_error(squared_error: Tensor, reference: Tensor) -> Tensor:
    """A squared error in relMSE units: ``squared_error / (r² + ε)``, elementwise.

    The one place the relMSE normalisation is written for tensors; :func:`relmse_map` gives it
    the squared error ``(d - r)²``, and an estimator of the squared error (e.g. SURE, or a
    variance) can be given instead, normalised by a reference-like image ``r``.

    Args:
        squared_error: any shape broadcastable with ``reference``.
        reference: linear HDR colour, e.g. ``(B, 3, H, W)``.
    """
    return squared_error / (reference.square() + RELMSE_EPS)


def relmse_map(output: Tensor, reference: Tensor) -> Tensor:
    """Per-element relMSE ``(d - r)² / (r² + ε)``, same shape as the inputs (float32 or 64)."""
    with torch.autocast(output.device.type, enabled=False):
        d, r = _f32(output), _f32(reference)
        return relative_squared_error((d - r).square(), r)


def relmse(output: Tensor, reference: Tensor, mask: Tensor | None = None) -> Tensor:
    """Mean relMSE ``(d - r)² / (r² + ε)`` over the masked pixels (scalar)."""
    with torch.autocast(output.device.type, enabled=False):
        return _masked_mean(relmse_map(output, reference), mask)


def crop_log_relmse(output: Tensor, reference: Tensor, mask: Tensor, floor: float = 1e-6) -> Tensor:
    """Mean over the batch of ``log(floor + relMSE of each crop's masked pixels)`` (scalar).

    Args:
        output, reference: ``(B, 3, H, W)`` linear HDR colour.
        mask: ``(B, 1, H, W)`` 0/1 weights; a crop without any weight counts as relMSE 0.
        floor: keeps the log finite for a crop matched exactly.
    """
    with torch.autocast(output.device.type, enabled=False):
        err = relmse_map(output, reference)
        mask = mask.to(err.dtype)
        per = (err * mask).sum((1, 2, 3)) / (mask.sum((1, 2, 3)) * err.shape[1]).clamp_min(1.0)
        return torch.log(per + floor).mean()


def smape_relmse(output: Tensor, reference: Tensor, mask: Tensor | None = None) -> Tensor:
    """SMAPE + relMSE over the masked pixels (scalar)."""
    return smape(output, reference, mask) + relmse(output, reference, mask)


def l1(output: Tensor, reference: Tensor, mask: Tensor | None = None) -> Tensor:
    """Mean absolute error over the masked pixels (scalar)."""
    with torch.autocast(output.device.type, enabled=False):
        return _masked_mean((_f32(output) - _f32(reference)).abs(), mask)


def asymmetric(
    output: Tensor,
    reference: Tensor,
    noisy: Tensor,
    mask: Tensor | None = None,
    slope: float = 2.0,
) -> Tensor:
    """Vogels' asymmetric SMAPE with slope λ = ``slope`` (see the module docstring).

    Args:
        noisy: the noisy input colour ``x`` ``(B, 3, H, W)``, same space as ``output``.
        slope: λ >= 1.
    """
    if slope < 1:
        raise ValueError(f"asymmetric loss slope must be >= 1, got {slope}")
    with torch.autocast(output.device.type, enabled=False):
        d, r, x = _f32(output), _f32(reference), _f32(noisy)
        far_side = ((d - r) * (r - x) > 0).to(d.dtype)
        return _masked_mean(smape_map(d, r) * (1 + (slope - 1) * far_side), mask)


LossFn = Callable[..., Tensor]
#: Loss name -> function ``(output, reference, mask)``; ``asymmetric`` also takes ``noisy``.
LOSSES: dict[str, LossFn] = {
    "smape": smape,
    "relmse": relmse,
    "smape+relmse": smape_relmse,
    "l1": l1,
    "asymmetric": asymmetric,
}


def temporal_smape(
    output: Tensor,
    previous: Tensor,
    reference: Tensor,
    previous_reference: Tensor,
    mask: Tensor | None = None,
) -> Tensor:
    """SMAPE of the output's frame difference against the reference's (scalar).

    ``smape(o_t - o_{t-1}, r_t - r_{t-1})`` over the masked pixels: the temporal term of
    Isik et al. 2021 / Balint et al. 2023 (their "temporal SMAPE" on consecutive frames;
    the previous frames are on frame ``t``'s grid, i.e. warped there by the caller, and
    ``mask`` holds 0 where that warp is invalid). Flicker (an output difference the
    reference does not have) costs up to 1 per element, like SMAPE itself.
    """
    return smape(output - previous, reference - previous_reference, mask)


def compute_loss(
    name: str,
    output: Tensor,
    reference: Tensor,
    mask: Tensor | None = None,
    *,
    noisy: Tensor | None = None,
    slope: float = 2.0,
) -> Tensor:
    """The loss ``name`` (a key of :data:`LOSSES`); ``noisy`` is required for ``asymmetric``."""
    if name == "asymmetric":
        if noisy is None:
            raise ValueError("the asymmetric loss needs the noisy input")
        return asymmetric(output, reference, noisy, mask, slope)
    if name not in LOSSES:
        raise ValueError(f"unknown loss {name!r}; known: {', '.join(LOSSES)}")
    return LOSSES[name](output, reference, mask)


__all__ = [
    "LOSSES",
    "RELMSE_EPS",
    "SMAPE_EPS",
    "asymmetric",
    "compute_loss",
    "crop_log_relmse",
    "l1",
    "relative_squared_error",
    "relmse",
    "relmse_map",
    "smape",
    "smape_map",
    "smape_relmse",
    "temporal_smape",
]
