"""The kpcn method's ``prefilter`` parameter (issue 21): noisy albedo / normal without a
variance buffer are prefiltered by default; ``off`` keeps the old behaviour; a bad value is one
clear error."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mcdenoise.denoise import denoise
from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers
from mcdenoise.methods.kpcn import METHOD
from mcdenoise.models.weights import shipped_model_path

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"

pytestmark = pytest.mark.skipif(
    not shipped_model_path("kpcn").is_file(), reason="no shipped kpcn weights"
)

#: one intra-op thread for this module (tests/conftest.py)
ONE_THREAD = True


def test_prefilter_defaults_to_auto_and_changes_only_inputs_without_variances() -> None:
    assert METHOD.defaults["prefilter"] == "auto"
    b = load_buffers(SAMPLES / "cornell_spp4.exr").crop(0, 0, 64, 64)
    basic = b.subset(["color", "albedo", "normal"])
    auto = denoise(basic, "kpcn").image
    off = denoise(basic, "kpcn", params={"prefilter": "off"}).image
    assert not torch.equal(auto, off)
    # a render with feature variances (full source): auto leaves its features as they are
    full_auto = denoise(b, "kpcn").image
    full_off = denoise(b, "kpcn", params={"prefilter": "off"}).image
    assert torch.equal(full_auto, full_off)


def test_a_bad_prefilter_value_is_one_clear_error() -> None:
    b = load_buffers(SAMPLES / "cornell_spp4.exr").crop(0, 0, 32, 32)
    with pytest.raises(InputError, match="prefilter must be one of auto, all, off"):
        denoise(b, "kpcn", params={"prefilter": "yes"})
