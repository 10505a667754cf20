"""The Kalantari model's feature names and normalisation: statistics, clamping, set checks."""

from __future__ import annotations

import math

import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.models.features import CLAMP, FeatureStats, check_feature_names, feature_names


def test_unknown_spp_becomes_the_training_mean() -> None:
    feats = torch.randn(1, 3, 4, 4)
    feats[:, 2] = math.nan
    stats = FeatureStats(["a", "b", "spp"], [0.0, 0.0, 4.0], [1.0, 1.0, 1.0])
    z = stats.normalize(feats)
    assert bool((z[:, 2] == 0).all()) and bool(torch.isfinite(z).all())
    huge = stats.normalize(torch.full((1, 3, 2, 2), 1e30))
    assert float(huge.max()) == CLAMP


def test_stats_ignore_nan_and_floor_the_std() -> None:
    a = torch.stack([torch.arange(16.0).view(4, 4), torch.full((4, 4), math.nan)])[None]
    s = FeatureStats.from_samples(["x", "spp"], [a])
    assert s.mean[0] == pytest.approx(7.5) and s.mean[1] == 0.0 and s.std[1] == pytest.approx(1e-6)
    assert FeatureStats.from_dict(s.to_dict()) == s


def test_feature_set_differences_are_named() -> None:
    full = feature_names(["albedo", "normal", "depth", "position"], ["albedo"])
    no_albedo = feature_names(["normal", "depth", "position"])
    check_feature_names(full, list(full), "m")
    with pytest.raises(InputError) as err:
        check_feature_names(full, no_albedo, "model.pt")
    msg = str(err.value)
    assert "uses albedo.*, albedo.std.*, which the input lacks" in msg and "model.pt" in msg
    with pytest.raises(InputError, match="order"):
        check_feature_names(["a", "b"], ["b", "a"], "m")
