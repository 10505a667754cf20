"""Training ``auxnet``, the learned prefilter of noisy albedo and normal buffers.

``mcdenoise train --model auxnet --data DIR`` on renders of ``mcdenoise render`` (or
``benchmarks/render_random.py``): every noisy level's albedo and normal are the inputs, its
reference's albedo and normal the targets (auxiliary buffers converge within a few dozen
samples, so any reference of the colour is more than clean enough for them). Images without
an albedo (AO scenes) are reported and skipped.

The loss is the squared error of ``log1p(albedo)`` (close to a relative error for albedos
up to about 1, bounded for the glossy lobes' albedos far above it and for a black reference)
plus the normal's squared error, over the crop's loss mask (the config's ``loss`` field is not
used; the card records ``"loss_used": "mse-log-albedo+mse-normal"``). Tried and left
(``docs/results/aux-prefilter.md``): an L1 loss (where a pixel's few samples saw a surface
and the background, the reference is their coverage-weighted mean, which L1, seeking the
median, does not; the net stayed the identity for 500 steps), and the albedo's relative
squared error ``(p − r)² / (r² + ε)`` (ε = 0.01: every kernel collapsed onto one tap within
250 steps; ε = 0.1: the net stayed at its starting blur for 750 steps).

Augmentation, per crop: flips and 90° rotations, one RGB permutation of colour and albedo, the colour's exposure ×2^U(-2, 2) (the net sees the colour
only as a guide), and half of the crops of images with feature variances shown without
them (as a plain renderer file would come), so one net serves both kinds of file. Crops are
drawn half in proportion to the noisy albedo's error. Validation (split by image): the loss
over whole images, and the albedo's relative MSE before and after (``val_albedo_relmse``,
``val_albedo_relmse_noisy``). ``-s channels=`` sets the U-Net's widths, ``-s kernel=`` the
kernel edge (default 7). Recipe: ``data/recipes/auxnet.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.losses import relmse
from mcdenoise.models.auxnet import AuxCard, AuxNet, net_inputs
from mcdenoise.prep.inputs import exposure_scale, prepare_inputs
from mcdenoise.prep.learned_prefilter import noise_channels
from mcdenoise.train.config import TrainConfig
from mcdenoise.train.loop import CardTask, TrainResult, run_training
from mcdenoise.train.pack import load_training_data
from mcdenoise.train.patches import (
    REFERENCE,
    Item,
    LoadReport,
    PatchSampler,
    augment,
    describe_training,
)

#: Kernel edge when the config says 0.
DEFAULT_KERNEL = 7
#: Share of crops (of images with feature variances) shown without them.
DROP_VARIANCE = 0.5
#: Exposure augmentation of the guide colour, in stops either way.
EXPOSURE_STOPS = 2.0
#: Config keys the prepared data depends on (a pack records them).
PACK_KEYS = ("model", "levels", "val_fraction", "seed", "max_images")


def _zeros(like: Tensor) -> Tensor:
    return like.new_zeros(1, *like.shape[1:])


def prepare(buffers: FeatureBuffers, reference: FeatureBuffers) -> dict[str, Tensor]:
    """Noisy albedo, normal, their variances (zeros and ``has_var`` 0 when absent), the
    colour at the standard exposure, and the reference's albedo (``reference``) and normal.

    Raises:
        MissingFeatureError: no albedo or normal in the level or its reference.
    """
    buffers.require(["albedo", "normal"], needed_by="auxnet training")
    reference.require(["albedo", "normal"], needed_by="auxnet training (the reference)")
    inp = prepare_inputs(buffers, features=("albedo", "normal"), prefilter=False)
    ref = prepare_inputs(reference, features=("albedo", "normal"), prefilter=False)
    a, n = inp.features["albedo"][0], inp.features["normal"][0]
    av, nv = inp.feature_vars.get("albedo"), inp.feature_vars.get("normal")
    has = av is not None and nv is not None
    cn, an = noise_channels(inp.features["albedo"], inp.color, inp.color_var)
    return {
        "albedo": a,
        "normal": n,
        "color_noise": cn[0],
        "albedo_noise": an[0],
        "albedo_var": av[0].mean(0, keepdim=True) if has else _zeros(a),
        "normal_var": nv[0].mean(0, keepdim=True) if has else _zeros(a),
        "has_var": torch.full_like(a[:1], 1.0 if has else 0.0),
        "color": inp.color[0] * exposure_scale(inp.color),
        REFERENCE: ref.features["albedo"][0],
        "ref_normal": ref.features["normal"][0],
    }


prepare.reference_buffers = True  # type: ignore[attr-defined]


def batch_inputs(batch: dict[str, Tensor]) -> Tensor:
    """:func:`~mcdenoise.models.auxnet.net_inputs` of a batch, the variance channels zeroed
    for the crops whose ``has_var`` is 0."""
    x = net_inputs(
        batch["albedo"],
        batch["normal"],
        batch["color"],
        batch["color_noise"],
        batch["albedo_noise"],
        batch["albedo_var"],
        batch["normal_var"],
    )
    keep = batch["has_var"][:, :1, :1, :1]
    return torch.cat([x[:, :12], x[:, 12:] * keep], dim=1)


def aux_loss(
    model: AuxNet, batch: dict[str, Tensor], mask: Tensor | None = None
) -> tuple[Tensor, dict[str, Tensor]]:
    """The training loss of a batch and the filtered buffers."""
    weights = model(batch_inputs(batch))
    out = model.filter(weights, {"albedo": batch["albedo"], "normal": batch["normal"]})
    log_ref = torch.log1p(batch[REFERENCE].clamp_min(0))
    err_a = (torch.log1p(out["albedo"].clamp_min(0)) - log_ref).square()
    err_n = (out["normal"] - batch["ref_normal"]).square()
    err = err_a.mean(1, keepdim=True) + err_n.mean(1, keepdim=True)
    if mask is None:
        return err.mean(), out
    return (err * mask).sum() / mask.sum().clamp_min(1.0), out


class AuxTask(CardTask):
    """The :class:`~mcdenoise.train.loop.Task` of auxnet."""

    def __init__(self, model: AuxNet, val_items: Sequence[Item], description: dict[str, Any]):
        super().__init__(model, description)
        self.model: AuxNet = model
        self.val_items = list(val_items)

    def loss(self, batch: dict[str, Tensor]) -> Tensor:
        loss, _ = aux_loss(self.model, batch, batch["mask"])
        return loss

    def validate(self) -> dict[str, float]:
        if not self.val_items:
            return {}
        m = self.model.multiple
        losses, rel, rel_noisy = [], [], []
        for it in self.val_items:
            t = {k: v[None].to(self.device) for k, v in it.tensors.items()}
            h, w = t["albedo"].shape[-2:]
            ph, pw = (-h) % m, (-w) % m
            if ph or pw:
                t = {k: F.pad(v, (0, pw, 0, ph), mode="replicate") for k, v in t.items()}
            loss, out = aux_loss(self.model, t)
            losses.append(float(loss))
            ref = t[REFERENCE][..., :h, :w]
            rel.append(float(relmse(out["albedo"][..., :h, :w], ref)))
            rel_noisy.append(float(relmse(t["albedo"][..., :h, :w], ref)))
        self.last_val = {
            "val_loss": sum(losses) / len(losses),
            "val_albedo_relmse": sum(rel) / len(rel),
            "val_albedo_relmse_noisy": sum(rel_noisy) / len(rel_noisy),
        }
        return self.last_val


def build(cfg: TrainConfig, *, progress: bool = False) -> tuple[AuxTask, PatchSampler, LoadReport]:
    """Load and prepare the data, make the model.

    Raises:
        InputError: no data, no usable image, a crop the net cannot take.
    """
    if not cfg.data:
        raise InputError("no training data: pass --data DIR (a folder made by mcdenoise render)")
    card = AuxCard(widths=list(cfg.channels), kernel=cfg.kernel or DEFAULT_KERNEL)
    card.check("the config")
    crop = cfg.patch + 2 * cfg.margin
    train_items, val_items, report = load_training_data(
        cfg, prepare, crop=crop, keys=PACK_KEYS, progress=progress
    )
    torch.manual_seed(cfg.seed)
    model = AuxNet(card)
    if crop % model.multiple:
        raise InputError(
            f"patch + 2 * margin = {crop} must be a multiple of {model.multiple} "
            f"(the net folds 2×2 blocks and pools {len(card.widths) - 1} times)"
        )

    def transform(batch: dict[str, Tensor], g: torch.Generator) -> dict[str, Tensor]:
        if cfg.augment:
            batch = augment(batch, g, ("color", "albedo", REFERENCE))
        n = batch["color"].shape[0]
        stops = (torch.rand(n, generator=g) * 2 - 1) * EXPOSURE_STOPS
        batch["color"] = batch["color"] * torch.exp2(stops).view(-1, 1, 1, 1)
        drop = torch.rand(n, generator=g) < DROP_VARIANCE
        batch["has_var"] = batch["has_var"] * (~drop).float().view(-1, 1, 1, 1)
        return batch

    sampler = PatchSampler(
        train_items,
        patch=cfg.patch,
        margin=cfg.margin,
        importance=cfg.importance,
        noisy_key="albedo",
        transform=transform,
    )
    description = {
        **describe_training(cfg, train_items, val_items),
        "loss_used": "mse-log-albedo+mse-normal",
    }
    return AuxTask(model, val_items, description), sampler, report


def train_auxnet(
    cfg: TrainConfig, out: str | Path, *, resume: bool = False, progress: bool = True
) -> tuple[TrainResult, LoadReport]:
    """Train an auxnet model into the run folder ``out`` (see :mod:`mcdenoise.train.loop`)."""
    return run_training(cfg, build, out, resume=resume, progress=progress)


__all__ = [
    "DEFAULT_KERNEL",
    "PACK_KEYS",
    "AuxTask",
    "aux_loss",
    "batch_inputs",
    "build",
    "prepare",
    "train_auxnet",
]
