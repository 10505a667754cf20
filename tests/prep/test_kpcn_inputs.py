"""The kpcn network's inputs from buffers (mcdenoise.prep.kpcn): source choice, prepared tensors."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers
from mcdenoise.io.buffers import MissingFeatureError
from mcdenoise.models.encoders import SOURCES
from mcdenoise.prep.kpcn import (
    EXPOSURE_QUANTILE,
    EXPOSURE_RANGE,
    PREPARED,
    choose_source,
    exposure_scale,
    prepare_tensors,
    scale_exposure,
    source_for,
)

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"
ALL = list(SOURCES)  # full, basic, color
FULL_BUFFERS = set(SOURCES["full"])


@pytest.mark.parametrize(
    ("present", "trained", "want"),
    [
        (FULL_BUFFERS, ALL, "full"),
        (FULL_BUFFERS | {"albedo_var", "diffuse"}, ALL, "full"),
        ({"color", "albedo", "normal"}, ALL, "basic"),
        (FULL_BUFFERS - {"color_var"}, ALL, "basic"),  # no variance: not the full source
        ({"color", "albedo"}, ALL, "color"),
        ({"color"}, ALL, "color"),
        (FULL_BUFFERS, ["basic", "color"], "basic"),  # only among the trained sources
        (FULL_BUFFERS, ["color"], "color"),
        ({"color", "albedo"}, ["full", "basic"], None),
        ({"albedo", "normal"}, ALL, None),
    ],
)
def test_choose_source(present, trained, want) -> None:
    assert choose_source(present, trained) == want
    assert choose_source(sorted(present), trained) == want  # any sequence of names


def test_source_for_names_the_missing_buffers() -> None:
    b = load_buffers(SAMPLES / "cornell_spp4.exr")
    assert source_for(b, ALL) == "full"
    assert source_for(b.subset(["color", "albedo", "normal"]), ["full", "basic"]) == "basic"
    with pytest.raises(MissingFeatureError, match="normal"):
        source_for(b.subset(["color", "albedo"]), ["full", "basic"])


@pytest.mark.parametrize("source", ALL)
def test_prepared_tensors_have_the_documented_channels(source) -> None:
    b = load_buffers(SAMPLES / "cornell_spp4.exr")
    t = prepare_tensors(b, source)
    assert set(SOURCES[source]) <= set(t) | {"color_var"}
    for name, v in t.items():
        assert v.shape == (PREPARED[name], *b.shape) and bool(torch.isfinite(v).all()), name


def test_prefilter_modes_touch_only_the_features_they_name() -> None:
    b = load_buffers(SAMPLES / "cornell_spp4.exr")
    full_off = prepare_tensors(b, "full", "off")
    # auto: a render with feature variances is left as it is (the full source sees them)
    for name, v in prepare_tensors(b, "full", "auto").items():
        assert torch.equal(v, full_off[name]), name
    # all: the features with a variance are prefiltered too
    full_all = prepare_tensors(b, "full", "all")
    assert not torch.equal(full_all["albedo"], full_off["albedo"])
    assert torch.equal(full_all["color"], full_off["color"])
    # basic (no variances): auto prefilters albedo and normal with an estimated variance
    basic = b.subset(["color", "albedo", "normal"])
    off, auto = prepare_tensors(basic, "basic", "off"), prepare_tensors(basic, "basic", "auto")
    assert torch.equal(off["albedo"], basic["albedo"])
    for name in ("albedo", "normal"):
        assert not torch.equal(auto[name], off[name]), name
        assert float((auto[name] - off[name]).abs().mean()) < 0.05, name
    assert torch.equal(auto["color"], off["color"])
    # adaptive (the default): the same as all where every feature has its variance buffer
    for name, v in prepare_tensors(b, "full").items():
        assert torch.equal(v, full_all[name]), name
    # and its own prefilter of the features without one (prep/aux_prefilter.py)
    adaptive = prepare_tensors(basic, "basic")
    assert not torch.equal(adaptive["albedo"], auto["albedo"])
    assert torch.equal(adaptive["color"], off["color"])
    with pytest.raises(InputError, match="prefilter must be one of adaptive, auto, all, off"):
        prepare_tensors(basic, "basic", "on")


def test_exposure_scale_brings_the_level_into_the_range_only_when_outside() -> None:
    lo, hi = EXPOSURE_RANGE
    g = torch.Generator().manual_seed(0)
    base = torch.rand(3, 40, 50, generator=g)
    level = float(torch.quantile(base.mean(0).flatten(), EXPOSURE_QUANTILE))
    inside = base * (0.5 * (lo + hi) / level)
    assert exposure_scale(inside) == 1.0
    dark, bright = base * (0.1 * lo / level), base * (10 * hi / level)
    assert exposure_scale(dark) == pytest.approx(10.0, rel=1e-4)
    assert exposure_scale(bright) == pytest.approx(0.1, rel=1e-4)
    assert exposure_scale(torch.zeros(3, 8, 8)) == 1.0  # black: nothing to scale
    t = {"color": dark, "color_var": dark[:1] * 0 + 2.0, "albedo": base}
    s = scale_exposure(t, 10.0)
    torch.testing.assert_close(s["color"], dark * 10)
    torch.testing.assert_close(s["color_var"], t["color_var"] * 100)
    assert s["albedo"] is base
