"""Names and normalisation of the Kalantari model's per-pixel input features.

:func:`feature_names` is the ordered feature set of an input with a given set of guides (and
guide variances); ``compute_features`` (``prep/kalantari.py``) computes exactly these
channels from the buffers (the table of what each one is lives there). A model stores the
names with their normalisation statistics (:class:`FeatureStats`: per-feature mean and
standard deviation over the training pixels) and refuses a file whose names differ from what
this version computes (:func:`check_feature_names`). Normalised values are clamped to ±8 so a
firefly or an absurd depth cannot drive the network out of its training range. The kpcn
network normalises its input channels with the same statistics class.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.settings import GUIDE_FEATURES
from mcdenoise.modelfile import CardFields

#: Window edges of the local statistics.
WINDOWS: tuple[int, ...] = (3, 7, 21)
#: Window edge of the regional means (``regional=True``; see ``prep/kalantari.py``).
REGION = 63
#: Channel names of each guide feature (as in the FeatureBuffers layout).
GUIDE_CHANNELS: dict[str, tuple[str, ...]] = {
    "albedo": ("r", "g", "b"),
    "normal": ("x", "y", "z"),
    "depth": ("z",),
    "position": ("x", "y", "z"),
}
#: Normalised features are clamped to ``±CLAMP``.
CLAMP = 8.0


def feature_names(
    guides: Sequence[str], with_guide_vars: Sequence[str] = (), regional: bool = False
) -> list[str]:
    """The ordered feature names for inputs with ``guides`` (and variances of
    ``with_guide_vars``), with the regional means last when ``regional``."""
    guides = [g for g in GUIDE_FEATURES if g in guides]
    names = ["screen.x", "screen.y", "color.r", "color.g", "color.b"]
    for g in guides:
        names += [f"{g}.{c}" for c in GUIDE_CHANNELS[g]]
    names += [f"lum.mean.{w}" for w in WINDOWS] + [f"lum.std.{w}" for w in WINDOWS]
    for g in guides:
        names += [f"{g}.std.{w}" for w in WINDOWS]
    names += ["lum.grad"] + [f"{g}.grad" for g in guides]
    names += ["lum.mad", "color.relvar"]
    names += [f"{g}.var" for g in guides if g in with_guide_vars]
    names += ["spp"]
    if regional:
        names += ["region.relvar", "region.lum.std", "region.lum.grad"]
        names += [f"region.{g}.grad" for g in guides]
    return names


def check_feature_names(
    expected: Sequence[str], got: Sequence[str], what: str, got_label: str = "the input"
) -> None:
    """Raise an :class:`InputError` naming the difference when ``got != expected``.

    ``expected`` are a model's feature names, ``got`` those computed for ``got_label``.
    """
    if list(expected) == list(got):
        return
    missing = [n for n in expected if n not in got]
    extra = [n for n in got if n not in expected]
    if missing or extra:
        detail = []
        if missing:
            detail.append(f"the model uses {', '.join(_group(missing))}, which {got_label} lacks")
        if extra:
            detail.append(
                f"{got_label} has {', '.join(_group(extra))}, which the model was not trained with"
            )
        raise InputError(f"{what}: feature set differs: {'; '.join(detail)}")
    raise InputError(f"{what}: feature order differs from the model's")


def _group(names: Sequence[str]) -> list[str]:
    """Collapse ``albedo.r, albedo.g, ...`` into ``albedo.*`` for short messages."""
    out: list[str] = []
    for n in names:
        head = n.rsplit(".", 1)[0]
        same = [m for m in names if m.rsplit(".", 1)[0] == head]
        label = f"{head}.*" if len(same) > 1 else n
        if label not in out:
            out.append(label)
    return out


@dataclass
class FeatureStats:
    """Per-feature mean and standard deviation over the training pixels.

    Attributes:
        names: feature names, in channel order.
        mean, std: one float per feature (``std`` floored at 1e-6).
    """

    names: list[str]
    mean: list[float]
    std: list[float]

    @staticmethod
    def from_samples(names: Sequence[str], samples: Sequence[Tensor]) -> FeatureStats:
        """Statistics of ``(1, F, H, W)`` feature maps (NaNs -- unknown spp -- ignored)."""
        if not samples:
            raise InputError("no feature maps to compute normalisation statistics from")
        flat = torch.cat([s.double().flatten(2)[0] for s in samples], dim=1)  # (F, N)
        ok = torch.isfinite(flat)
        n = ok.sum(1).clamp_min(1)
        z = torch.where(ok, flat, torch.zeros_like(flat))
        mean = z.sum(1) / n
        var = (torch.where(ok, flat - mean[:, None], torch.zeros_like(flat)).square()).sum(1) / n
        return FeatureStats(list(names), mean.tolist(), var.sqrt().clamp_min(1e-6).tolist())

    def to_dict(self) -> dict[str, list]:
        return {"names": list(self.names), "mean": list(self.mean), "std": list(self.std)}

    @staticmethod
    def from_dict(d: object, what: str = "model file", field: str = "features") -> FeatureStats:
        """Statistics from a card's field ``field`` (a dict), every value checked
        (:class:`~mcdenoise.modelfile.CardFields`): names, finite means, positive stds."""
        f = CardFields(d, what, field)
        names = f.texts("names", min_len=1, unique=True)
        mean = f.numbers("mean", -1e30, 1e30, min_len=1)
        std = f.numbers("std", 1e-30, 1e30, min_len=1)
        if not (len(names) == len(mean) == len(std)):
            f.fail("names", "feature statistics have inconsistent lengths")
        return FeatureStats(names, mean, std)

    def normalize(self, feats: Tensor) -> Tensor:
        """``(feats - mean) / std`` clamped to ±:data:`CLAMP`; NaN/Inf -> 0 (the mean)."""
        m = torch.tensor(self.mean, dtype=feats.dtype, device=feats.device)[None, :, None, None]
        s = torch.tensor(self.std, dtype=feats.dtype, device=feats.device)[None, :, None, None]
        z = (feats - m) / s
        z = torch.nan_to_num(z, nan=0.0, posinf=CLAMP, neginf=-CLAMP)
        return z.clamp(-CLAMP, CLAMP)


__all__ = [
    "CLAMP",
    "GUIDE_CHANNELS",
    "REGION",
    "WINDOWS",
    "FeatureStats",
    "check_feature_names",
    "feature_names",
]
