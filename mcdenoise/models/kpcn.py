"""Kernel-predicting CNN (Bako et al. 2017) with a source-aware encoder and multi-scale kernels
(Vogels et al. 2018).

Data flow of one image (``(B, C, H, W)`` tensors, linear HDR colour)::

    buffers --prepare_tensors--> colour, variance, albedo, normal, depth, position ...
                                                                          (prep/kpcn.py)
      --source_channels--> log colour, log std, features, gradients      (encoders.py)
      --Normalizer + the source's encoder--> latent (channels[0] wide, full resolution)
      --U-Net trunk--> decoder features at full, 1/2, 1/4 ... resolution
      --per scale s: 1×1 head -> k² logits -> float32 softmax -> kernels applied to the
        demodulated colour box-downsampled s times                        (multiscale.py)
      --scale compositor (learned per-pixel α), coarse to fine--> irradiance
      --× (albedo + 0.01), clamp >= 0, NaN -> 0--> denoised colour

With ``albedo_kernels`` the remodulation factor ``albedo + 0.01`` is itself filtered first, by
a second set of predicted full-resolution ``k × k`` kernels. Demodulation divides each pixel by
its own noisy albedo, which is right (colour and albedo come from the same samples); but where
the albedo is noisy (texture finer than a pixel near a horizon, depth of field, motion blur)
multiplying the filtered irradiance back by it restores the albedo's noise. The kernels start
near a delta (centre weight 0.69), so the network can keep sharp textures sharp.

The kernels average the *linear* demodulated colour (energy is kept; the log transform is
only the network's view of it). The trunk is a lean U-Net: ``channels = [24, 32, 48, 64]``
are the widths at full, 1/2, 1/4 and 1/8 resolution (two 3×3 convolutions per level down,
two per level up except one at full resolution); a KPCN-sized 9-layer 100-channel network
would cost ~110 s per megapixel on two CPU cores.

Inference (:meth:`KpcnModel.denoise_tensors`; :func:`mcdenoise.methods.kpcn.denoise_kpcn` from a
FeatureBuffers) runs on tiles with a halo of :attr:`KpcnModel.halo`
pixels (more than the receptive field, tile origins aligned to the U-Net's pooling grid), so
tiled and untiled results agree to float rounding; within a tile the k² kernels exist for a
strip of rows at a time. Peak memory is bounded by the tile size, not the frame size.

Model file (``torch.save`` of a dict, read with ``weights_only=True``)::

    {"card": {format, sources, stats {source: FeatureStats}, channels, kernel, scales,
              encoder, training}, "state": state_dict}
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from mcdenoise.errors import InputError
from mcdenoise.filters.albedo import demodulate
from mcdenoise.modelfile import (
    MAX_KERNEL,
    MAX_WIDTH,
    Card,
    CardModule,
    check_model_size,
)
from mcdenoise.models.encoders import (
    SOURCES,
    Normalizer,
    channel_names,
    encoder,
    shared_layout,
    source_channels,
)
from mcdenoise.models.features import FeatureStats
from mcdenoise.models.multiscale import apply_head, composite, downsample
from mcdenoise.models.precision import trunk_autocast

#: Version of the model file layout.
FORMAT = "mcdenoise.kpcn/1"
ENCODERS = ("source-aware", "shared")
#: Initial centre logit of the albedo kernels (the others start at 0): e^4 / (e^4 + k² - 1) of
#: the weight on the pixel itself, 0.69 for k = 5 (not a saturated softmax, whose gradient
#: would be too small to move away from the delta).
ALBEDO_CENTRE_LOGIT = 4.0
#: Default inference tile edge (pixels, a multiple of 64) and kernel strip height (rows).
TILE = 1024
STRIP = 128


@dataclass
class KpcnCard(Card):
    """Everything needed to rebuild and check a model (JSON-able).

    Attributes:
        sources: input sources the model has encoders for (keys of :data:`SOURCES`).
        stats: per source, normalisation statistics of its channels (names = the channel set).
        channels: U-Net widths per level (full resolution first).
        kernel: kernel edge ``k`` (odd).
        scales: number of kernel scales (full, 1/2, 1/4 ...).
        encoder: ``source-aware`` (one encoder per source) or ``shared`` (one input layer).
        albedo_kernels: filter the remodulation albedo with predicted kernels (see the module
            docstring; files without the field: ``False``).
        training: free-form description of the training run.
    """

    sources: list[str]
    stats: dict[str, FeatureStats]
    channels: list[int] = field(default_factory=lambda: [24, 32, 48, 64])
    kernel: int = 21
    scales: int = 3
    encoder: str = "source-aware"
    training: dict[str, Any] = field(default_factory=dict)
    albedo_kernels: bool = False
    format: str = FORMAT

    def check(self, what: str = "model") -> None:
        unknown = [s for s in self.sources if s not in SOURCES]
        problems = []
        if unknown or not self.sources:
            problems.append(f"unknown or no sources {self.sources} (known: {', '.join(SOURCES)})")
        for s in self.sources:
            if s in self.stats and self.stats[s].names != channel_names(s):
                diff = sorted(set(self.stats[s].names) ^ set(channel_names(s)))
                problems.append(
                    f"the '{s}' source was trained with other input channels (differing: "
                    f"{', '.join(diff) or 'order'})"
                )
            elif s not in self.stats:
                problems.append(f"no normalisation statistics for source '{s}'")
        if self.kernel < 1 or self.kernel % 2 == 0:
            problems.append(f"kernel must be odd, got {self.kernel}")
        if len(self.channels) < 2 or not 1 <= self.scales <= len(self.channels):
            problems.append(f"bad channels {self.channels} / scales {self.scales}")
        if self.encoder not in ENCODERS:
            problems.append(f"encoder must be one of {ENCODERS}, got {self.encoder!r}")
        if problems:
            raise InputError(f"{what}: {'; '.join(problems)}")

    def plain(self) -> dict[str, Any]:
        d = super().plain()
        d["stats"] = {k: v.to_dict() for k, v in self.stats.items()}
        return d

    @staticmethod
    def from_dict(d: Mapping[str, Any], what: str = "model file") -> KpcnCard:
        """The card of a model file: every field's type and range checked, and the size of
        the model it describes bounded (:mod:`mcdenoise.modelfile`), before anything is built.
        """
        f = KpcnCard.fields(d, what)
        channels = f.integers("channels", 1, MAX_WIDTH, min_len=2, max_len=8)
        stats = f.sub("stats")
        card = KpcnCard(
            sources=f.texts("sources", tuple(SOURCES), min_len=1, unique=True),
            stats={
                k: FeatureStats.from_dict(stats.get(k), what, f"stats.{k}")
                for k in f.mapping("stats")
            },
            channels=channels,
            kernel=f.integer("kernel", 1, MAX_KERNEL, odd=True),
            scales=f.integer("scales", 1, len(channels)),
            encoder=f.text("encoder", ENCODERS),
            training=f.mapping("training", default={}),
            albedo_kernels=f.flag("albedo_kernels", default=False),
        )
        card.check(what)
        check_model_size(lambda: KpcnModel(card), what)
        return card


def _block(n_in: int, n_out: int, convs: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(convs):
        layers += [nn.Conv2d(n_in if i == 0 else n_out, n_out, 3, padding=1), nn.ReLU(inplace=True)]
    return nn.Sequential(*layers)


def albedo_head(n_in: int, kernel: int) -> nn.Conv2d:
    """The 1×1 head of the albedo kernels, starting near a delta (:data:`ALBEDO_CENTRE_LOGIT`)."""
    conv = nn.Conv2d(n_in, kernel * kernel, 1)
    nn.init.zeros_(conv.weight)
    with torch.no_grad():
        conv.bias.zero_()
        conv.bias[kernel * kernel // 2] = ALBEDO_CENTRE_LOGIT
    return conv


class KpcnModel(CardModule):
    """The network and its pre/post-processing; see the module docstring.

    ``forward(batch)`` is the training path on crops: ``batch`` holds prepared tensors
    ``(B, C, h, w)`` (``h``, ``w`` multiples of :attr:`multiple`) and ``source`` ``(B,)`` (an
    index into ``card.sources`` per crop); it returns the denoised colour ``(B, 3, h, w)``.
    """

    card_class = KpcnCard

    def __init__(self, card: KpcnCard) -> None:
        super().__init__()
        card.check()
        self.card = card
        ch = card.channels
        self.norms = nn.ModuleDict({s: Normalizer(card.stats[s]) for s in card.sources})
        if card.encoder == "source-aware":
            self.encoders = nn.ModuleDict(
                {s: encoder(len(channel_names(s)), ch[0]) for s in card.sources}
            )
        else:
            self.encoders = nn.ModuleDict({"shared": encoder(len(channel_names("full")), ch[0])})
        self.down = nn.ModuleList(_block(ch[i - 1], ch[i], 2) for i in range(1, len(ch)))
        self.up = nn.ModuleList(
            _block(ch[i + 1] + ch[i], ch[i], 1 if i == 0 else 2) for i in range(len(ch) - 1)
        )
        k2 = card.kernel * card.kernel
        self.heads = nn.ModuleList(nn.Conv2d(ch[s], k2, 1) for s in range(card.scales))
        self.alphas = nn.ModuleList(nn.Conv2d(ch[s], 1, 1) for s in range(card.scales - 1))
        if card.albedo_kernels:
            self.albedo_head = albedo_head(ch[0], card.kernel)

    # --- geometry ----------------------------------------------------------------------
    @property
    def multiple(self) -> int:
        """Input sizes must be multiples of this (the U-Net pools ``len(channels) - 1`` times)."""
        return 2 ** (len(self.card.channels) - 1)

    @property
    def halo(self) -> int:
        """Tile overlap (pixels, a multiple of :attr:`multiple`) covering the receptive field."""
        levels = len(self.card.channels)
        conv = (
            2 + sum(2 * 2**i for i in range(1, levels)) + sum(2 * 2**i for i in range(levels - 1))
        )
        kern = (self.card.kernel // 2 + 1) * 2 ** (self.card.scales - 1) + 2**self.card.scales
        need = conv + kern + 2**levels
        m = self.multiple
        return -(-need // m) * m

    # --- network -------------------------------------------------------------------------
    def encode(self, raw: Tensor, source: str) -> Tensor:
        """Latent ``(B, channels[0], H, W)`` of raw source channels."""
        # channels-last convolutions: 1.4-1.8x faster on CPU (oneDNN), same results to rounding
        z = self.norms[source](raw).contiguous(memory_format=torch.channels_last)
        if self.card.encoder == "shared":
            return self.encoders["shared"](shared_layout(z, source))
        return self.encoders[source](z)

    def trunk(self, latent: Tensor) -> list[Tensor]:
        """U-Net decoder features, full resolution first."""
        skips = [latent]
        x = latent
        for block in self.down:
            x = block(F.max_pool2d(x, 2))
            skips.append(x)
        outs = [x]
        for i in range(len(self.up) - 1, -1, -1):
            x = F.interpolate(x, scale_factor=2.0, mode="nearest")
            x = self.up[i](torch.cat([x, skips[i]], dim=1))
            outs.append(x)
        return outs[::-1]

    def features(
        self, t: Mapping[str, Tensor], source: str, precision: str = "fp32"
    ) -> list[Tensor]:
        """Decoder features of prepared tensors, full resolution first (:meth:`trunk`).

        ``precision="bf16"`` runs the encoder and trunk under bfloat16 autocast and returns the
        features as float32 (:mod:`~mcdenoise.models.precision`)."""
        raw = source_channels(source, t)
        if precision == "fp32":
            return self.trunk(self.encode(raw, source))
        with trunk_autocast(precision, raw.device):
            feats = self.trunk(self.encode(raw, source))
        return [f.float() for f in feats]

    def reconstruct(self, irr: Tensor, feats: Sequence[Tensor], strip: int | None = None) -> Tensor:
        """Kernels at every scale applied to ``irr`` and composited (float32)."""
        images = [irr.float() if irr.dtype != torch.float64 else irr]
        for _ in range(1, self.card.scales):
            images.append(downsample(images[-1]))
        k = self.card.kernel
        res = apply_head(images[-1], feats[self.card.scales - 1], self.heads[-1], k, strip=strip)
        for s in range(self.card.scales - 2, -1, -1):
            fine = apply_head(images[s], feats[s], self.heads[s], k, strip=strip)
            alpha = torch.sigmoid(self.alphas[s](feats[s]).float())
            res = composite(fine, res, alpha)
        return res

    def run(
        self,
        t: Mapping[str, Tensor],
        source: str,
        strip: int | None = None,
        precision: str = "fp32",
    ) -> Tensor:
        """Denoise prepared tensors ``(B, C, H, W)`` (sizes multiples of :attr:`multiple`);
        ``precision`` is the trunk's (:meth:`features`)."""
        irr, factor = demodulate(t["color"], t.get("albedo"))
        feats = self.features(t, source, precision)
        if self.card.albedo_kernels and "albedo" in t:
            factor = apply_head(factor, feats[0], self.albedo_head, self.card.kernel, strip=strip)
        out = self.reconstruct(irr, feats, strip) * factor.to(irr.dtype)
        return out.clamp_min(0.0)

    def forward(self, batch: Mapping[str, Tensor]) -> Tensor:
        src = batch["source"]
        out: Tensor | None = None
        for i, name in enumerate(self.card.sources):
            idx = (src == i).nonzero().flatten()
            if idx.numel() == 0:
                continue
            sub = {k: v[idx] for k, v in batch.items() if k in SOURCES[name] or k.endswith("_var")}
            res = self.run(sub, name)
            if out is None:
                out = res.new_zeros((src.shape[0], *res.shape[1:]))
            out[idx] = res
        if out is None:
            raise InputError("empty batch")
        return out

    @torch.no_grad()
    def compositor_weights(self, t: Mapping[str, Tensor], source: str) -> list[Tensor]:
        """Per-pixel compositor weights α ``(B, 1, H/2^s, W/2^s)``, one per coarser scale
        ``s = 1 .. scales-1`` (how much of scale ``s`` enters scale ``s - 1``), of prepared
        tensors (sizes multiples of :attr:`multiple`). A scale whose α is near 0 everywhere
        is unused: its gate closed during training."""
        feats = self.features(t, source)
        return [
            torch.sigmoid(self.alphas[s](feats[s]).float()) for s in range(self.card.scales - 1)
        ]

    # --- inference ---------------------------------------------------------------------
    @torch.no_grad()
    def denoise_tensors(
        self,
        t: Mapping[str, Tensor],
        source: str,
        *,
        tile: int = TILE,
        strip: int = STRIP,
        precision: str = "fp32",
    ) -> Tensor:
        """Tiled :meth:`run` on prepared tensors ``(1, C, H, W)`` of any size; ``precision``
        ``fp32`` or ``bf16`` (the trunk's, :mod:`~mcdenoise.models.precision`)."""
        h, w = t["color"].shape[-2:]
        m, halo = self.multiple, self.halo
        tile = max(m, -(-tile // m) * m)
        out = torch.empty_like(t["color"], dtype=torch.float32)
        for y0 in range(0, h, tile):
            for x0 in range(0, w, tile):
                y1, x1 = min(h, y0 + tile), min(w, x0 + tile)
                a, b = max(0, y0 - halo), min(h, y1 + halo)
                c, d = max(0, x0 - halo), min(w, x1 + halo)
                sub = {k: v[..., a:b, c:d] for k, v in t.items()}
                res = self._run_padded(sub, source, strip, precision)
                out[..., y0:y1, x0:x1] = res[..., y0 - a : y1 - a, x0 - c : x1 - c]
        return torch.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0).clamp_min(0.0)

    def _run_padded(
        self, t: Mapping[str, Tensor], source: str, strip: int, precision: str = "fp32"
    ) -> Tensor:
        h, w = t["color"].shape[-2:]
        m = self.multiple
        ph, pw = -h % m, -w % m
        if ph or pw:
            t = {k: F.pad(v, (0, pw, 0, ph), mode="replicate") for k, v in t.items()}
        return self.run(t, source, strip, precision)[..., :h, :w]


def new_model(
    sources: Sequence[str],
    stats: Mapping[str, FeatureStats],
    *,
    channels: Sequence[int] = (24, 32, 48, 64),
    kernel: int = 21,
    scales: int = 3,
    encoder: str = "source-aware",
    albedo_kernels: bool = False,
) -> KpcnModel:
    """An untrained model."""
    card = KpcnCard(
        [s for s in SOURCES if s in sources],
        {s: stats[s] for s in sources},
        list(channels),
        kernel,
        scales,
        encoder,
        albedo_kernels=albedo_kernels,
    )
    return KpcnModel(card)


__all__ = ["FORMAT", "STRIP", "TILE", "KpcnCard", "KpcnModel", "new_model"]
