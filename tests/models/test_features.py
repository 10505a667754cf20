"""Per-pixel features: names, shapes, normalisation, feature-set checks."""

from __future__ import annotations

import math

import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.filters.prepare import _demodulate, prepare_inputs
from mcdenoise.io import load_buffers
from mcdenoise.models.features import (
    CLAMP,
    FeatureStats,
    check_feature_names,
    compute_features,
    feature_names,
)


def test_features_of_a_render_match_their_names_and_are_finite(samples_dir) -> None:
    b = load_buffers(samples_dir / "cornell_spp4.exr")
    inp = prepare_inputs(b)
    irr, var, _ = _demodulate(inp, True, 1e-2)
    feats, names = compute_features(inp, irr, var, b.spp)
    assert feats.shape == (1, len(names), *b.shape)
    assert names == feature_names(["albedo", "normal", "depth", "position"], list(inp.feature_vars))
    assert bool(torch.isfinite(feats).all())
    i = names.index("spp")
    assert float(feats[0, i].mean()) == pytest.approx(math.log2(4))
    # local std of the noisy log-luminance grows with the window less than the noise falls
    assert float(feats[0, names.index("lum.std.3")].mean()) > 0


def test_regional_features_are_63px_means_appended_last(samples_dir) -> None:
    b = load_buffers(samples_dir / "cornell_spp4.exr")
    inp = prepare_inputs(b)
    irr, var, _ = _demodulate(inp, True, 1e-2)
    plain, names = compute_features(inp, irr, var, b.spp)
    feats, rnames = compute_features(inp, irr, var, b.spp, regional=True)
    guides = ["albedo", "normal", "depth", "position"]
    assert rnames == feature_names(guides, list(inp.feature_vars), regional=True)
    assert rnames[: len(names)] == names and torch.equal(feats[:, : len(names)], plain)
    assert rnames[len(names) :] == [
        "region.relvar", "region.lum.std", "region.lum.grad",
        *[f"region.{g}.grad" for g in guides],
    ]  # fmt: skip
    # one pixel by hand: the mean of its pixel's relvar over the in-image part of 63 x 63
    relvar = plain[0, names.index("color.relvar")]
    y, x = 10, 100
    window = relvar[max(0, y - 31) : y + 32, max(0, x - 31) : x + 32]
    got = feats[0, rnames.index("region.relvar"), y, x]
    assert float(got) == pytest.approx(float(window.mean()), rel=1e-4)
    assert bool(torch.isfinite(feats).all())


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
