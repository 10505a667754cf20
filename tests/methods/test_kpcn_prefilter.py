"""The kpcn method's ``prefilter`` and ``exposure`` parameters (issue 21): noisy albedo /
normal without a variance buffer are prefiltered by default, an input darker or brighter than
the training renders is scaled into their range; ``off`` keeps the old behaviour; a bad value
is one clear error."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mcdenoise.denoise import denoise
from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.methods.kpcn import METHOD
from mcdenoise.models.weights import shipped_model_path

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"

pytestmark = pytest.mark.skipif(
    not shipped_model_path("kpcn").is_file(), reason="no shipped kpcn weights"
)

#: one intra-op thread for this module (tests/conftest.py)
ONE_THREAD = True


def test_prefilter_defaults_to_adaptive_which_changes_only_inputs_without_variances() -> None:
    assert METHOD.defaults["prefilter"] == "adaptive"
    b = load_buffers(SAMPLES / "cornell_spp4.exr").crop(0, 0, 64, 64)
    basic = b.subset(["color", "albedo", "normal"])
    auto = denoise(basic, "kpcn", params={"prefilter": "auto"}).image
    off = denoise(basic, "kpcn", params={"prefilter": "off"}).image
    assert not torch.equal(auto, off)
    # without variances there is nothing for `auto` to leave out: `all` is the same
    assert torch.equal(denoise(basic, "kpcn", params={"prefilter": "all"}).image, auto)
    # the default prefilters them its own way (uncapped where pixels mix surfaces)
    assert not torch.equal(denoise(basic, "kpcn").image, auto)
    # a render with feature variances (full source): auto leaves its features as they are,
    # all prefilters them too, and the default is all there, bit for bit (the held-out and
    # golden figures of full renders do not move)
    full_auto = denoise(b, "kpcn", params={"prefilter": "auto"}).image
    full_off = denoise(b, "kpcn", params={"prefilter": "off"}).image
    full_all = denoise(b, "kpcn", params={"prefilter": "all"}).image
    assert torch.equal(full_auto, full_off)
    assert not torch.equal(full_all, full_off)
    assert torch.equal(denoise(b, "kpcn").image, full_all)


def test_a_bad_prefilter_or_exposure_value_is_one_clear_error() -> None:
    b = load_buffers(SAMPLES / "cornell_spp4.exr").crop(0, 0, 32, 32)
    with pytest.raises(InputError, match="prefilter must be one of adaptive, auto, all, off"):
        denoise(b, "kpcn", params={"prefilter": "yes"})
    with pytest.raises(InputError, match="exposure must be one of auto, off"):
        denoise(b, "kpcn", params={"exposure": "on"})


def test_exposure_auto_makes_a_dark_or_bright_input_scale_invariant() -> None:
    b = load_buffers(SAMPLES / "cornell_spp4.exr").crop(32, 32, 64, 64)
    basic = b.subset(["color", "albedo", "normal"])

    def run(scale: float, exposure: str = "auto") -> torch.Tensor:
        x = FeatureBuffers({**basic.buffers, "color": basic["color"] * scale}, spp=basic.spp)
        return denoise(x, "kpcn", params={"exposure": exposure}).image / scale

    # far below and far above the range: both are brought to the same end of it
    torch.testing.assert_close(run(1e-3), run(2e-3), rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(run(1e3), run(5e2), rtol=1e-4, atol=1e-6)
    # with exposure off the network sees the scale (what the normalisation removes)
    assert not torch.allclose(run(1e3, "off"), run(5e2, "off"), rtol=1e-2, atol=1e-6)
