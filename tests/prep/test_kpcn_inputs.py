"""The kpcn network's inputs from buffers (mcdenoise.prep.kpcn): source choice, prepared tensors."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mcdenoise.io import load_buffers
from mcdenoise.io.buffers import MissingFeatureError
from mcdenoise.models.encoders import SOURCES
from mcdenoise.prep.kpcn import PREPARED, choose_source, prepare_tensors, source_for

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
