"""Learned per-pixel filter parameters: the Kalantari, Bako, Sen 2015 MLP.

A small per-pixel MLP (1×1 convolutions) maps per-pixel features
(``compute_features`` of ``prep/kalantari.py``, named and normalised as in
:mod:`mcdenoise.models.features`) to the bandwidths of a classical filter, and the filter does
the denoising:

``kind = "xbf"``
    the cross-bilateral filter of :mod:`mcdenoise.filters.cross_bilateral`; outputs: the
    spatial bandwidth α, the colour bandwidth β and one bandwidth γ_k per guide feature.
``kind = "nlm"``
    the non-local means of :mod:`mcdenoise.filters.nlm`; outputs: its ``k`` and one ``k_f``
    per guide feature.

Parametrisation. Every bandwidth is the tuned fixed-filter default
(:class:`~mcdenoise.filters.settings.XbfSettings` / ``NlmSettings``, the exact value the
``cross-bilateral`` / ``nlm`` methods use) times ``exp(o)``, with the network's
log-offset ``o = B · tanh(raw / B)`` bounded by ``B = 3`` (a factor 20 either way). The last
layer starts at zero, so the **untrained model is exactly the fixed-parameter filter**;
training can only move away from it where that lowers the loss, positivity is built in, and
a multiplicative offset treats a bandwidth of 0.02 (depth) and 8 px (space) alike. The
filter runs on the same prepared inputs as the fixed pipeline (``prepare_item`` of
``prep/kalantari.py``: sanitised, normalised inputs and albedo demodulation), so the
comparison with the fixed filter is like for like. The module takes prepared tensor batches
only; :mod:`mcdenoise.methods.kalantari` runs it on a FeatureBuffers.

Model file (``torch.save`` of a dict, read with ``weights_only=True``)::

    {"card": {format, kind, guides, guide_vars, features (FeatureStats dict), hidden,
              outputs, bound, settings, training}, "state": state_dict}

Loading checks the format version and that the features the code computes for the model's
guide set are the ones stored (names and order); an input that lacks a guide the model was
trained with is refused with a message naming it
(``check_inputs`` of ``prep/kalantari.py``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from mcdenoise import __version__
from mcdenoise.errors import InputError
from mcdenoise.filters.cross_bilateral import cross_bilateral
from mcdenoise.filters.nlm import non_local_means
from mcdenoise.filters.settings import (
    GUIDE_FEATURES,
    NlmSettings,
    XbfSettings,
    feature_bandwidths,
    filter_radius,
)
from mcdenoise.modelfile import (
    MAX_WIDTH,
    Card,
    CardFields,
    CardModule,
    check_model_size,
)
from mcdenoise.models.features import FeatureStats, check_feature_names, feature_names

#: Version of the model file layout.
FORMAT = "mcdenoise.kalantari/1"
#: Bound ``B`` of the log-offsets.
BOUND = 3.0
KINDS = ("xbf", "nlm")


def settings_class(kind: str) -> type[XbfSettings] | type[NlmSettings]:
    if kind not in KINDS:
        raise InputError(f"unknown Kalantari filter kind {kind!r}; known: {', '.join(KINDS)}")
    return XbfSettings if kind == "xbf" else NlmSettings


def output_names(kind: str, guides: Sequence[str], passes: int = 1) -> list[str]:
    """Names of the predicted log-offsets, in channel order.

    A two-pass cross-bilateral model (``passes = 2``) also predicts the second pass's spatial
    and colour bandwidths (its colour distance is measured on the first pass's result).
    """
    head = ["spatial", "color"] if kind == "xbf" else ["k"]
    tail = ["spatial2", "color2"] if kind == "xbf" and passes == 2 else []
    return head + [g for g in GUIDE_FEATURES if g in guides] + tail


@dataclass
class ModelCard(Card):
    """Everything needed to rebuild and check a model (JSON-able).

    Attributes:
        kind: ``"xbf"`` or ``"nlm"``.
        guides: guide features the model uses (and requires), in :data:`GUIDE_FEATURES` order.
        guide_vars: guides whose variance the model was trained with.
        features: normalisation statistics (their ``names`` are the feature set).
        hidden: hidden layer sizes of the MLP.
        settings: the fixed-filter settings the offsets multiply (field -> value).
        training: free-form description of the training run (data, steps, metrics).
    """

    kind: str
    guides: list[str]
    guide_vars: list[str]
    features: FeatureStats
    hidden: list[int]
    settings: dict[str, Any] = field(default_factory=dict)
    training: dict[str, Any] = field(default_factory=dict)
    bound: float = BOUND
    format: str = FORMAT

    @property
    def regional(self) -> bool:
        """Whether the features include the regional means (:mod:`~mcdenoise.models.features`)."""
        return any(n.startswith("region.") for n in self.features.names)

    @property
    def outputs(self) -> list[str]:
        return output_names(self.kind, self.guides, int(self.settings.get("passes", 1)))

    def filter_settings(self) -> XbfSettings | NlmSettings:
        cls = settings_class(self.kind)
        known = {f.name for f in dataclasses.fields(cls)}
        values = {
            k: (tuple(v) if isinstance(v, list) else v)
            for k, v in self.settings.items()
            if k in known
        }
        return cls(**values)

    def plain(self) -> dict[str, Any]:
        d = super().plain()
        d["features"] = self.features.to_dict()
        d["outputs"] = self.outputs
        return d

    @staticmethod
    def from_dict(d: Mapping[str, Any], what: str = "model file") -> ModelCard:
        """The card of a model file: every field's type and range checked, and the size of
        the network it describes bounded (:mod:`mcdenoise.modelfile`), before anything is built.
        """
        f = ModelCard.fields(d, what)
        kind = f.text("kind", KINDS)
        card = ModelCard(
            kind=kind,
            guides=f.texts("guides", GUIDE_FEATURES, unique=True),
            guide_vars=f.texts("guide_vars", GUIDE_FEATURES, unique=True),
            features=FeatureStats.from_dict(f.get("features"), what, "features"),
            hidden=f.integers("hidden", 1, MAX_WIDTH, min_len=0),
            settings=card_settings(f, kind),
            training=f.mapping("training", default={}),
            bound=f.number("bound", 0.01, 100.0, default=BOUND),
        )
        n_in, n_out = len(card.features.names), len(card.outputs)
        check_model_size(lambda: KalantariNet(n_in, card.hidden, n_out, card.bound), what)
        return card


#: Ranges of the integer filter settings a card may hold (a card from a file must not ask for
#: a filter that never ends; the shipped models use a 21-pixel window and radii 10 and 1).
SETTING_RANGES: dict[str, tuple[int, int]] = {
    "kernel_size": (1, 101),
    "search_radius": (0, 50),
    "patch_radius": (0, 10),
    "passes": (1, 2),
}


def card_settings(f: CardFields, kind: str) -> dict[str, Any]:
    """The ``settings`` field of a card: fields of the ``kind``'s settings class only, each
    of its type (integers in :data:`SETTING_RANGES`, numbers not NaN and >= 0, guide names)."""
    defaults = {x.name: x.default for x in dataclasses.fields(settings_class(kind))}
    s = f.sub("settings", default={})
    out: dict[str, Any] = {}
    for key in f.mapping("settings", default={}):
        if key not in defaults:
            s.fail(key, f"is not a setting of the {kind} filter")
        default = defaults[key]
        if isinstance(default, bool):
            out[key] = s.flag(key)
        elif isinstance(default, int):
            lo, hi = SETTING_RANGES.get(key, (0, 1000))
            out[key] = s.integer(key, lo, hi, odd=key == "kernel_size")
        elif isinstance(default, float):
            out[key] = s.number(key, 0.0)
        elif isinstance(default, tuple):
            out[key] = s.texts(key, GUIDE_FEATURES, unique=True)
        else:
            out[key] = s.text(key)
    return out


class KalantariNet(nn.Module):
    """Per-pixel MLP: ``(B, F, H, W)`` normalised features -> ``(B, O, H, W)`` log-offsets."""

    def __init__(self, n_in: int, hidden: Sequence[int], n_out: int, bound: float = BOUND) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        c = n_in
        for h in hidden:
            layers += [nn.Conv2d(c, h, 1), nn.ReLU()]
            c = h
        last = nn.Conv2d(c, n_out, 1)
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)
        self.body = nn.Sequential(*layers, last)
        self.bound = bound

    def forward(self, z: Tensor) -> Tensor:
        raw = self.body(z)  # (B, O, H, W)
        return self.bound * torch.tanh(raw / self.bound)


class KalantariModel(CardModule):
    """Features -> MLP -> per-pixel bandwidths -> classical filter.

    Args:
        card: the model card (kind, guides, feature statistics, hidden sizes, settings).
    """

    card_class = ModelCard

    @classmethod
    def from_card(cls, card: ModelCard, path: Path) -> KalantariModel:
        """The model of ``card``; a feature set that differs from what this version computes
        is an InputError naming ``path`` (the message names the difference)."""
        try:
            return cls(card)
        except InputError as err:
            raise InputError(f"{path}: {err}") from None

    def __init__(self, card: ModelCard) -> None:
        super().__init__()
        self.card = card
        self.settings = card.filter_settings()
        expected = feature_names(card.guides, card.guide_vars, card.regional)
        check_feature_names(card.features.names, expected, "model file", f"mcdenoise {__version__}")
        self.net = KalantariNet(len(expected), card.hidden, len(card.outputs), card.bound)

    # --- sizes ------------------------------------------------------------------------------
    @property
    def radius(self) -> int:
        """Pixels of context a filtered pixel depends on (the training crop margin)."""
        return filter_radius(self.settings)

    # --- forward -------------------------------------------------------------------------
    def offsets(self, features: Tensor) -> Tensor:
        """Log-offsets ``(B, O, H, W)`` from raw features ``(B, F, H, W)``."""
        return self.net(self.card.features.normalize(features))

    def filter(self, batch: Mapping[str, Tensor], offsets: Tensor | None = None) -> Tensor:
        """Filtered, remodulated colour ``(B, 3, H, W)`` (linear HDR, >= 0) of a prepared batch.

        Args:
            batch: ``prep/kalantari.py``'s ``prepare_for_model`` output stacked to
                ``(B, C, H, W)``.
            offsets: log-offsets to use instead of the network's (zeros: the fixed filter).
        """
        o = self.offsets(batch["features"]) if offsets is None else offsets
        s = self.settings
        guides = self.card.guides
        with_var = [g for g in guides if f"fvar.{g}" in batch]
        base, floors = feature_bandwidths(s, guides, with_var)
        feats = {g: batch[f"feat.{g}"] for g in guides}
        fvars = {g: batch.get(f"fvar.{g}") for g in guides}
        head = 2 if self.card.kind == "xbf" else 1
        sig = {g: base[g] * torch.exp(o[:, head + i : head + i + 1]) for i, g in enumerate(guides)}
        irr, var = batch["irr"], batch["irr_var"]
        if self.card.kind == "xbf":
            assert isinstance(s, XbfSettings)
            common = {
                "kernel_size": s.kernel_size,
                "sigma_features": sig,
                "color_var": var,
                "var_pair": s.var_pair,
                "feature_vars": fvars,
                "feature_floor": floors,
                "feature_gradient": s.feature_gradient,
            }
            out = cross_bilateral(
                irr,
                feats or None,
                sigma_spatial=s.sigma_spatial * torch.exp(o[:, 0:1]),
                sigma_color=s.sigma_color * torch.exp(o[:, 1:2]),
                **common,  # type: ignore[arg-type]
            )
            if s.passes == 2:  # as denoise_xbf: colour distances on the first pass's result
                n = len(self.card.outputs)
                out = cross_bilateral(
                    irr,
                    feats or None,
                    sigma_spatial=s.sigma_spatial * torch.exp(o[:, n - 2 : n - 1]),
                    sigma_color=s.sigma_color_refine * torch.exp(o[:, n - 1 : n]),
                    guide=out,
                    **common,  # type: ignore[arg-type]
                )
        else:
            assert isinstance(s, NlmSettings)
            out = non_local_means(
                irr,
                search_radius=s.search_radius,
                patch_radius=s.patch_radius,
                k=s.k * torch.exp(o[:, 0:1]),
                alpha=s.alpha,
                color_var=var,
                var_pair=s.var_pair,  # type: ignore[arg-type]
                features=feats or None,
                feature_k=sig,
                feature_vars=fvars,
                feature_floor=floors,
                feature_gradient=s.feature_gradient,
                combine=s.combine,  # type: ignore[arg-type]
            )
        return (out * batch["factor"]).clamp_min(0.0)

    def forward(self, batch: Mapping[str, Tensor], offsets: Tensor | None = None) -> Tensor:
        """:meth:`filter` (so a training loop can call the module, e.g. through DDP)."""
        return self.filter(batch, offsets)

    @torch.no_grad()
    def banded_offsets(
        self, features: Callable[[int, int], Tensor], height: int, chunk_rows: int = 256
    ) -> Tensor:
        """The log-offsets ``(1, O, H, W)`` of an image of ``height`` rows whose raw features
        ``features(y0, y1)`` gives ``chunk_rows`` rows at a time; the MLP's temporaries
        (normalised copies, hidden layers) exist for 32 rows at a time. The result does not
        depend on either."""
        rows = []
        for y in range(0, height, chunk_rows):
            band = features(y, min(y + chunk_rows, height))
            rows += [self.offsets(band[..., i : i + 32, :]) for i in range(0, band.shape[-2], 32)]
            del band
        return torch.cat(rows, dim=-2)

    def denoise_item(
        self,
        item: Mapping[str, Tensor],
        *,
        chunk_rows: int = 256,
        features: Callable[[int, int], Tensor] | None = None,
    ) -> Tensor:
        """Denoise one prepared image ``{name: (C, H, W)}``; returns ``(3, H, W)`` float32
        linear HDR colour (finite, >= 0).

        Features are made ``chunk_rows`` rows at a time and the MLP runs on 32 rows at a time (the
        result does not depend on either).
        ``features(y0, y1)`` gives the raw features ``(1, F, y1 - y0, W)`` of rows ``[y0, y1)``
        (``prep/kalantari.py``'s ``item_features``) for an item without ``features``, so no
        ``F × H × W`` tensor exists. The chunks run one after the other, in this thread: on
        worker threads their memory stayed with the workers' allocator arenas, and a 4K frame
        peaked at 8.4 GB instead of ``docs/results/kalantari.md``'s figure.
        """
        batch = {k: v[None] for k, v in item.items() if k != "features"}
        h = batch["irr"].shape[-2]
        if features is None:
            feats = item["features"][None]

            def features(y0: int, y1: int) -> Tensor:
                return feats[..., y0:y1, :]

        out = self.filter(batch, self.banded_offsets(features, h, chunk_rows))
        return torch.nan_to_num(out[0], nan=0.0, posinf=0.0, neginf=0.0).float()


def new_model(
    kind: str,
    guides: Sequence[str],
    guide_vars: Sequence[str],
    stats: FeatureStats,
    hidden: Sequence[int],
    settings: Mapping[str, Any] | None = None,
) -> KalantariModel:
    """An untrained model (= the fixed filter) for a guide set and feature statistics."""
    cls = settings_class(kind)
    if kind == "xbf" and int(dict(settings or {}).get("passes", 1)) not in (1, 2):
        raise InputError("a learned cross-bilateral filter has 1 or 2 passes")
    base = dataclasses.asdict(cls(**dict(settings or {})))
    base = {k: (list(v) if isinstance(v, tuple) else v) for k, v in base.items()}
    card = ModelCard(
        kind,
        [g for g in GUIDE_FEATURES if g in guides],
        list(guide_vars),
        stats,
        list(hidden),
        base,
    )
    return KalantariModel(card)


__all__ = [
    "BOUND",
    "FORMAT",
    "KINDS",
    "SETTING_RANGES",
    "KalantariModel",
    "KalantariNet",
    "ModelCard",
    "card_settings",
    "new_model",
    "output_names",
    "settings_class",
]
