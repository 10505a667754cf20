"""The parts of the temporal kpcn (:mod:`mcdenoise.models.kpcn_temporal`): the joint kernels
over the frames of a window (one softmax over every tap of every frame), the temporal module
that corrects each frame's kernel (:class:`TemporalMixer`), its noise inputs, and the
recurrent source of the causal model (:class:`RecurrentBlend`, with its history clamp).

Every function takes and returns ``(B, C, H, W)`` tensors and is finite for any input (NaN
logits count as 0, invalid taps get weight exactly 0).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from mcdenoise.models.multiscale import LOGIT_LIMIT

#: Initial logit bias of the centre frame's taps: with 5 frames its kernel starts with
#: e² / (e² + 4) = 65 % of the weight, each other frame 9 %. Equal weights (0) made the
#: untrained model 3.5× worse than the single-frame one on validation sequences (a firefly of
#: a neighbour frame, blurred by the warp, is no longer recognised as one by that frame's own
#: kernel); starting near the single-frame model, training adds the neighbours where they help.
CENTRE_BIAS = 2.0
#: Kernel edge of the recurrent source (the previous output, warped to frame t).
RECURRENT_KERNEL = 3
#: Initial logit of the recurrent blend weight β: sigmoid(−1) = 27 % of the previous output
#: where it is valid, before training.
RECURRENT_BIAS = -1.0
#: Initial logit bias of the recurrent kernel's centre tap (its other taps start at 0).
RECURRENT_CENTRE = 2.0


# --- the joint kernels ------------------------------------------------------------------------
def tap_valid(mask: Tensor, kernel: int) -> Tensor:
    """``(B, k², H, W)`` bool: tap ``(dy, dx)`` of pixel ``p`` reads a valid pixel
    (``mask(p + (dy, dx)) > 0.5`` and inside the image); channel order of ``F.unfold``."""
    b, _, h, w = mask.shape
    taps = F.unfold(mask.to(torch.float32), kernel, padding=kernel // 2)
    return (taps > 0.5).view(b, kernel * kernel, h, w)


def joint_kernel_softmax(logits: Sequence[Tensor], valid: Sequence[Tensor]) -> list[Tensor]:
    """One softmax over all taps of all frames: ``N`` logits ``(B, k², H, W)`` -> ``N`` weights.

    Taps whose ``valid`` ``(B, k², H, W)`` (:func:`tap_valid`) is False get weight exactly 0;
    NaN logits count as 0 and ±Inf / huge values are clamped to ±:data:`LOGIT_LIMIT` (the
    maximum is subtracted before ``exp``), so the weights are finite, non-negative and sum to
    1 over the window wherever one tap is valid (the centre frame's centre tap always is).
    Computed in float32 (float64 kept for gradcheck), autocast off.
    """
    n = len(logits)
    with torch.autocast(logits[0].device.type, enabled=False):
        z = torch.stack(list(logits), dim=1)
        z = z if z.dtype in (torch.float32, torch.float64) else z.float()
        z = torch.nan_to_num(z, nan=0.0, posinf=LOGIT_LIMIT, neginf=-LOGIT_LIMIT)
        ok = torch.stack(list(valid), dim=1)
        z = torch.where(ok, z, torch.full((), -math.inf, dtype=z.dtype, device=z.device))
        b, _, kk, h, w = z.shape
        wts = torch.softmax(z.reshape(b, n * kk, h, w), dim=1)
        wts = torch.nan_to_num(wts, nan=0.0)  # a pixel with no valid tap at all: weight 0
        return list(wts.view(b, n, kk, h, w).unbind(1))


def frame_log_softmax(logits: Tensor, valid: Tensor) -> Tensor:
    """Log of one frame's own kernel weights: ``logits`` minus their log-sum-exp over
    ``valid`` taps (NaN -> 0, ±Inf clamped as in :func:`joint_kernel_softmax`).

    The model passes the *in-image* taps, not the frame's valid ones: a neighbour frame keeps
    the weight its own kernel gives each tap, and the taps on invalid pixels are then dropped
    by the joint softmax, so a frame whose kernel wanted mostly invalid pixels (a
    disocclusion, an edge) contributes little. Renormalising over the valid taps instead gave
    all of such a frame's share to the few valid taps its kernel had almost ignored, across
    the edge: 10× the single-frame relMSE on disoccluded pixels before training (held-out
    random-9000-000003, glossy_env).

    The single-frame head's logits carry an arbitrary per-pixel offset (a softmax ignores it),
    so two frames' raw logits cannot be compared: a joint softmax of raw logits would follow
    whichever frame's offset happens to be larger (measured: 18× the single-frame relMSE on a
    training sequence before training). Normalised per frame first, a joint softmax of these
    gives every frame the same total weight (the mean of the per-frame kernels over the valid
    frames), which the temporal module's corrections then reweight.
    """
    z = logits if logits.dtype in (torch.float32, torch.float64) else logits.float()
    z = torch.nan_to_num(z, nan=0.0, posinf=LOGIT_LIMIT, neginf=-LOGIT_LIMIT)
    masked = torch.where(valid, z, torch.full((), -LOGIT_LIMIT, dtype=z.dtype, device=z.device))
    return z - torch.logsumexp(masked, dim=1, keepdim=True)


def apply_joint(images: Sequence[Tensor], weights: Sequence[Tensor]) -> Tensor:
    """``Σ_i Σ_taps w_i · image_i(p + tap)``: per-pixel kernels of every frame applied to that
    frame and summed. ``images`` ``(B, C, H, W)``, ``weights`` ``(B, k², H, W)`` (taps in
    ``F.unfold`` order); out-of-image taps read 0 (their weight is 0 by construction)."""
    kk = weights[0].shape[1]
    k = round(kk**0.5)
    r = k // 2
    h, w = images[0].shape[-2:]
    out = torch.zeros_like(images[0])
    for img, wt in zip(images, weights):
        padded = F.pad(img, (r, r, r, r))
        for dy in range(k):
            for dx in range(k):
                tap = dy * k + dx
                out = out + wt[:, tap : tap + 1] * padded[..., dy : dy + h, dx : dx + w]
    return out


def min_pool(mask: Tensor) -> Tensor:
    """2×2 min-pooling: a coarse pixel is valid when all four below it are."""
    return -F.max_pool2d(-mask, 2)


def box3(x: Tensor) -> Tensor:
    """3×3 box mean (replicate padding)."""
    return F.avg_pool2d(F.pad(x, (1, 1, 1, 1), mode="replicate"), 3, stride=1)


def noise_inputs(
    images: Sequence[Tensor], variances: Sequence[Tensor], masks: Sequence[Tensor], centre: int
) -> list[Tensor]:
    """Per frame ``(B, 2, h, w)``: how far its warped irradiance is from frame t's, in units
    of their noise, and how much noisier it is (the temporal module's extra inputs, card
    ``inputs`` 2).

    Channel 0: ``log1p(mean_c (box3(x_i) − box3(x_t))² / ((v_i + v_t) / 9 + ε))``, where
    ``box3`` is the 3×3 mean and ``v`` the per-pixel variance of the mean (its 3×3 mean, i.e.
    the variance of ``box3(x)`` under independent pixels); ε = 1e-4 (x_t² + 1e-2) keeps it
    finite and scale-free. Near 0 where the two frames agree within their noise; large at a
    disocclusion, a moving shadow or a neighbour's firefly.
    Channel 1: ``log((v̄_i + ε) / (v̄_t + ε))`` (channel means, clamped to ±10).
    Frame t's own channels are 0; invalid pixels (mask 0) are 0 too.
    """
    xc = box3(images[centre])
    vc = box3(variances[centre].clamp_min(0.0))
    out = []
    for i, (x, v, m) in enumerate(zip(images, variances, masks)):
        if i == centre:
            out.append(torch.zeros_like(xc[:, :2]))
            continue
        vi = box3(v.clamp_min(0.0))
        eps = 1e-4 * (xc.square() + 1e-2)
        z = ((box3(x) - xc).square() / ((vi + vc) / 9.0 + eps)).mean(1, keepdim=True)
        r = torch.log((vi.mean(1, keepdim=True) + 1e-6) / (vc.mean(1, keepdim=True) + 1e-6))
        feats = torch.cat([torch.log1p(z), r.clamp(-10.0, 10.0)], dim=1)
        out.append(torch.nan_to_num(feats) * (m > 0.5).to(feats.dtype))
    return out


# --- the recurrent source ------------------------------------------------------------------------
def clamp_history(prev: Tensor, noisy: Tensor) -> Tensor:
    """``prev`` clamped per channel to the range of ``noisy`` over each pixel's 3×3
    neighbourhood (temporal anti-aliasing's neighbourhood clamp, on the noisy frame so that
    its range is wide): a history value no pixel around it in frame t comes near, such as a
    specular highlight that moved unlike the surface under it (mirrors, the motion vectors
    follow the surface) or an HDR edge spread by the bilinear warp, cannot persist."""
    padded = F.pad(noisy, (1, 1, 1, 1), mode="replicate")
    hi = F.max_pool2d(padded, 3, stride=1)
    lo = -F.max_pool2d(-padded, 3, stride=1)
    return torch.minimum(torch.maximum(prev, lo), hi)


class RecurrentBlend(nn.Module):
    """The previous output as a kernel source (card ``recurrent``; the practical real-time
    denoisers' recurrence, e.g. Chaitanya et al. 2017, Schied et al. 2017's history).

    ``x = (1 − β) · r + β · K ⊛ p``: ``r`` is this frame's kernel result (irradiance), ``p``
    the previous output warped to frame t and demodulated by frame t's albedo factor, ``K`` a
    :data:`RECURRENT_KERNEL`² kernel over ``p``'s valid taps and ``β = sigmoid(·) · mask``.
    Both come from a small network over ``[f_t (finest trunk features), log1p r, log1p p,
    |r − p| / (r + p + 0.02), mask]``. Its last layer starts at zero: ``β`` starts at
    sigmoid(:data:`RECURRENT_BIAS`), ``K`` centred (:data:`RECURRENT_CENTRE`). Where the
    previous output is invalid (a disocclusion, the first frame) ``β = 0`` and ``x = r``.
    """

    def __init__(self, channels: int, hidden: int = 16) -> None:
        super().__init__()
        k = RECURRENT_KERNEL
        self.net = nn.Sequential(
            nn.Conv2d(channels + 8, hidden, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(hidden, hidden, 3, padding=1),
            nn.ReLU(inplace=True),
        )
        self.out = nn.Conv2d(hidden, k * k + 1, 1)
        nn.init.zeros_(self.out.weight)
        with torch.no_grad():
            self.out.bias.zero_()
            self.out.bias[k * k // 2] = RECURRENT_CENTRE
            self.out.bias[k * k] = RECURRENT_BIAS

    def forward(
        self, feats: Tensor, res: Tensor, prev: Tensor, mask: Tensor, noisy: Tensor | None = None
    ) -> Tensor:
        """``noisy``: frame t's noisy irradiance; the history is clamped to its 3×3 range
        (:func:`clamp_history`) first."""
        k = RECURRENT_KERNEL
        valid = (mask > 0.5).to(res.dtype)
        if noisy is not None:
            prev = clamp_history(prev, noisy.to(res.dtype))
        prev = prev * valid
        diff = ((res - prev).abs() / (res.abs() + prev.abs() + 0.02)).mean(1, keepdim=True)
        x = torch.cat(
            [
                feats.to(res.dtype),
                torch.log1p(res.clamp_min(0.0)),
                torch.log1p(prev.clamp_min(0.0)),
                diff * valid,
                valid,
            ],
            dim=1,
        )
        y = self.out(self.net(x))
        wts = joint_kernel_softmax([y[:, : k * k]], [tap_valid(valid, k)])
        beta = torch.sigmoid(y[:, k * k :]) * valid
        return (1.0 - beta) * res + beta * apply_joint([prev], wts)


# --- the temporal module -----------------------------------------------------------------------
class TemporalMixer(nn.Module):
    """Per-scale temporal module: per-frame logit corrections ``Δ_i`` and a context (see the
    module docstring). ``out`` and ``alpha`` start at zero."""

    def __init__(self, channels: int, hidden: int, kernel: int, extra: int = 0) -> None:
        super().__init__()
        #: channels of per-frame extra inputs (:func:`noise_inputs`)
        self.extra = extra
        self.frame = nn.Sequential(
            nn.Conv2d(2 * channels + 2 + extra, hidden, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(hidden, hidden, 3, padding=1),
            nn.ReLU(inplace=True),
        )
        self.out = nn.Conv2d(2 * hidden, kernel * kernel, 1)
        self.alpha = nn.Conv2d(hidden, 1, 1)
        for conv in (self.out, self.alpha):
            nn.init.zeros_(conv.weight)
            nn.init.zeros_(conv.bias)
        #: Logit added to every tap of the centre frame (:data:`CENTRE_BIAS` at the start).
        self.centre_bias = nn.Parameter(torch.tensor(CENTRE_BIAS))

    def forward(
        self,
        feats: Sequence[Tensor],
        masks: Sequence[Tensor],
        centre: int,
        extra: Sequence[Tensor] | None = None,
    ) -> tuple[list[Tensor], Tensor]:
        """``(Δ logits per frame, compositor logit correction (B, 1, h, w))``; ``extra``: per
        frame the :func:`noise_inputs` (when the module was built for them)."""
        fc = feats[centre]
        n, b = len(feats), fc.shape[0]
        more = list(extra) if self.extra else [fc[:, :0]] * n
        x = torch.cat(
            [
                torch.cat(
                    [
                        f,
                        f - fc,
                        m.to(f.dtype),
                        torch.full_like(m, float(i == centre), dtype=f.dtype),
                        e.to(f.dtype),
                    ],
                    dim=1,
                )
                for i, (f, m, e) in enumerate(zip(feats, masks, more))
            ],
            dim=0,
        )
        hid = self.frame(x).view(n, b, -1, *fc.shape[-2:])
        m = torch.stack([mm.to(hid.dtype) for mm in masks])  # (N, B, 1, h, w)
        ctx = (hid * m).sum(0) / m.sum(0).clamp_min(1.0)
        deltas = [
            self.out(torch.cat([hid[i], ctx], dim=1)) + (self.centre_bias if i == centre else 0.0)
            for i in range(n)
        ]
        return deltas, self.alpha(ctx)


__all__ = [
    "CENTRE_BIAS",
    "RECURRENT_BIAS",
    "RECURRENT_CENTRE",
    "RECURRENT_KERNEL",
    "RecurrentBlend",
    "TemporalMixer",
    "apply_joint",
    "box3",
    "clamp_history",
    "frame_log_softmax",
    "joint_kernel_softmax",
    "min_pool",
    "noise_inputs",
    "tap_valid",
]
