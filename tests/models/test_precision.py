"""The trunk's inference precision (``kpcn -p precision=auto|fp32|bf16``,
mcdenoise.models.precision): ``auto`` follows the device, bf16 runs the convolutions and
nothing else in bfloat16, and the shipped model's error on a sample moves by less than the
0.5 % the speed issue allows."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.eval.metrics import relmse
from mcdenoise.io import load_buffers
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.methods.kpcn import denoise_kpcn
from mcdenoise.models import precision as P
from mcdenoise.models.weights import load_kpcn, shipped_model_path

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"


def test_auto_is_bf16_exactly_where_the_device_has_it_natively(monkeypatch) -> None:
    assert P.resolve_precision("fp32", "cpu") == "fp32"
    assert P.resolve_precision("bf16", "cpu") == "bf16"
    monkeypatch.setattr(P, "native_bf16", lambda device: True)
    assert P.resolve_precision("auto", "cpu") == "bf16"
    monkeypatch.setattr(P, "native_bf16", lambda device: False)
    assert P.resolve_precision("auto", "cpu") == "fp32"


def test_an_unknown_precision_is_one_clear_error() -> None:
    with pytest.raises(InputError, match="precision must be one of auto, fp32, bf16"):
        P.resolve_precision("fp16", "cpu")


def test_fp32_is_the_untouched_path_and_runs_without_autocast() -> None:
    with P.trunk_autocast("fp32", "cpu"):
        assert not torch.is_autocast_enabled("cpu")
    with P.trunk_autocast("bf16", "cpu"):
        assert torch.is_autocast_enabled("cpu")
        assert torch.get_autocast_dtype("cpu") == torch.bfloat16


@pytest.fixture(scope="module")
def shipped():
    path = shipped_model_path("kpcn")
    if not path.is_file():
        pytest.skip("no shipped kpcn weights")
    return load_kpcn(path).eval()


@pytest.mark.parametrize("scene", ["cornell", "materials"])
def test_bf16_trunk_moves_the_shipped_models_error_by_under_half_a_percent(shipped, scene) -> None:
    noisy = load_buffers(SAMPLES / f"{scene}_spp4.exr")
    ref = load_buffers(SAMPLES / "ref" / f"{scene}.exr")["color"]
    basic = noisy.subset(["color", "albedo", "normal"])
    for b in (noisy, basic):
        fp32 = denoise_kpcn(shipped, b, precision="fp32")
        bf16 = denoise_kpcn(shipped, b, precision="bf16")
        assert bf16.dtype == torch.float32 and bool(torch.isfinite(bf16).all())
        assert not torch.equal(fp32, bf16)  # the trunk did run in bfloat16
        e32, e16 = relmse(fp32, ref), relmse(bf16, ref)
        assert abs(e16 / e32 - 1) < 0.005, (scene, e32, e16)
        # and the two images differ far less than either differs from the reference
        assert relmse(bf16, fp32) < 0.02 * e32


def test_the_kernels_and_compositor_stay_float32_under_bf16(shipped, kernel_dtypes) -> None:
    seen = kernel_dtypes
    conv: list[torch.dtype] = []
    hook = shipped.up[0].register_forward_hook(lambda m, i, o: conv.append(o.dtype))
    try:
        b: FeatureBuffers = load_buffers(SAMPLES / "cornell_spp4.exr").crop(0, 0, 40, 40)
        out = denoise_kpcn(shipped, b, precision="bf16")
    finally:
        hook.remove()
    assert set(conv) == {torch.bfloat16}
    assert seen and set(seen) == {(torch.float32, torch.float32)}
    assert out.dtype == torch.float32
