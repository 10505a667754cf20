"""Input sources of the kernel-predicting CNN and its source-aware encoder (Vogels et al. 2018).

Renderers write different buffers. A *source* is a fixed set of buffers; each has its own small
encoder (two 3×3 convolutions) that maps its channels into one shared latent space, in front of
a shared trunk. A model trained on one source adapts to a new one by training only a new encoder
against the frozen trunk (``train --finetune-encoder``).

==========  ===============================================================  ==================
source      buffers                                                          who writes them
==========  ===============================================================  ==================
``full``    colour + its variance, albedo, normal, depth, position            ``mcdenoise render``
            (+ feature variances when present, else 0)
``basic``   colour, albedo, normal                                           Mitsuba AOV files,
                                                                             Cycles, OIDN users
``color``   colour only                                                      any beauty pass
==========  ===============================================================  ==================

``choose_source`` (``prep/kpcn.py``) takes the first of ``full``, ``basic``, ``color``
whose buffers the input has (among those the model was trained with).

Input channels (``prepare_tensors`` of ``prep/kpcn.py`` once per image, then
:func:`source_channels` per crop/tile, inside the network's forward): the sanitised colour is
demodulated by the albedo (``irr = c / (albedo + 0.01)``, :mod:`mcdenoise.filters.albedo`; the
texture is multiplied back after filtering; without albedo ``irr = c``); the network sees
``log1p(irr)`` (HDR values compressed), ``log1p(sqrt(var(irr)))``, the albedo, the normal,
depth / position divided by the scene extent (``prep/inputs.py``),
``log1p(sqrt(·))`` of the feature variances, and the gradient magnitudes
``|∂x f| + |∂y f|`` of the log colour and of every feature. Each channel is then normalised
with per-source mean / standard deviation measured on the training data (stored in the model).
Position enters only through its gradient: absolute world coordinates do not generalise
across scenes.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor, nn

from mcdenoise.filters.albedo import demodulate, demodulated_variance
from mcdenoise.models.features import FeatureStats

#: Sources in order of preference, with the buffers each needs.
SOURCES: dict[str, tuple[str, ...]] = {
    "full": ("color", "color_var", "albedo", "normal", "depth", "position"),
    "basic": ("color", "albedo", "normal"),
    "color": ("color",),
}
#: Feature variances the full source uses when present (zero otherwise).
FEATURE_VARS = ("albedo", "normal", "depth")


def channel_names(source: str) -> list[str]:
    """The network input channels of ``source``, in order."""
    names = ["log_r", "log_g", "log_b"]
    if source == "full":
        names.append("log_std")
    if source in ("full", "basic"):
        names += ["albedo_r", "albedo_g", "albedo_b", "normal_x", "normal_y", "normal_z"]
    if source == "full":
        names.append("depth")
        names += [f"log_std_{g}" for g in FEATURE_VARS]
    names.append("grad_log")
    if source in ("full", "basic"):
        names += ["grad_albedo", "grad_normal"]
    if source == "full":
        names += ["grad_depth", "grad_position"]
    return names


def _grad(x: Tensor) -> Tensor:
    """``|∂x| + |∂y|`` summed over channels, ``(B, 1, H, W)`` (forward differences, 0 at the edge)."""
    gx = torch.zeros_like(x)
    gy = torch.zeros_like(x)
    gx[..., :, :-1] = x[..., :, 1:] - x[..., :, :-1]
    gy[..., :-1, :] = x[..., 1:, :] - x[..., :-1, :]
    return (gx.abs() + gy.abs()).sum(1, keepdim=True)


def source_channels(source: str, t: Mapping[str, Tensor]) -> Tensor:
    """Raw (unnormalised) input channels ``(B, len(channel_names(source)), H, W)``.

    Args:
        t: prepared tensors ``(B, C, H, W)`` (``prepare_tensors`` of ``prep/kpcn.py``,
            batched), at least the buffers of ``source``.
    """
    irr, factor = demodulate(t["color"], t.get("albedo"))
    log = torch.log1p(irr)
    parts = [log]
    if source == "full":
        var = demodulated_variance(t["color_var"], factor)
        parts.append(torch.log1p(var.clamp_min(0).sqrt()))
    if source in ("full", "basic"):
        parts += [t["albedo"], t["normal"]]
    if source == "full":
        parts.append(t["depth"])
        parts += [torch.log1p(t[f"{g}_var"].clamp_min(0).sqrt()) for g in FEATURE_VARS]
    parts.append(_grad(log))
    if source in ("full", "basic"):
        parts += [_grad(t["albedo"]), _grad(t["normal"])]
    if source == "full":
        parts += [_grad(t["depth"]), _grad(t["position"])]
    return torch.cat(parts, dim=1)


class Normalizer(nn.Module):
    """Per-channel ``(x - mean) / std`` with statistics from the training data (buffers, saved
    with the weights); NaN -> 0 and values clamped to ±8 so no input can blow up the network."""

    def __init__(self, stats: FeatureStats) -> None:
        super().__init__()
        n = len(stats.names)
        self.register_buffer("mean", torch.tensor(stats.mean, dtype=torch.float32).view(1, n, 1, 1))
        self.register_buffer("std", torch.tensor(stats.std, dtype=torch.float32).view(1, n, 1, 1))

    def forward(self, x: Tensor) -> Tensor:
        z = (x - self.mean.to(x.dtype)) / self.std.to(x.dtype)
        return torch.nan_to_num(z, nan=0.0, posinf=8.0, neginf=-8.0).clamp(-8.0, 8.0)


def encoder(n_in: int, width: int) -> nn.Sequential:
    """A source's input module: two 3×3 convolutions with ReLU, ``n_in`` -> ``width`` channels."""
    return nn.Sequential(
        nn.Conv2d(n_in, width, 3, padding=1),
        nn.ReLU(inplace=True),
        nn.Conv2d(width, width, 3, padding=1),
        nn.ReLU(inplace=True),
    )


def shared_layout(z: Tensor, source: str) -> Tensor:
    """Normalised channels of ``source`` placed in the ``full`` layout, missing ones 0 (= the
    training mean): the input of the ``shared`` encoder, the ablation with one input layer
    for every source."""
    full = channel_names("full")
    index = [full.index(n) for n in channel_names(source)]
    # keep the caller's memory format: a plain new_zeros would turn a channels-last input into
    # NCHW and every convolution after it would run 1.3-1.8x slower on CPU
    last = z.is_contiguous(memory_format=torch.channels_last)
    fmt = torch.channels_last if last else torch.contiguous_format
    shape = (z.shape[0], len(full), *z.shape[2:])
    out = torch.empty(shape, dtype=z.dtype, device=z.device, memory_format=fmt).zero_()
    out[:, index] = z
    return out


__all__ = [
    "FEATURE_VARS",
    "SOURCES",
    "Normalizer",
    "channel_names",
    "encoder",
    "shared_layout",
    "source_channels",
]
