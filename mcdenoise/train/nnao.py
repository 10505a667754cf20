"""Training ``nnao`` (Holden et al. 2016) on ray-traced AO renders.

``mcdenoise train --model nnao --data DIR`` on a folder of AO renders (``effects = ["ao"]``,
with the camera header; ``data/recipes/nnao.md``). Each image's G-buffer gives the network
inputs of every pixel (:func:`mcdenoise.methods.nnao.nnao_inputs`, the same function the
method uses) and the reference render the target: its grey level, the ray-traced AO. The
noisy colour is not used, so every spp level of an image gives the same inputs up to the
G-buffer's pixel filtering; ``-s levels=4`` (one level) saves memory and time.

Like Holden et al. the loss is the mean squared error per pixel, over the non-empty pixels
(the config's ``loss`` field is not used; the model card records ``"loss_used": "mse"``);
a step draws ``batch`` × :data:`PIXELS_PER_BATCH` pixels uniformly from all training images
(the network is per pixel: there are no crops). Validation: the MSE and relMSE (ε = 0.01) of
the whole validation images (split by image); ``val_loss`` is the MSE.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.methods.nnao import gbuffer_for, nnao_inputs
from mcdenoise.models.nnao import NnaoCard, NnaoModel
from mcdenoise.train.config import TrainConfig
from mcdenoise.train.loop import CardTask, TrainResult, run_training
from mcdenoise.train.patches import REFERENCE, Item, LoadReport, describe_training, load_split

#: Pixels per unit of ``batch`` (``batch = 8``: 8192 pixels a step).
PIXELS_PER_BATCH = 1024
#: Sample points of the trained model.
SAMPLES = 16
#: The spiral's radial exponent of the trained model (recorded in its card).
RADIAL_POWER = 1.0


def prepare(buffers: FeatureBuffers, ref: Tensor) -> dict[str, Tensor]:
    """Inputs ``(C, H, W)``, the target AO ``(1, H, W)`` and the non-empty mask of one level.

    Raises:
        InputError: no camera / AO radius in the file (not an AO render of mcdenoise).
    """
    g, radius = gbuffer_for(buffers, {"radius": None, "fov": None, "fov_axis": ""})
    return {
        "inputs": nnao_inputs(g, radius, SAMPLES, RADIAL_POWER),
        "valid": g.valid[None].float(),
        REFERENCE: ref.float().mean(0, keepdim=True),
    }


def _pixels(items: Sequence[Item]) -> tuple[Tensor, Tensor]:
    xs, ys = [], []
    for it in items:
        t = it.tensors
        m = t["valid"][0] > 0
        xs.append(t["inputs"].permute(1, 2, 0)[m])
        ys.append(t[REFERENCE][0][m])
    return torch.cat(xs), torch.cat(ys)


class PixelSampler:
    """Uniform random pixels of the training images (the loop's ``sampler.batch``)."""

    def __init__(self, items: Sequence[Item]) -> None:
        self.x, self.y = _pixels(items)

    def batch(self, n: int, gen: torch.Generator) -> dict[str, Tensor]:
        idx = torch.randint(0, len(self.y), (n * PIXELS_PER_BATCH,), generator=gen)
        return {"inputs": self.x[idx], "target": self.y[idx]}


class NnaoTask(CardTask):
    """The :class:`~mcdenoise.train.loop.Task` of nnao."""

    def __init__(
        self, model: NnaoModel, val_items: Sequence[Item], description: dict[str, Any]
    ) -> None:
        super().__init__(model, description)
        self.model: NnaoModel = model
        self.val = _pixels(val_items) if val_items else None

    def loss(self, batch: dict[str, Tensor]) -> Tensor:
        out = self.forward_module(batch["inputs"])
        return torch.mean((out.float() - batch["target"]) ** 2)

    def validate(self) -> dict[str, float]:
        if self.val is None:
            return {}
        x, y = (t.to(self.device) for t in self.val)
        out = self.model(x)
        mse = float(torch.mean((out - y) ** 2))
        rel = float(torch.mean((out - y) ** 2 / (y * y + 0.01)))
        self.last_val = {"val_loss": mse, "val_relmse": rel}
        return self.last_val


def build(cfg: TrainConfig, *, progress: bool = False) -> tuple[NnaoTask, PixelSampler, LoadReport]:
    """Load and prepare the data, make the model (``cfg.hidden``: its hidden layers).

    Raises:
        InputError: no data, no usable AO image.
    """
    if not cfg.data:
        raise InputError("no training data: pass --data DIR (AO renders of mcdenoise render)")
    train_items, val_items, report = load_split(cfg, prepare, crop=1, progress=progress)
    torch.manual_seed(cfg.seed)
    model = NnaoModel(NnaoCard(samples=SAMPLES, radial_power=RADIAL_POWER, hidden=list(cfg.hidden)))
    description = {**describe_training(cfg, train_items, val_items), "loss_used": "mse"}
    return NnaoTask(model, val_items, description), PixelSampler(train_items), report


def train_nnao(
    cfg: TrainConfig, out: str | Path, *, resume: bool = False, progress: bool = True
) -> tuple[TrainResult, LoadReport]:
    """Train an nnao model into the run folder ``out`` (see :mod:`mcdenoise.train.loop`)."""
    return run_training(cfg, build, out, resume=resume, progress=progress)


__all__ = ["PIXELS_PER_BATCH", "SAMPLES", "NnaoTask", "PixelSampler", "build", "train_nnao"]
