"""Training the Kalantari 2015 models (``kalantari-xbf``, ``kalantari-nlm``) end to end.

The loss is relMSE (ε = 0.01) between the filtered, remodulated colour and the reference,
on the masked centre of each crop (:class:`~mcdenoise.train.patches.PatchSampler`); its
gradient flows through the filter (weights, per-pixel bandwidths) into the MLP. Every level
of the data set (e.g. 4, 16 and 64 spp) is trained on together: the ``spp`` and noise-level
features tell the network which it is looking at.

Validation runs the model on the *whole* validation images (never trained on: the split is
by image) and reports their mean relMSE (``val_loss``, which picks the exported model), the
geometric mean, the same for the fixed-parameter filter (the untrained model) and the ratio
learned / fixed, per spp level too.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.settings import GUIDE_FEATURES, filter_radius
from mcdenoise.geomean import geometric_mean
from mcdenoise.losses import crop_log_relmse, relmse
from mcdenoise.models.features import FeatureStats, feature_names
from mcdenoise.models.kalantari import KalantariModel, new_model, settings_class
from mcdenoise.prep.kalantari import prepare_item
from mcdenoise.train.config import TrainConfig
from mcdenoise.train.loop import CardTask, TrainResult, run_training
from mcdenoise.train.patches import (
    Item,
    LoadReport,
    PatchSampler,
    describe_training,
    image_relmse,
    load_split,
)

#: Trainable model names -> filter kind.
MODELS = {"kalantari-xbf": "xbf", "kalantari-nlm": "nlm"}
#: Pixel stride of the samples the normalisation statistics are computed from.
STATS_STRIDE = 4


def _batch(item: Item) -> dict[str, Tensor]:
    return {k: v[None] for k, v in item.tensors.items()}


class KalantariTask(CardTask):
    """A :class:`~mcdenoise.train.loop.Task` for a Kalantari model.

    The training forward goes through ``forward_module`` (the model, or its DDP wrapper
    under torchrun); validation uses the bare model on ``device`` (both set by
    :func:`~mcdenoise.train.loop.train`).

    Args:
        model: the model to train (its card's ``training`` field is filled on export).
        val_items: prepared validation levels (whole images).
        description: what to record about the training data in the model card.
    """

    def __init__(
        self,
        model: KalantariModel,
        val_items: Sequence[Item],
        description: dict[str, Any],
        loss: str = "relmse",
    ) -> None:
        super().__init__(model, description)
        self.model: KalantariModel = model
        self.loss_name = loss
        self.val_items = list(val_items)
        self._fixed: list[float] | None = None

    def loss(self, batch: dict[str, Tensor]) -> Tensor:
        out = self.forward_module(batch)
        if self.loss_name == "log-relmse":
            return crop_log_relmse(out, batch["reference"], batch["mask"])
        return relmse(out, batch["reference"], batch["mask"])

    def _errors(self, fixed: bool) -> list[float]:
        errs = []
        for it in self.val_items:
            b = {k: v.to(self.device) for k, v in _batch(it).items()}
            off = None
            if fixed:
                shape = (1, len(self.model.card.outputs), *it.size)
                off = torch.zeros(shape, dtype=b["irr"].dtype, device=self.device)
            errs.append(image_relmse(self.model.filter(b, off)[0], b["reference"][0]))
        return errs

    def validate(self) -> dict[str, float]:
        if not self.val_items:
            return {}
        if self._fixed is None:
            self._fixed = self._errors(fixed=True)
        learned = self._errors(fixed=False)
        res: dict[str, float] = {
            "val_loss": sum(learned) / len(learned),
            "val_geomean": geometric_mean(learned),
            "val_fixed_loss": sum(self._fixed) / len(self._fixed),
            "val_fixed_geomean": geometric_mean(self._fixed),
        }
        res["val_ratio"] = res["val_geomean"] / res["val_fixed_geomean"]
        for spp in sorted({it.entry.spp for it in self.val_items if it.entry.spp}):
            idx = [i for i, it in enumerate(self.val_items) if it.entry.spp == spp]
            ratio = geometric_mean([learned[i] for i in idx]) / geometric_mean(
                [self._fixed[i] for i in idx]
            )
            res[f"val_ratio_spp{spp}"] = ratio
        self.last_val = res
        return res


def build(
    cfg: TrainConfig, *, progress: bool = False
) -> tuple[KalantariTask, PatchSampler, LoadReport]:
    """Scan, split, load and prepare the data, compute feature statistics, make the model.

    Raises:
        InputError: unknown model, unknown guide, no usable training image.
    """
    if cfg.model not in MODELS:
        raise InputError(f"unknown model {cfg.model!r}; trainable: {', '.join(MODELS)}")
    unknown = [g for g in cfg.guides if g not in GUIDE_FEATURES]
    if unknown:
        raise InputError(f"unknown guide(s) {unknown}; known: {', '.join(GUIDE_FEATURES)}")
    if not cfg.data:
        raise InputError("no training data: pass --data DIR (a folder made by mcdenoise render)")
    kind = MODELS[cfg.model]
    overrides: dict[str, Any] = {}
    if cfg.kernel:
        key, value = (
            ("kernel_size", cfg.kernel) if kind == "xbf" else ("search_radius", cfg.kernel // 2)
        )
        overrides[key] = value
    if cfg.passes != 1:
        if kind != "xbf":
            raise InputError("passes applies to kalantari-xbf only")
        overrides["passes"] = cfg.passes
    settings = settings_class(kind)(**overrides)
    guides = [g for g in GUIDE_FEATURES if g in cfg.guides]

    def prepare(buffers: Any, ref: Tensor) -> dict[str, Tensor]:
        return prepare_item(buffers, kind, settings, guides, ref, regional=cfg.regional)

    margin = max(cfg.margin, filter_radius(settings))
    crop = cfg.patch + 2 * margin
    train_items, val_items, report = load_split(cfg, prepare, crop=crop, progress=progress)
    keys = set(train_items[0].tensors)
    guide_vars = [g for g in guides if f"fvar.{g}" in keys]
    val_items = [it for it in val_items if set(it.tensors) == keys]
    names = feature_names(guides, guide_vars, cfg.regional)
    stats = FeatureStats.from_samples(
        names,
        [it.tensors["features"][None, :, ::STATS_STRIDE, ::STATS_STRIDE] for it in train_items],
    )
    torch.manual_seed(cfg.seed)
    model = new_model(kind, guides, guide_vars, stats, cfg.hidden, overrides)
    description = describe_training(cfg, train_items, val_items)
    sampler = PatchSampler(
        train_items, patch=cfg.patch, margin=margin, importance=cfg.importance, noisy_key="color"
    )
    return KalantariTask(model, val_items, description, cfg.loss), sampler, report


def train_kalantari(
    cfg: TrainConfig, out: str | Path, *, resume: bool = False, progress: bool = True
) -> tuple[TrainResult, LoadReport]:
    """Train a Kalantari model into the run folder ``out`` (see :mod:`mcdenoise.train.loop`)."""
    return run_training(cfg, build, out, resume=resume, progress=progress)
