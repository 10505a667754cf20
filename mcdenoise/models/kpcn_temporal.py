"""Temporal kernel-predicting CNN (Vogels et al. 2018, "Denoising with Kernel Prediction and
Asymmetric Loss Functions", section 5: the temporal extension of their KPCN).

A window of frames around frame ``t`` (``offline``: past and future, e.g. ``t-2 … t+2``;
``causal``: past only, ``t-N+1 … t``) is denoised into frame ``t``::

    frames t+o, each warped to frame t along the motion vectors (bilinear, invalid pixels
      masked; mcdenoise.filters.warp, done by the caller: mcdenoise.methods.kpcn_temporal)
      --single-frame kpcn source encoder + U-Net trunk (shared weights, one batched call)-->
      per frame i and scale s: features f_i^s
      --temporal module per scale (below)--> per frame i a k×k kernel's logits
      --ONE softmax over all k² taps of all N frames (taps on invalid pixels: weight 0)-->
      kernels applied to the warped, demodulated frames and summed
      --Vogels' scale compositor, coarse to fine--> × (albedo_t + 0.01) --> frame t

The logits of frame ``i`` are the single-frame model's own head on that frame's features plus
a correction from the temporal module: ``L_i = head_s(f_i) + Δ_i``. The temporal module
(:class:`~mcdenoise.models.temporal_modules.TemporalMixer`, one per scale) sees per frame ``[f_i, f_i − f_t, mask_i, is_centre]``,
two 3×3 convolutions give ``h_i``, a mask-weighted mean over the window gives a context ``h̄``,
and a 1×1 convolution of ``[h_i, h̄]`` gives ``Δ_i`` (and, from ``h̄``, a correction of the
compositor's blend logit); the centre frame's taps get a learned bias (start
:data:`~mcdenoise.models.temporal_modules.CENTRE_BIAS`). The last layers start at zero, so before training the model is a
weighted mean of the single-frame kpcn's kernels of the valid frames (each frame's logits are
first normalised on their own, :func:`~mcdenoise.models.temporal_modules.frame_log_softmax`), most of the weight on frame ``t``:
a motion-compensated, mask-aware blend that the temporal module then learns to reweight
(Vogels: the kernels of all frames are normalised jointly). Training starts
from the shipped single-frame model with the trunk frozen (:mod:`mcdenoise.train.kpcn_temporal`).

Masks: the centre frame is valid everywhere. At the coarser scales a pixel is valid only when
all four pixels below it are (min-pooling), so a kernel never reads a value that averages an
invalid pixel in. A tap is read only where its frame's mask is 1 at the tapped pixel (and the
pixel lies in the image): the logits of all other taps are set to −∞ before the softmax, and
the warped frames hold 0 there (never NaN), so no invalid value can reach the output or its
gradient.

A window of one frame is exactly the single-frame model (:meth:`TemporalKpcn.run` runs
:meth:`KpcnModel.run`: with one frame the joint softmax is kpcn's in-image softmax and the
temporal module has nothing to combine).

Model file (``torch.save`` of a dict): ``{"card": {format, base (the kpcn card), window,
mode, hidden, training}, "state": state_dict}``; the base's weights live under ``base.``.
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
    MAX_WIDTH,
    Card,
    CardModule,
    check_model_size,
)
from mcdenoise.models.kpcn import KpcnCard, KpcnModel
from mcdenoise.models.multiscale import apply_head, composite, downsample, head_logits
from mcdenoise.models.temporal_modules import (
    RecurrentBlend,
    TemporalMixer,
    apply_joint,
    box3,
    frame_log_softmax,
    joint_kernel_softmax,
    min_pool,
    noise_inputs,
    tap_valid,
)

#: Version of the model file layout.
FORMAT = "mcdenoise.kpcn-temporal/1"
#: ``offline``: past and future frames (odd window centred on t); ``causal``: past frames only.
MODES = ("offline", "causal")
#: Default inference tile edge (pixels).
TILE = 512
#: Most frames of a window a model file may ask for (each frame's trunk features are kept).
MAX_WINDOW = 15
#: Extra per-frame input channels of the temporal module by card ``inputs`` version.
MIXER_INPUTS = {1: 0, 2: 2}


def window_offsets(window: int, mode: str) -> list[int]:
    """Frame offsets of a window, oldest first.

    >>> window_offsets(5, "offline"), window_offsets(3, "causal")
    ([-2, -1, 0, 1, 2], [-2, -1, 0])
    """
    if mode not in MODES:
        raise InputError(f"temporal mode must be one of {', '.join(MODES)}, got {mode!r}")
    if window < 1 or (mode == "offline" and window % 2 == 0):
        raise InputError(f"window must be >= 1 (odd for the offline mode), got {window} ({mode})")
    if mode == "causal":
        return list(range(-(window - 1), 1))
    r = window // 2
    return list(range(-r, r + 1))


@dataclass
class TemporalCard(Card):
    """Everything needed to rebuild the temporal model (JSON-able).

    Attributes:
        base: the single-frame kpcn's card (:meth:`KpcnCard.to_dict`).
        window: frames per window (3, 5 …).
        mode: ``offline`` or ``causal`` (:data:`MODES`).
        hidden: width of the temporal module per kernel scale.
        inputs: what the temporal module sees per frame (:data:`MIXER_INPUTS`): 1, the
            trunk's features and the mask (the first shipped model); 2, also the
            noise-normalised difference to frame t and the log ratio of the frames' variances
            (:func:`noise_inputs`), so it can reject disoccluded pixels and fireflies.
        recurrent: the previous *output*, warped to frame t, is one more kernel source
            (:class:`RecurrentBlend`; run frame by frame, :mod:`mcdenoise.methods.kpcn_temporal`).
        training: free-form description of the training run.
    """

    base: dict[str, Any]
    window: int = 5
    mode: str = "offline"
    hidden: list[int] = field(default_factory=lambda: [16, 24, 32])
    inputs: int = 1
    recurrent: bool = False
    training: dict[str, Any] = field(default_factory=dict)
    format: str = FORMAT

    def check(self, what: str = "model") -> KpcnCard:
        base = KpcnCard.from_dict(self.base, what)
        window_offsets(self.window, self.mode)
        if len(self.hidden) != base.scales or min(self.hidden) < 1:
            raise InputError(
                f"{what}: hidden must give one width per kernel scale ({base.scales}), "
                f"got {self.hidden}"
            )
        return base

    @property
    def offsets(self) -> list[int]:
        return window_offsets(self.window, self.mode)

    @staticmethod
    def from_dict(d: Mapping[str, Any], what: str = "model file") -> TemporalCard:
        """The card of a model file: every field's type and range checked (the ``base`` card
        by :meth:`KpcnCard.from_dict`), and the size of the model it describes bounded
        (:mod:`mcdenoise.modelfile`), before anything is built."""
        f = TemporalCard.fields(d, what)
        card = TemporalCard(
            base=f.mapping("base"),
            window=f.integer("window", 1, MAX_WINDOW),
            mode=f.text("mode", MODES),
            hidden=f.integers("hidden", 1, MAX_WIDTH),
            inputs=f.integer("inputs", 1, max(MIXER_INPUTS), default=1),
            recurrent=f.flag("recurrent", default=False),
            training=f.mapping("training", default={}),
        )
        card.check(what)
        check_model_size(lambda: TemporalKpcn(card), what)
        return card


class TemporalKpcn(CardModule):
    """The temporal model; ``base`` is a :class:`KpcnModel` (the shared trunk and heads)."""

    card_class = TemporalCard

    def __init__(self, card: TemporalCard) -> None:
        super().__init__()
        base_card = card.check()
        self.card = card
        self.base = KpcnModel(base_card)
        ch, k = base_card.channels, base_card.kernel
        extra = MIXER_INPUTS[card.inputs]
        self.mixers = nn.ModuleList(
            TemporalMixer(ch[s], card.hidden[s], k, extra) for s in range(base_card.scales)
        )
        self.recurrence = RecurrentBlend(ch[0]) if card.recurrent else None

    @property
    def centre(self) -> int:
        """Index of frame ``t`` in a full window."""
        return self.card.offsets.index(0)

    @property
    def multiple(self) -> int:
        return self.base.multiple

    @property
    def halo(self) -> int:
        """The trunk's halo plus the temporal module's two 3×3 convolutions per scale."""
        m = self.multiple
        extra = 2 * 2 ** (self.base.card.scales - 1) + m
        return -(-(self.base.halo + extra) // m) * m

    def trunk_parameters(self) -> list[nn.Parameter]:
        return list(self.base.parameters())

    def temporal_parameters(self) -> list[nn.Parameter]:
        rec = list(self.recurrence.parameters()) if self.recurrence is not None else []
        return list(self.mixers.parameters()) + rec

    # --- network -------------------------------------------------------------------------
    def run(
        self,
        frames: Sequence[Mapping[str, Tensor]],
        masks: Sequence[Tensor],
        centre: int,
        source: str,
        *,
        trunk_grad: bool = True,
        features: Sequence[Sequence[Tensor]] | None = None,
        previous: Tensor | None = None,
        previous_mask: Tensor | None = None,
    ) -> Tensor:
        """Denoise frame ``centre`` of a window of prepared tensors ``(B, C, H, W)``.

        Args:
            frames: per frame of the window (any length >= 1), its prepared tensors warped
                to the centre frame's grid (0 where invalid); sizes multiples of
                :attr:`multiple`.
            masks: per frame ``(B, 1, H, W)`` validity of the warp (1 valid); the centre's is
                ignored (valid everywhere).
            centre: index of frame ``t`` in ``frames``.
            source: the input source (a key of the base card's sources).
            trunk_grad: False runs the shared trunk without autograd (the frozen stage of
                training).
            features: the trunk's features per frame and scale (``[frame][scale]``, full
                resolution first), when the caller has them (a frozen trunk's, computed once
                per training window); ``None``: computed here.
            previous, previous_mask: a recurrent model's previous output ``(B, 3, H, W)``
                (linear, remodulated, the same exposure scale) warped to frame t, and where
                that warp is valid ``(B, 1, H, W)``; ``None`` (the first frame, a cut): no
                recurrence.
        """
        recur = self.recurrence is not None and previous is not None
        if len(frames) == 1 and not recur:
            return self.base.run(frames[0], source)
        base = self.base
        n, k, scales = len(frames), base.card.kernel, base.card.scales
        c = frames[centre]
        _, factor = demodulate(c["color"], c.get("albedo"))
        # Nothing of a neighbour frame under its zero mask is read, not even by the trunk's
        # convolutions (the warp leaves 0 there; a caller's NaN would otherwise spread).
        frames = [
            f
            if i == centre
            else {
                key: torch.where(masks[i] > 0.5, v, torch.zeros((), dtype=v.dtype))
                for key, v in f.items()
            }
            for i, f in enumerate(frames)
        ]
        keys = [key for key in c if all(key in f for f in frames)]
        stacked = {key: torch.cat([f[key] for f in frames], dim=0) for key in keys}
        b = c["color"].shape[0]
        if features is None:
            with torch.set_grad_enabled(trunk_grad and torch.is_grad_enabled()):
                feats_all = base.features(stacked, source)
            feats = [list(f.split(b, dim=0)) for f in feats_all[:scales]]  # [scale][frame]
        else:
            feats = [[features[i][s] for i in range(n)] for s in range(scales)]
        irr, fac = demodulate(stacked["color"], stacked.get("albedo"))
        irr = irr.float() if irr.dtype != torch.float64 else irr
        images = [list(irr.split(b, dim=0))]
        ones = torch.ones_like(masks[centre][:, :1], dtype=irr.dtype)
        mk = [[ones if i == centre else (masks[i] > 0.5).to(irr.dtype) for i in range(n)]]
        noisy = self.card.inputs >= 2
        if noisy:
            if "color_var" in stacked:
                var = stacked["color_var"].to(irr.dtype) / fac.to(irr.dtype).square()
            else:  # no variance buffer: the local spatial variance stands in
                var = (box3(irr.square()) - box3(irr).square()).clamp_min(0.0)
            variances = [list(var.split(b, dim=0))]
        for _ in range(1, scales):
            images.append([downsample(x) for x in images[-1]])
            mk.append([min_pool(m) for m in mk[-1]])
            if noisy:
                variances.append([downsample(v) / 4.0 for v in variances[-1]])
        res: Tensor | None = None
        for s in range(scales - 1, -1, -1):
            extra = noise_inputs(images[s], variances[s], mk[s], centre) if noisy else None
            deltas, dalpha = self.mixers[s](feats[s], mk[s], centre, extra)
            valid = [tap_valid(m, k) for m in mk[s]]
            in_image = tap_valid(mk[s][centre], k)
            logits = [
                frame_log_softmax(head_logits(base.heads[s], f), in_image).to(d.dtype) + d
                for f, d in zip(feats[s], deltas)
            ]
            fine = apply_joint(images[s], joint_kernel_softmax(logits, valid))
            if res is None:
                res = fine
            else:
                logit = base.alphas[s](feats[s][centre]).to(dalpha.dtype) + dalpha
                res = composite(fine, res, torch.sigmoid(logit))
        assert res is not None
        if base.card.albedo_kernels and "albedo" in c:
            factor = apply_head(factor, feats[0][centre], base.albedo_head, k)
        factor = factor.to(res.dtype)
        if recur:
            assert self.recurrence is not None and previous is not None
            pmask = torch.ones_like(ones) if previous_mask is None else previous_mask
            prev = torch.nan_to_num(previous.to(res.dtype), nan=0.0, posinf=0.0, neginf=0.0)
            prev = prev / factor.clamp_min(1e-3)
            noisy = c["color"].to(res.dtype) / factor.clamp_min(1e-3)
            res = self.recurrence(feats[0][centre], res, prev, pmask.to(res.dtype), noisy)
        return (res * factor).clamp_min(0.0)

    def forward(self, batch: Mapping[str, Tensor]) -> Tensor:
        """Training path: ``batch`` holds ``{name}@{i}`` and ``mask@{i}`` for every frame ``i``
        of the window (:attr:`card.offsets` order), optionally the trunk's features
        ``feat{s}@{i}`` per scale ``s`` and (recurrent models) ``previous`` /
        ``previous_mask``, and one ``source`` index ``source`` for the whole batch (``(B,)``,
        all equal)."""
        n = len(self.card.offsets)
        frames = [
            {
                k.split("@")[0]: v
                for k, v in batch.items()
                if k.endswith(f"@{i}") and not k.startswith(("mask", "feat"))
            }
            for i in range(n)
        ]
        masks = [batch[f"mask@{i}"] for i in range(n)]
        source = self.base.card.sources[int(batch["source"][0])]
        features = None
        if "feat0@0" in batch:
            scales = self.base.card.scales
            features = [[batch[f"feat{s}@{i}"] for s in range(scales)] for i in range(n)]
        return self.run(
            frames,
            masks,
            self.centre,
            source,
            trunk_grad=self.training_trunk,
            features=features,
            previous=batch.get("previous"),
            previous_mask=batch.get("previous_mask"),
        )

    #: Whether :meth:`forward` lets gradients reach the trunk (set by the trainer).
    training_trunk: bool = True

    # --- inference ---------------------------------------------------------------------
    @torch.no_grad()
    def denoise_window(
        self,
        frames: Sequence[Mapping[str, Tensor]],
        masks: Sequence[Tensor],
        centre: int,
        source: str,
        *,
        tile: int = TILE,
        previous: Tensor | None = None,
        previous_mask: Tensor | None = None,
    ) -> Tensor:
        """Tiled :meth:`run` on a window of prepared tensors ``(1, C, H, W)`` of any size; a
        window of one frame without a previous output is :meth:`KpcnModel.denoise_tensors`
        (bit for bit)."""
        recur = self.recurrence is not None and previous is not None
        if len(frames) == 1 and not recur:
            return self.base.denoise_tensors(frames[0], source, tile=max(tile, 64))
        h, w = frames[centre]["color"].shape[-2:]
        m, halo = self.multiple, self.halo
        tile = max(m, -(-tile // m) * m)
        out = torch.empty_like(frames[centre]["color"], dtype=torch.float32)
        for y0 in range(0, h, tile):
            for x0 in range(0, w, tile):
                y1, x1 = min(h, y0 + tile), min(w, x0 + tile)
                a, b = max(0, y0 - halo), min(h, y1 + halo)
                c, d = max(0, x0 - halo), min(w, x1 + halo)
                fr = [{k: v[..., a:b, c:d] for k, v in f.items()} for f in frames]
                mk = [mm[..., a:b, c:d] for mm in masks]
                pv = [
                    x[..., a:b, c:d] for x in (previous, previous_mask) if recur and x is not None
                ]
                ph, pw = -(b - a) % m, -(d - c) % m
                if ph or pw:
                    fr = [
                        {k: F.pad(v, (0, pw, 0, ph), mode="replicate") for k, v in f.items()}
                        for f in fr
                    ]
                    mk = [F.pad(mm, (0, pw, 0, ph), mode="replicate") for mm in mk]
                    pv = [F.pad(x, (0, pw, 0, ph), mode="replicate") for x in pv]
                res = self.run(
                    fr,
                    mk,
                    centre,
                    source,
                    previous=pv[0] if pv else None,
                    previous_mask=pv[1] if len(pv) > 1 else None,
                )[..., : b - a, : d - c]
                out[..., y0:y1, x0:x1] = res[..., y0 - a : y1 - a, x0 - c : x1 - c]
        return torch.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0).clamp_min(0.0)


def from_single_frame(
    base: KpcnModel,
    *,
    window: int = 5,
    mode: str = "offline",
    hidden: Sequence[int] | None = None,
    inputs: int = 1,
    recurrent: bool = False,
) -> TemporalKpcn:
    """A temporal model around the weights of a trained single-frame ``base`` (the temporal
    module at its zero start)."""
    hid = list(hidden) if hidden is not None else [16, 24, 32][: base.card.scales]
    while len(hid) < base.card.scales:
        hid.append(hid[-1])
    card = TemporalCard(
        base=base.card.to_dict(),
        window=window,
        mode=mode,
        hidden=hid,
        inputs=inputs,
        recurrent=recurrent,
    )
    model = TemporalKpcn(card)
    model.base.load_state_dict(base.state_dict())
    return model


__all__ = [
    "FORMAT",
    "MAX_WINDOW",
    "MIXER_INPUTS",
    "MODES",
    "TILE",
    "TemporalCard",
    "TemporalKpcn",
    "from_single_frame",
    "window_offsets",
]
