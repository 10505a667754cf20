"""NNAO: a per-pixel MLP that predicts ambient occlusion from a sampled G-buffer neighbourhood.

Holden, Saito and Komura, "Neural Network Ambient Occlusion" (SIGGRAPH Asia 2016 technical
briefs): for each pixel a fixed pattern of sample points around it is read from the
G-buffer, their view-space position relative to the pixel and their normals form the input of
a small fully connected network trained on ray-traced AO; at run time it is one shader pass
(their network is evaluated with a few precomputed filters).

This is the per-pixel MLP of the paper, not a convolutional equivalent. Why: the paper's
point is that the sample pattern scales with the *projected AO radius* (``f r / z`` pixels),
so the same weights see the same world-space neighbourhood at every depth; a convolution has a
fixed pixel footprint and would have to learn every scale of the radius, from far less data
than the 256 training images here give (``data/recipes/nnao.md``). The MLP with a
radius-scaled pattern also has SSAO's cost structure (a few texture fetches per pixel plus a
small matrix product), which is what the comparison with the screen-space methods asks for.

Differences from the paper, and why:

* Inputs per sample (``FEATURES_PER_SAMPLE`` = 7): the offset to the pixel's view-space
  position divided by the AO radius and clamped to ``[-2, 2]`` (3), the sample's view-space
  normal (3), and a 0/1 flag "a surface is there" (off screen / empty pixels give 0 for all
  seven); plus the pixel's own normal (3). Holden feed depth differences and normals too; the
  clamp keeps depth discontinuities (a far background behind a near edge) from giving inputs
  far outside the training range.
* The pattern is a golden-angle spiral of ``samples`` points in the screen-space disk of the
  projected radius (Holden use a fixed random pattern), point ``k`` at radius
  ``((k + 0.5) / samples) ** radial_power`` (:func:`sample_pattern`; the card records the
  exponent). The shipped weights use 1, the spiral of McGuire et al.'s Scalable Ambient
  Obscurance (2012): radii uniform in ``r``, so 4 of 16 points lie within 0.22 of the radius
  instead of 1 with Vogel's even cover (``sqrt``, 0.5, the layout of all earlier files). Why:
  an occluder at distance ``d`` covers a solid angle ~``1/d²``, so the near ring matters most
  for the contact darkening; the cost is the same (same number of fetches). Chosen on the
  validation images of the training data (``data/recipes/nnao.md``: val MSE 0.00406 against
  0.00488).
* Hidden layers and output: ReLU MLP (``hidden``), sigmoid output, so the AO is in ``[0, 1]``
  for any input; the adapter writes 1 on empty pixels (where the ray-traced AO is 1).

This module imports torch only: the G-buffer inputs are built by ``mcdenoise.methods.nnao``
(with :mod:`mcdenoise.ao.geometry`), for both the method and the trainer.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor, nn

from mcdenoise.errors import InputError
from mcdenoise.modelfile import (
    MAX_WIDTH,
    Card,
    CardModule,
    check_model_size,
)

FORMAT = "mcdenoise.nnao/1"
#: Inputs per sample point: offset / radius (3), normal (3), surface present (1).
FEATURES_PER_SAMPLE = 7
#: Clamp of the offset / radius inputs (depth discontinuities).
OFFSET_CLAMP = 2.0
#: Most sample points a model file may ask for (the inputs of every pixel are built at once:
#: 7 floats per sample point and pixel).
MAX_SAMPLES = 128
#: The spiral's radial exponent of model files whose card does not record one (all files
#: written before ``radial_power`` existed: Vogel's ``sqrt``).
LEGACY_RADIAL_POWER = 0.5


def input_channels(samples: int) -> int:
    """Input size of a model with ``samples`` sample points (plus the pixel's normal)."""
    return FEATURES_PER_SAMPLE * samples + 3


def sample_pattern(samples: int, radial_power: float = LEGACY_RADIAL_POWER) -> Tensor:
    """The ``(samples, 2)`` screen-space offsets, in units of the projected AO radius: a golden
    angle spiral, point ``k`` at radius ``((k + 0.5) / samples) ** radial_power`` and angle
    ``k`` golden angles (0.5: Vogel's even cover of the disk; 1: SAO's spiral, denser near the
    centre)."""
    k = torch.arange(samples, dtype=torch.float32)
    r = ((k + 0.5) / samples) ** radial_power
    a = k * math.pi * (3.0 - math.sqrt(5.0))
    return torch.stack([r * torch.cos(a), r * torch.sin(a)], dim=1)


@dataclass
class NnaoCard(Card):
    """What a model file records besides the weights.

    Attributes:
        samples: sample points per pixel (the input layout, :func:`input_channels`).
        radial_power: the spiral's radial exponent (:func:`sample_pattern`); a card without
            it is read as :data:`LEGACY_RADIAL_POWER`, the layout such files were trained with.
        hidden: hidden layer sizes.
        training: what it was trained on (filled by the trainer).
    """

    samples: int = 16
    radial_power: float = LEGACY_RADIAL_POWER
    hidden: list[int] = field(default_factory=lambda: [32, 16])
    training: dict[str, Any] = field(default_factory=dict)
    format: str = FORMAT

    def check(self, what: str = "model") -> None:
        if self.samples < 1 or not self.hidden or any(h < 1 for h in self.hidden):
            raise InputError(f"{what}: bad samples {self.samples} / hidden {self.hidden}")
        if not (math.isfinite(self.radial_power) and self.radial_power > 0):
            raise InputError(f"{what}: bad radial_power {self.radial_power} (must be > 0)")

    @staticmethod
    def from_dict(d: Mapping[str, Any], what: str = "model file") -> NnaoCard:
        """The card of a model file: every field's type and range checked, and the size of
        the network bounded (:mod:`mcdenoise.modelfile`), before anything is built."""
        f = NnaoCard.fields(d, what)
        card = NnaoCard(
            samples=f.integer("samples", 1, MAX_SAMPLES),
            radial_power=f.number("radial_power", 0.01, 100.0, default=LEGACY_RADIAL_POWER),
            hidden=f.integers("hidden", 1, MAX_WIDTH),
            training=f.mapping("training", default={}),
        )
        card.check(what)
        check_model_size(lambda: NnaoModel(card), what)
        return card


class NnaoModel(CardModule):
    """The MLP: ``forward(x)`` maps inputs ``(..., C)`` to AO ``(...)`` in ``[0, 1]``."""

    card_class = NnaoCard

    def __init__(self, card: NnaoCard) -> None:
        super().__init__()
        card.check()
        self.card = card
        sizes = [input_channels(card.samples), *card.hidden]
        layers: list[nn.Module] = []
        for a, b in itertools.pairwise(sizes):
            layers += [nn.Linear(a, b), nn.ReLU()]
        layers.append(nn.Linear(sizes[-1], 1))
        self.net = nn.Sequential(*layers)
        # start at "unoccluded" (sigmoid(2) = 0.88): most pixels of an AO image are near 1
        last = layers[-1]
        assert isinstance(last, nn.Linear)
        nn.init.constant_(last.bias, 2.0)

    def forward(self, x: Tensor) -> Tensor:
        # not-finite inputs (never produced by the input builder) must not leak NaN
        x = torch.nan_to_num(x, nan=0.0, posinf=OFFSET_CLAMP, neginf=-OFFSET_CLAMP)
        return torch.sigmoid(self.net(x)[..., 0])


__all__ = [
    "FEATURES_PER_SAMPLE",
    "FORMAT",
    "LEGACY_RADIAL_POWER",
    "MAX_SAMPLES",
    "OFFSET_CLAMP",
    "NnaoCard",
    "NnaoModel",
    "input_channels",
    "sample_pattern",
]
