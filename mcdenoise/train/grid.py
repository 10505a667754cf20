"""Grid search of the fixed-parameter filters: the fair baseline for the learned ones.

"What does learning buy" is only meaningful against the *best* fixed parameters, found on the
same training data the learned model saw. :func:`grid_search` runs the cross-bilateral or
NLM filter with every combination of a compact grid over its main bandwidths on prepared
training images (:func:`mcdenoise.prep.kalantari.prepare_item`, the same preparation as the
learned models) and picks, **per spp level**, the combination with the lowest geometric-mean
relMSE. (Per level, because the learned model knows the spp; one setting for all levels
would be a weaker baseline.)
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch

from mcdenoise.filters.settings import GUIDE_FEATURES
from mcdenoise.geomean import geometric_mean
from mcdenoise.models.features import FeatureStats, feature_names
from mcdenoise.models.kalantari import new_model
from mcdenoise.progress import Mode, progress_bar
from mcdenoise.train.patches import Item, image_relmse

#: Default grids: the main bandwidths of each filter (values around the tuned defaults).
GRIDS: dict[str, dict[str, list[Any]]] = {
    "xbf": {
        "sigma_spatial": [4.0, 8.0, 16.0],
        "sigma_color": [1.0, 2.0, 4.0, 8.0],
        "feature_scale": [0.5, 1.0, 2.0],
    },
    "nlm": {
        "k": [0.25, 0.45, 0.8, 1.4],
        "feature_scale": [0.5, 1.0, 2.0],
    },
    # two-pass cross-bilateral (the baseline of a two-pass learned model)
    "xbf2": {
        "passes": [2],
        "sigma_spatial": [2.0, 3.0, 4.0, 8.0],
        "sigma_color": [2.0, 4.0, 8.0],
        "sigma_color_refine": [0.125, 0.25, 0.5, 1.0],
    },
}


@dataclass
class GridResult:
    """Per spp level: the best settings and their geometric-mean relMSE; every trial too."""

    kind: str
    grid: dict[str, list[Any]]
    best: dict[int, dict[str, Any]] = field(default_factory=dict)
    best_error: dict[int, float] = field(default_factory=dict)
    trials: list[dict[str, Any]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "grid": self.grid,
            "best": {str(k): v for k, v in self.best.items()},
            "best_error": {str(k): v for k, v in self.best_error.items()},
            "trials": self.trials,
        }

    @staticmethod
    def from_dict(d: Mapping[str, Any]) -> GridResult:
        return GridResult(
            kind=d["kind"],
            grid=dict(d["grid"]),
            best={int(k): dict(v) for k, v in d["best"].items()},
            best_error={int(k): float(v) for k, v in d["best_error"].items()},
            trials=list(d.get("trials", [])),
        )


def grid_search(
    kind: str,
    items: Sequence[Item],
    grid: Mapping[str, Sequence[Any]] | None = None,
    *,
    progress: Mode = False,
) -> GridResult:
    """Evaluate every grid point on every item; the best per spp level.

    Args:
        kind: ``"xbf"``, ``"nlm"`` or ``"xbf2"`` (two-pass cross-bilateral grid).
        items: prepared whole images (from :func:`~mcdenoise.train.patches.load_items` with
            :func:`~mcdenoise.prep.kalantari.prepare_item`), with ``reference``.
        grid: setting name -> values (default :data:`GRIDS`).
        progress: report the search on stderr (:func:`mcdenoise.progress.progress_bar`: a
            bar on a terminal, a line per stage in a log).
    """
    grid = {k: list(v) for k, v in (grid or GRIDS[kind]).items()}
    kind = "xbf" if kind == "xbf2" else kind
    keys = list(grid)
    guides = [g for g in GUIDE_FEATURES if f"feat.{g}" in items[0].tensors]
    with_var = [g for g in guides if f"fvar.{g}" in items[0].tensors]
    names = feature_names(guides, with_var)
    stats = FeatureStats(names, [0.0] * len(names), [1.0] * len(names))
    result = GridResult(kind, grid)
    levels = sorted({it.entry.spp or 0 for it in items})
    combos = list(itertools.product(*(grid[k] for k in keys)))
    bar = progress_bar(combos, desc=f"grid {kind}", unit="setting", progress=progress, leave=False)
    for values in bar:
        settings = dict(zip(keys, values, strict=True))
        model = new_model(kind, guides, with_var, stats, [1], settings)
        errs: dict[int, list[float]] = {lv: [] for lv in levels}
        with torch.no_grad():
            for it in items:
                b = {k: v[None] for k, v in it.tensors.items()}
                zeros = torch.zeros((1, len(model.card.outputs), *it.size))
                errs[it.entry.spp or 0].append(
                    image_relmse(model.filter(b, zeros)[0], it.tensors["reference"])
                )
        for lv in levels:
            g = geometric_mean(errs[lv])
            result.trials.append({"spp": lv, **settings, "geomean_relmse": g})
            if g < result.best_error.get(lv, math.inf):
                result.best_error[lv], result.best[lv] = g, settings
    return result
