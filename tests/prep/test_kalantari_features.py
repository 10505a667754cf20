"""Per-pixel features of the Kalantari models (mcdenoise.prep.kalantari): names, shapes, the
regional means."""

from __future__ import annotations

import math

import pytest
import torch

from mcdenoise.io import load_buffers
from mcdenoise.models.features import feature_names
from mcdenoise.prep.inputs import demodulate_inputs, prepare_inputs
from mcdenoise.prep.kalantari import compute_features


def test_features_of_a_render_match_their_names_and_are_finite(samples_dir) -> None:
    b = load_buffers(samples_dir / "cornell_spp4.exr")
    inp = prepare_inputs(b)
    irr, var, _ = demodulate_inputs(inp, eps=1e-2)
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
    irr, var, _ = demodulate_inputs(inp, eps=1e-2)
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
