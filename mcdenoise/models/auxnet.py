"""``auxnet``: the learned prefilter of noisy albedo and normal buffers.

A path tracer's albedo and normal are the means of the same few samples as the colour. Where
the samples of a pixel see different surfaces (depth of field, motion, texture and geometry
finer than a pixel, glossy first hits) they are noisy, and ``kpcn`` multiplies its filtered
irradiance back by the albedo it is given. OIDN denoises its auxiliary images with networks
of their own for this reason; this is ours: a small U-Net that predicts, per pixel and per
buffer kind, a normalised ``k × k`` kernel applied to the noisy buffer itself (kernel
prediction, Bako et al. 2017). A kernel can only average what the buffer holds, so the
result stays in the buffer's range (an albedo never leaves ``[min, max]`` of its
neighbourhood, a background normal of 0 stays 0) and a net trained on one renderer's buffers
cannot invent values for another's.

Inputs per pixel (:func:`net_inputs`, 15 channels): ``log1p`` of the albedo, the normal, the
normal's length (shorter than 1 where a pixel's samples saw different orientations or the
background), ``log1p`` of the colour brought to a standard exposure, two noise levels (the
colour's relative standard deviation and the albedo's, estimated from its neighbourhood: a
file need not say how many samples it has, and without them a net blurs a clean 64-spp
texture as it blurs a 4-spp one), and, where the file has them, the albedo's and normal's variances of the mean (as ``log1p(10·sqrt(v))``) with a flag
channel saying whether they are present (files without variances get zeros and flag 0; the
trainer shows every crop both ways).

The card records the widths, the kernel size and the buffer kinds; the model imports only
torch and :mod:`mcdenoise.modelfile`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from mcdenoise.errors import InputError
from mcdenoise.modelfile import (
    MAX_KERNEL,
    MAX_WIDTH,
    Card,
    CardModule,
    check_model_size,
)

#: Model-file format tag of an auxnet card.
FORMAT = "mcdenoise.auxnet/1"
#: Buffer kinds the net filters, in output order, and their channel counts.
KINDS = {"albedo": 3, "normal": 3}
#: Input channels of :func:`net_inputs`.
IN_CHANNELS = 15


def _variance_channel(v: Tensor | None, like: Tensor) -> Tensor:
    if v is None:
        return like.new_zeros(like.shape[0], 1, *like.shape[2:])
    return torch.log1p(10.0 * v.clamp_min(0).mean(dim=1, keepdim=True).sqrt())


def net_inputs(
    albedo: Tensor,
    normal: Tensor,
    color: Tensor,
    color_noise: Tensor,
    albedo_noise: Tensor,
    albedo_var: Tensor | None = None,
    normal_var: Tensor | None = None,
) -> Tensor:
    """The ``(B, 15, H, W)`` input of :class:`AuxNet`.

    Args:
        albedo, normal: ``(B, 3, H, W)`` noisy buffers as the renderer wrote them (sanitised).
        color: ``(B, 3, H, W)`` linear colour, already brought to the standard exposure
            (:func:`mcdenoise.prep.inputs.exposure_scale`).
        color_noise: ``(B, 1, H, W)`` the colour's relative standard deviation of the mean
            (``sqrt(color_var) / (luminance + 0.01)``): how many samples the pixel has, as
            far as the net can tell on a file that does not say.
        albedo_noise: ``(B, 1, H, W)`` the albedo's standard deviation estimated from its
            own neighbourhood (:func:`mcdenoise.prep.inputs.estimate_feature_variance`).
        albedo_var, normal_var: ``(B, 1 or 3, H, W)`` variances of the mean, or ``None``.
    """
    has = albedo_var is not None and normal_var is not None
    flag = albedo.new_full((albedo.shape[0], 1, *albedo.shape[2:]), 1.0 if has else 0.0)
    length = normal.square().sum(dim=1, keepdim=True).sqrt()
    return torch.cat(
        [
            torch.log1p(albedo.clamp_min(0)),
            normal,
            length,
            torch.log1p(color.clamp_min(0)),
            torch.log1p(10.0 * color_noise.clamp_min(0)),
            torch.log1p(10.0 * albedo_noise.clamp_min(0)),
            _variance_channel(albedo_var if has else None, albedo),
            _variance_channel(normal_var if has else None, albedo),
            flag,
        ],
        dim=1,
    )


def apply_kernels(x: Tensor, weights: Tensor, k: int) -> Tensor:
    """``sum_j w_j · x(p + o_j)`` over the ``k × k`` offsets, edges replicated.

    Args:
        x: ``(B, C, H, W)``; weights: ``(B, k², H, W)`` (normalised).
    """
    r = k // 2
    h, w = x.shape[-2:]
    xp = F.pad(x, (r, r, r, r), mode="replicate")
    out = torch.zeros_like(x)
    j = 0
    for dy in range(k):
        for dx in range(k):
            out = out + weights[:, j : j + 1] * xp[:, :, dy : dy + h, dx : dx + w]
            j += 1
    return out


@dataclass
class AuxCard(Card):
    """What an auxnet model file records besides the weights.

    Attributes:
        widths: channels of the U-Net's levels (half, quarter, eighth resolution, ...).
        kernel: edge of the predicted kernels (odd).
        training: what it was trained on (filled by the trainer).
    """

    widths: list[int] = field(default_factory=lambda: [24, 32, 48])
    kernel: int = 7
    training: dict[str, Any] = field(default_factory=dict)
    format: str = FORMAT

    def check(self, what: str = "model") -> None:
        if not 2 <= len(self.widths) <= 5 or any(not 1 <= c <= MAX_WIDTH for c in self.widths):
            raise InputError(f"{what}: widths must be 2 to 5 levels of 1 to {MAX_WIDTH}")
        if self.kernel < 1 or self.kernel % 2 == 0 or self.kernel > MAX_KERNEL:
            raise InputError(f"{what}: kernel must be odd, 1 to {MAX_KERNEL}, got {self.kernel}")

    @staticmethod
    def from_dict(d: Mapping[str, Any], what: str = "model file") -> AuxCard:
        """The card of a model file: fields type- and range-checked, the network's size
        bounded (:mod:`mcdenoise.modelfile`) before anything is built."""
        f = AuxCard.fields(d, what)
        card = AuxCard(
            widths=f.integers("widths", 1, MAX_WIDTH),
            kernel=f.integer("kernel", 1, MAX_KERNEL, odd=True),
            training=f.mapping("training", default={}),
        )
        card.check(what)
        check_model_size(lambda: AuxNet(card), what)
        return card


def _block(a: int, b: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(a, b, 3, padding=1), nn.ReLU(), nn.Conv2d(b, b, 3, padding=1), nn.ReLU()
    )


class AuxNet(CardModule):
    """U-Net at half resolution -> per-kind kernel logits at full resolution.

    The full-resolution input is folded into its 2×2 blocks (``pixel_unshuffle``: 4× the
    channels at half the size, no information lost) and the U-Net (average-pool down,
    nearest up, skip concatenation) runs from there; its head predicts each pixel's kernels
    for the four pixels of its block (``pixel_shuffle`` back). Running no convolution at full
    resolution makes it about 4× cheaper than the same U-Net one level up.

    ``forward(x)`` takes :func:`net_inputs` and returns the kernel weights
    ``(B, len(KINDS) · k², H, W)``; :meth:`filter` applies them. ``H`` and ``W`` must be
    multiples of :attr:`multiple` (callers pad).
    """

    card_class = AuxCard

    def __init__(self, card: AuxCard) -> None:
        super().__init__()
        card.check()
        self.card = card
        w = card.widths
        self.enc = nn.ModuleList([_block(4 * IN_CHANNELS, w[0])])
        self.enc.extend(_block(w[i - 1], w[i]) for i in range(1, len(w)))
        self.dec = nn.ModuleList(_block(w[i] + w[i + 1], w[i]) for i in range(len(w) - 1))
        k2 = card.kernel * card.kernel
        self.head = nn.Conv2d(w[0], 4 * len(KINDS) * k2, 1)
        # start near a box filter with some preference for the pixel itself: a saturated
        # centre tap would have no gradient
        nn.init.zeros_(self.head.weight)
        with torch.no_grad():
            bias = torch.zeros(len(KINDS), k2, 4)
            bias[:, k2 // 2] = 1.0
            self.head.bias.copy_(bias.flatten())

    @property
    def multiple(self) -> int:
        return 2 ** len(self.card.widths)

    def forward(self, x: Tensor) -> Tensor:
        x = torch.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0)
        x = F.pixel_unshuffle(x, 2)
        skips = []
        for i, block in enumerate(self.enc):
            if i:
                x = F.avg_pool2d(x, 2)
            x = block(x)
            skips.append(x)
        for i in range(len(self.dec) - 1, -1, -1):
            x = F.interpolate(x, scale_factor=2.0, mode="nearest")
            x = self.dec[i](torch.cat([skips[i], x], dim=1))
        logits = F.pixel_shuffle(self.head(x).float(), 2)
        k2 = self.card.kernel**2
        b, _, h, w = logits.shape
        return torch.softmax(logits.view(b, len(KINDS), k2, h, w), dim=2).view(b, -1, h, w)

    def filter(self, weights: Tensor, buffers: Mapping[str, Tensor]) -> dict[str, Tensor]:
        """Each kind of ``buffers`` (``(B, C, H, W)``) averaged by its predicted kernels."""
        k = self.card.kernel
        k2 = k * k
        out = {}
        for i, name in enumerate(KINDS):
            if name in buffers:
                out[name] = apply_kernels(
                    buffers[name].float(), weights[:, i * k2 : (i + 1) * k2], k
                )
        return out


__all__ = ["FORMAT", "IN_CHANNELS", "KINDS", "AuxCard", "AuxNet", "apply_kernels", "net_inputs"]
