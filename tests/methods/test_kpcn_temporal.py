"""The kpcn-temporal method over sequences: one frame, order, history, bad sequences."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers
from mcdenoise.io.buffers import FeatureBuffers, MissingFeatureError
from mcdenoise.methods.kpcn import denoise_kpcn
from mcdenoise.methods.kpcn_temporal import denoise_kpcn_temporal_sequence
from mcdenoise.models.encoders import channel_names, source_channels
from mcdenoise.models.features import FeatureStats
from mcdenoise.models.kpcn import KpcnModel, new_model
from mcdenoise.models.kpcn_temporal import from_single_frame
from mcdenoise.models.weights import load_kpcn, shipped_model_path
from mcdenoise.prep.kpcn import prepare_tensors

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"
ONE_THREAD = True


@pytest.fixture(scope="module")
def cornell() -> FeatureBuffers:
    """A 32×32 crop of the Cornell box at 4 spp."""
    return load_buffers(SAMPLES / "cornell_spp4.exr").crop(40, 40, 32, 32)


@pytest.fixture(scope="module")
def reference() -> torch.Tensor:
    return load_buffers(SAMPLES / "ref" / "cornell.exr").crop(40, 40, 32, 32).get("color")


@pytest.fixture(scope="module")
def tiny(cornell) -> KpcnModel:
    t = {k: v[None] for k, v in prepare_tensors(cornell, "full").items()}
    stats = {"full": FeatureStats.from_samples(channel_names("full"), [source_channels("full", t)])}
    torch.manual_seed(0)
    return new_model(["full"], stats, channels=(8, 8, 8), kernel=3, scales=3).eval()


def _static(cornell: FeatureBuffers, ref: torch.Tensor, n: int, seed: int = 0):
    """``n`` frames of a static scene: the reference with independent noise per frame (30 %
    relative, its variance in color_var), the 4-spp features, zero motion, all valid."""
    g = torch.Generator().manual_seed(seed)
    h, w = cornell.shape
    out = []
    for i in range(n):
        noise = torch.randn(ref.shape, generator=g)
        b = FeatureBuffers({k: v.clone() for k, v in cornell.buffers.items()})
        b["color"] = (ref * (1 + 0.3 * noise)).clamp_min(0)
        b["color_var"] = (0.3 * ref).square()
        b["motion"] = torch.zeros(2, h, w)
        b["motion_valid"] = torch.full((1, h, w), float(i > 0))
        b["motion_next"] = torch.zeros(2, h, w)
        b["motion_next_valid"] = torch.full((1, h, w), float(i < n - 1))
        out.append(b)
    return out


def _relmse(o: torch.Tensor, r: torch.Tensor) -> float:
    return float(((o - r) ** 2 / (r**2 + 0.01)).mean())


def test_one_frame_sequence_is_the_single_frame_kpcn(cornell, tiny) -> None:
    model = from_single_frame(tiny, window=5).eval()
    out = list(denoise_kpcn_temporal_sequence(model, [cornell]))
    assert len(out) == 1
    assert torch.equal(out[0], denoise_kpcn(tiny, cornell))


def test_offline_window_yields_every_frame_in_order(cornell, reference, tiny) -> None:
    model = from_single_frame(tiny, window=5, mode="offline").eval()
    frames = _static(cornell, reference, 4)
    outs = list(denoise_kpcn_temporal_sequence(model, frames, prefilter="off"))
    causal = list(
        denoise_kpcn_temporal_sequence(model, frames, window=3, mode="causal", prefilter="off")
    )
    assert len(outs) == 4 and len(causal) == 4
    assert all(o.shape == (3, 32, 32) and torch.isfinite(o).all() for o in outs + causal)
    # the causal frame 0 sees no other frame: the single-frame result
    assert torch.equal(causal[0], denoise_kpcn(tiny, frames[0], prefilter="off"))


def test_static_scene_error_falls_as_frames_accumulate(cornell, reference) -> None:
    """Independent noise per frame: the more past frames the causal window holds, the lower
    the error (the shipped single-frame kpcn inside the temporal model)."""
    path = shipped_model_path("kpcn")
    if not path.is_file():
        pytest.skip("no shipped kpcn weights")
    model = from_single_frame(load_kpcn(path), window=5, mode="causal").eval()
    frames = _static(cornell, reference, 5)
    outs = list(denoise_kpcn_temporal_sequence(model, frames, prefilter="off"))
    err = [_relmse(o, reference) for o in outs]
    assert err[4] < 0.85 * err[0], err
    assert err[2] < err[0] and err[4] < err[1], err


def test_frames_of_different_sizes_are_refused(cornell, tiny) -> None:
    model = from_single_frame(tiny, window=3).eval()
    small = cornell.crop(0, 0, 16, 24)
    with pytest.raises(InputError, match="every frame of a sequence must have one size"):
        list(denoise_kpcn_temporal_sequence(model, [cornell, small, cornell]))


def test_a_frame_without_the_source_buffers_is_refused(cornell, tiny) -> None:
    model = from_single_frame(tiny, window=3).eval()
    bare = cornell.subset(["color", "normal"])
    with pytest.raises(MissingFeatureError, match="albedo"):
        list(denoise_kpcn_temporal_sequence(model, [cornell, bare]))
