"""Training the kernel-predicting CNN (``kpcn``), and fine-tuning a new source encoder.

Data: a folder made by ``mcdenoise render`` (every spp level of every image; the split is by
image). Each image is prepared once for the ``full`` source
(:func:`~mcdenoise.prep.kpcn.prepare_tensors`); crops are drawn ∝ the noisy error
(:class:`~mcdenoise.train.patches.PatchSampler`), augmented (flips, 90° rotations, RGB
permutations) and each crop is shown to the network as one of the
trained sources (round robin from a random offset, so every encoder is used every step when
``batch >= len(sources)``): a ``basic`` crop simply lacks the variance, depth, position and
feature variances. The loss (default SMAPE, :mod:`mcdenoise.losses`) is computed on the crop
centre, in float32.

Validation runs the model on the *whole* validation images once per source and reports the
relMSE geometric mean per source and per spp level, with the noisy input's for scale;
``val_loss`` (which picks the exported ``model.pt``) is the geometric mean over images and
sources.

Fine-tuning (``finetune_encoder = SOURCE``, ``base = RUN``, Vogels 2018): the model of ``base``
is loaded, an encoder for ``SOURCE`` is added (or reset) with statistics from this data set,
and only that encoder is trained; the trunk and the other encoders stay frozen.

Continued training (``base = RUN`` alone): every weight of the base model, and its
normalisation statistics, are the starting point, and the whole model is trained with this
run's schedule (a warm restart, or fine-tuning on a user's own renders). The architecture is
the base's; a config that asks for a different one is refused, naming the difference.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.geomean import geometric_mean
from mcdenoise.losses import compute_loss, crop_log_relmse
from mcdenoise.models.encoders import SOURCES, channel_names, encoder, source_channels
from mcdenoise.models.features import FeatureStats
from mcdenoise.models.kpcn import KpcnCard, KpcnModel, new_model
from mcdenoise.prep.kpcn import COLOR_TENSORS, exposure_scale, prepare_tensors, scale_exposure
from mcdenoise.train.config import TrainConfig
from mcdenoise.train.loop import TrainResult, run_training
from mcdenoise.train.pack import (
    PackSummary,
    is_pack,
    load_training_data,
    pack_items,
    pack_meta,
)
from mcdenoise.train.patches import (
    Item,
    LoadReport,
    PatchSampler,
    Prepare,
    augment,
    describe_training,
    image_relmse,
)

#: Pixel stride of the samples the normalisation statistics are computed from.
STATS_STRIDE = 4
#: Default kernel edge when the config says 0.
DEFAULT_KERNEL = 21


def source_stats(items: Sequence[Item], source: str) -> FeatureStats:
    """Per-channel mean / std of ``source``'s input channels over the items' pixels."""
    samples = []
    for it in items:
        t = {k: v[None] for k, v in it.tensors.items()}
        samples.append(source_channels(source, t)[..., ::STATS_STRIDE, ::STATS_STRIDE])
    return FeatureStats.from_samples(channel_names(source), samples)


#: Features of a ``basic`` crop that the trainer prefilters as inference does (``prefilter``),
#: kept in the prepared item under ``<name>`` + :data:`BASIC_SUFFIX`.
BASIC_PREFILTERED = ("albedo", "normal")
BASIC_SUFFIX = "_basic"


def use_basic_features(batch: dict[str, Tensor], basic: Tensor) -> dict[str, Tensor]:
    """The batch with the crops flagged in ``basic`` ``(B,)`` given their basic-source
    (prefiltered) albedo and normal, and those extra tensors removed."""
    out = {k: v for k, v in batch.items() if not k.endswith(BASIC_SUFFIX)}
    for name in BASIC_PREFILTERED:
        alt = batch.get(name + BASIC_SUFFIX)
        if alt is not None:
            out[name] = torch.where(basic.view(-1, 1, 1, 1), alt, batch[name])
    return out


def augment_exposure(batch: dict[str, Tensor], scale: Tensor) -> dict[str, Tensor]:
    """Colour and reference of each crop times ``scale`` ``(B,)``, the colour variance times
    its square (albedo, normal, depth, position and their variances do not change)."""
    s = scale.view(-1, 1, 1, 1)
    out = dict(batch)
    for key in ("color", "reference"):
        out[key] = batch[key] * s.to(batch[key].dtype)
    if "color_var" in batch:
        out["color_var"] = batch["color_var"] * s.square().to(batch["color_var"].dtype)
    return out


#: Validation images on which the compositor weights are measured.
SCALE_USE_IMAGES = 8
#: Below this mean compositor weight a scale counts as unused (``mcdenoise train`` says so).
UNUSED_SCALE_WEIGHT = 0.01


class KpcnTask:
    """A :class:`~mcdenoise.train.loop.Task` for a :class:`KpcnModel`."""

    def __init__(
        self,
        model: KpcnModel,
        val_items: Sequence[Item],
        description: dict[str, Any],
        cfg: TrainConfig,
        val_sources: Sequence[str],
    ) -> None:
        self.module = model
        self.forward_module = model
        self.model = model
        self.val_items = list(val_items)
        self.description = description
        self.cfg = cfg
        self.val_sources = list(val_sources)
        self.last_val: dict[str, float] = {}
        self._noisy: list[float] | None = None
        # DDP: with fewer crops per step than sources, some encoder gets no gradient
        self.find_unused_parameters = cfg.batch < len(val_sources)

    def loss(self, batch: dict[str, Tensor]) -> Tensor:
        out = self.forward_module(batch)
        if self.cfg.loss == "log-relmse":
            return crop_log_relmse(out.float(), batch["reference"], batch["mask"])
        return compute_loss(
            self.cfg.loss,
            out,
            batch["reference"],
            batch["mask"],
            noisy=batch["color"],
            slope=self.cfg.asym_slope,
        )

    def validate(self) -> dict[str, float]:
        if not self.val_items:
            return {}
        device = next(self.model.parameters()).device
        if self._noisy is None:
            self._noisy = [
                image_relmse(it.tensors["color"], it.tensors["reference"]) for it in self.val_items
            ]
        res: dict[str, float] = {}
        every: list[float] = []
        for src in self.val_sources:
            errs = []
            for it in self.val_items:
                t = {k: v[None].to(device) for k, v in it.tensors.items() if k != "reference"}
                t = use_basic_features(t, torch.tensor([src == "basic"], device=device))
                out = self.model.denoise_tensors(t, src)[0].cpu()
                errs.append(image_relmse(out, it.tensors["reference"]))
            every += errs
            res[f"val_{src}_geomean"] = geometric_mean(errs)
            res[f"val_{src}_ratio_to_noisy"] = geometric_mean(errs) / geometric_mean(self._noisy)
            for spp in sorted({it.entry.spp for it in self.val_items if it.entry.spp}):
                idx = [i for i, it in enumerate(self.val_items) if it.entry.spp == spp]
                res[f"val_{src}_spp{spp}"] = geometric_mean([errs[i] for i in idx])
        res["val_loss"] = geometric_mean(every) if every else math.inf
        res.update(self._scale_use(device))
        self.last_val = res
        return res

    def _scale_use(self, device: torch.device) -> dict[str, float]:
        """``val_scale<s>_weight``: mean compositor weight of each coarser scale ``s`` over
        (up to 8 of) the validation images, on the first source; near 0: the scale is unused."""
        if self.model.card.scales < 2:
            return {}
        sums = [0.0] * (self.model.card.scales - 1)
        items = self.val_items[:SCALE_USE_IMAGES]
        m = self.model.multiple
        for it in items:
            t = {k: v[None].to(device) for k, v in it.tensors.items() if k != "reference"}
            t = use_basic_features(t, torch.tensor([self.val_sources[0] == "basic"], device=device))
            h, w = t["color"].shape[-2:]
            t = {k: v[..., : h - h % m, : w - w % m] for k, v in t.items()}
            for s, a in enumerate(self.model.compositor_weights(t, self.val_sources[0])):
                sums[s] += a.mean().item() / len(items)
        return {f"val_scale{s + 1}_weight": v for s, v in enumerate(sums)}

    def export(self, path: Path) -> None:
        # keep what the card already records (a fine-tuned model's base and its training)
        self.model.card.training = {
            **self.model.card.training,
            **self.description,
            "validation": dict(self.last_val),
        }
        self.model.save(path)


def _finetune_model(cfg: TrainConfig, train_items: Sequence[Item]) -> KpcnModel:
    """The base model with a fresh encoder for ``cfg.finetune_encoder`` (with
    ``cfg.finetune_keep``: the base's own encoder and statistics of that source, trained
    further); all else frozen."""
    src = cfg.finetune_encoder
    if src not in SOURCES:
        raise InputError(f"unknown source {src!r}; known: {', '.join(SOURCES)}")
    base = KpcnModel.load(cfg.base)
    if base.card.encoder != "source-aware":
        raise InputError(f"{cfg.base}: a shared-encoder model has no per-source encoder to train")
    keep = cfg.finetune_keep
    if keep and src not in base.card.sources:
        raise InputError(f"{cfg.base}: finetune_keep needs a base with a '{src}' encoder")
    stats = dict(base.card.stats)
    if not keep:
        stats[src] = source_stats(train_items, src)
    sources = [s for s in SOURCES if s in base.card.sources or s == src]
    card = KpcnCard(
        sources,
        stats,
        list(base.card.channels),
        base.card.kernel,
        base.card.scales,
        base.card.encoder,
        training={"base": str(cfg.base), "base_training": base.card.training},
        albedo_kernels=base.card.albedo_kernels,
    )
    model = KpcnModel(card)
    state = base.state_dict()
    if not keep:
        state = {k: v for k, v in state.items() if not k.startswith(f"norms.{src}.")}
        state = {k: v for k, v in state.items() if not k.startswith(f"encoders.{src}.")}
    _, unexpected = model.load_state_dict(state, strict=False)
    assert not unexpected, unexpected
    if not keep:
        model.encoders[src] = encoder(len(channel_names(src)), card.channels[0])
    for name, p in model.named_parameters():
        p.requires_grad_(name.startswith(f"encoders.{src}."))
    return model


def _continued_model(cfg: TrainConfig, sources: Sequence[str]) -> KpcnModel:
    """The model of ``cfg.base`` (every weight trained further), checked against ``cfg``."""
    base = KpcnModel.load(cfg.base)
    card = base.card
    wanted = {
        "kernel": (cfg.kernel or card.kernel, card.kernel),
        "channels": (list(cfg.channels), list(card.channels)),
        "scales": (cfg.scales, card.scales),
        "encoder": (cfg.encoder, card.encoder),
    }
    diff = [f"{k} {want} (base: {have})" for k, (want, have) in wanted.items() if want != have]
    missing = [s for s in sources if s not in card.sources]
    if missing:
        diff.append(f"sources {missing} (base has {card.sources}; use --finetune-encoder)")
    if card.albedo_kernels and not cfg.albedo_kernels:
        diff.append("albedo_kernels false (base: true)")
    if diff:
        raise InputError(f"{cfg.base}: the config asks for a different model: {'; '.join(diff)}")
    card.training = {"base": str(cfg.base), "base_training": card.training}
    if cfg.albedo_kernels and not card.albedo_kernels:
        # the base gains albedo kernels (starting near a delta); every other weight is kept
        card.albedo_kernels = True
        model = KpcnModel(card)
        missing_keys, unexpected = model.load_state_dict(base.state_dict(), strict=False)
        assert not unexpected and all(k.startswith("albedo_head.") for k in missing_keys)
        return model
    return base  # loaded with every parameter trainable


#: Config keys the prepared training data depends on: a pack (:mod:`mcdenoise.train.pack`)
#: records them, and training from it needs the same values.
PACK_KEYS = (
    "model",
    "levels",
    "val_fraction",
    "seed",
    "max_images",
    "sources",
    "prefilter",
    "normalize_exposure",
)


def make_prepare(cfg: TrainConfig, sources: Sequence[str]) -> Prepare:
    """The ``prepare`` hook of :func:`~mcdenoise.train.patches.load_items` for ``cfg``: the
    ``full`` source's tensors, the ``basic`` crops' prefiltered albedo and normal, the
    reference, and the exposure normalisation."""

    def prepare(buffers: Any, ref: Tensor) -> dict[str, Tensor]:
        full_mode = cfg.prefilter if cfg.prefilter in ("all", "adaptive", "learned") else "off"
        t = prepare_tensors(buffers, "full", full_mode)
        if cfg.prefilter != "off" and "basic" in sources:
            # what the basic source gets at inference: no feature variances, so the albedo
            # and normal are prefiltered with a variance estimated from themselves (auto,
            # all), or exactly as that inference mode does (adaptive, learned)
            basic_mode = cfg.prefilter if cfg.prefilter in ("adaptive", "learned") else "auto"
            basic = prepare_tensors(buffers.subset(list(SOURCES["basic"])), "basic", basic_mode)
            t.update({f"{k}{BASIC_SUFFIX}": basic[k] for k in BASIC_PREFILTERED})
        t["reference"] = ref
        if cfg.normalize_exposure:
            t = scale_exposure(t, exposure_scale(t["color"]))
        return t

    return prepare


def pack_kpcn(
    cfg: TrainConfig,
    path: str | Path,
    *,
    dtype: str = "float16",
    compress: bool = True,
    shard_bytes: int = 0,
    progress: bool = False,
) -> PackSummary:
    """Prepare ``cfg.data`` as :func:`build` does and write it to the pack ``path``
    (:mod:`mcdenoise.train.pack`); ``mcdenoise train --data PATH`` then trains from it."""
    if not cfg.data or is_pack(cfg.data):
        raise InputError("packing needs --data DIR (a folder made by mcdenoise render)")
    sources = [s for s in SOURCES if s in cfg.sources]
    return pack_items(
        cfg,
        make_prepare(cfg, sources),
        path,
        keys=PACK_KEYS,
        dtype=dtype,
        compress=compress,
        shard_bytes=shard_bytes,
        progress=progress,
    )


def build(cfg: TrainConfig, *, progress: bool = False) -> tuple[KpcnTask, PatchSampler, LoadReport]:
    """Scan, split, load and prepare the data, compute statistics, make (or load) the model.

    Raises:
        InputError: bad sources, crop size, no usable training image, bad base model.
    """
    if not cfg.data:
        raise InputError("no training data: pass --data DIR (a folder made by mcdenoise render)")
    unknown = [s for s in cfg.sources if s not in SOURCES]
    if unknown or not cfg.sources:
        raise InputError(f"unknown or no sources {cfg.sources}; known: {', '.join(SOURCES)}")
    sources = [s for s in SOURCES if s in cfg.sources]
    prepare = make_prepare(cfg, sources)
    crop = cfg.patch + 2 * cfg.margin
    train_items, val_items, report = load_training_data(
        cfg, prepare, crop=crop, keys=PACK_KEYS, progress=progress
    )
    torch.manual_seed(cfg.seed)
    if cfg.finetune_encoder:
        model = _finetune_model(cfg, train_items)
        trained = [cfg.finetune_encoder]
    elif cfg.base:
        model = _continued_model(cfg, sources)
        trained = sources
    else:
        stats = {s: source_stats(train_items, s) for s in sources}
        model = new_model(
            sources,
            stats,
            channels=cfg.channels,
            kernel=cfg.kernel or DEFAULT_KERNEL,
            scales=cfg.scales,
            encoder=cfg.encoder,
            albedo_kernels=cfg.albedo_kernels,
        )
        trained = sources
    if crop % model.multiple:
        raise InputError(
            f"patch + 2 * margin = {crop} must be a multiple of {model.multiple} "
            f"(the U-Net pools {len(cfg.channels) - 1} times)"
        )
    index = {s: i for i, s in enumerate(model.card.sources)}
    codes = torch.tensor([index[s] for s in trained])

    color_keys = (*COLOR_TENSORS, f"albedo{BASIC_SUFFIX}")
    basic_code = index.get("basic", -1)

    def transform(batch: dict[str, Tensor], g: torch.Generator) -> dict[str, Tensor]:
        if cfg.augment:
            batch = augment(batch, g, color_keys)
        n = batch["color"].shape[0]
        if cfg.exposure > 0:
            stops = (torch.rand(n, generator=g) * 2 - 1) * cfg.exposure
            batch = augment_exposure(batch, torch.exp2(stops))
        offset = int(torch.randint(len(codes), (), generator=g))
        batch["source"] = codes[(torch.arange(n) + offset) % len(codes)]
        return use_basic_features(batch, batch["source"] == basic_code)

    sampler = PatchSampler(
        train_items,
        patch=cfg.patch,
        margin=cfg.margin,
        importance=cfg.importance,
        noisy_key="color",
        transform=transform,
    )
    description = describe_training(cfg, train_items, val_items)
    if is_pack(cfg.data):
        meta = pack_meta(cfg.data)
        description["pack"] = {"source": meta["source"], "dtype": meta["dtype"]}
    task = KpcnTask(model, val_items, description, cfg, trained)
    return task, sampler, report


def train_kpcn(
    cfg: TrainConfig, out: str | Path, *, resume: bool = False, progress: bool = True
) -> tuple[TrainResult, LoadReport]:
    """Train (or fine-tune) a kpcn model into the run folder ``out``."""
    return run_training(cfg, build, out, resume=resume, progress=progress)


__all__ = [
    "BASIC_PREFILTERED",
    "BASIC_SUFFIX",
    "DEFAULT_KERNEL",
    "PACK_KEYS",
    "KpcnTask",
    "augment_exposure",
    "build",
    "make_prepare",
    "pack_kpcn",
    "source_stats",
    "train_kpcn",
    "use_basic_features",
]
