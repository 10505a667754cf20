"""Issue 37: the temporal module's noise inputs and the recurrent source (the previous output
warped to frame t)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mcdenoise.io import load_buffers
from mcdenoise.modelfile import read_card
from mcdenoise.models.encoders import channel_names, source_channels
from mcdenoise.models.features import FeatureStats
from mcdenoise.models.kpcn import KpcnModel, new_model
from mcdenoise.models.kpcn_temporal import TemporalCard, TemporalKpcn, from_single_frame
from mcdenoise.models.temporal_modules import RECURRENT_BIAS, clamp_history, noise_inputs
from mcdenoise.prep.kpcn import prepare_tensors

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"
WEIGHTS = Path(__file__).resolve().parents[2] / "mcdenoise" / "models" / "weights"
ONE_THREAD = True


@pytest.fixture(scope="module")
def crop() -> dict[str, torch.Tensor]:
    t = prepare_tensors(load_buffers(SAMPLES / "cornell_spp4.exr"), "full")
    return {k: v[None, :, 40:72, 40:72].contiguous() for k, v in t.items()}


@pytest.fixture(scope="module")
def base(crop) -> KpcnModel:
    stats = {
        "full": FeatureStats.from_samples(channel_names("full"), [source_channels("full", crop)])
    }
    torch.manual_seed(0)
    return new_model(["full"], stats, channels=(8, 8, 8), kernel=3, scales=3).eval()


def _noisy(crop, seed: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    t = dict(crop)
    t["color"] = crop["color"] * (1 + 0.3 * torch.randn(crop["color"].shape, generator=g)).abs()
    return t


def _recurrent(base: KpcnModel, window: int = 2) -> TemporalKpcn:
    torch.manual_seed(2)
    m = from_single_frame(
        base, window=window, mode="causal", hidden=[4, 4, 4], inputs=2, recurrent=True
    ).eval()
    with torch.no_grad():  # away from the zero start, so every input matters
        for mixer in m.mixers:
            mixer.out.weight.normal_(0, 0.3)
        assert m.recurrence is not None
        m.recurrence.out.weight.normal_(0, 0.3)
    return m


def test_noise_inputs_are_zero_where_frames_agree_and_large_at_a_disocclusion() -> None:
    g = torch.Generator().manual_seed(0)
    clean = 0.5 + 0.2 * torch.rand(1, 3, 16, 16, generator=g)
    var = torch.full_like(clean, 0.01)
    a = clean + 0.1 * torch.randn(clean.shape, generator=g)
    b = clean + 0.1 * torch.randn(clean.shape, generator=g)
    b[..., 4:10, 4:10] += 2.0  # another surface in the neighbour frame
    mask = torch.ones(1, 1, 16, 16)
    out = noise_inputs([b, a], [var, var], [mask, mask], centre=1)
    assert torch.count_nonzero(out[1]) == 0  # frame t's own inputs
    z = out[0][0, 0]
    assert float(z[5:9, 5:9].min()) > 4.0  # log1p of a difference of ~20 noise units squared
    assert float(z[12:, 12:].mean()) < 1.0  # agreement within the noise
    out = noise_inputs([b, a], [var, var], [torch.zeros_like(mask), mask], centre=1)
    assert torch.count_nonzero(out[0]) == 0  # an invalid pixel's inputs are 0


def test_recurrent_model_without_a_previous_output_is_the_window_model(base, crop) -> None:
    rec = _recurrent(base)
    plain = TemporalKpcn(TemporalCard(**{**rec.card.to_dict(), "recurrent": False}))
    plain.load_state_dict(
        {k: v for k, v in rec.state_dict().items() if not k.startswith("recurrence.")}
    )
    plain.eval()
    frames = [_noisy(crop, 1), _noisy(crop, 2)]
    masks = [torch.ones_like(crop["color"][:, :1])] * 2
    with torch.no_grad():
        a = rec.run(frames, masks, 1, "full")
        b = plain.run(frames, masks, 1, "full")
        # a previous output that is invalid everywhere (a cut) changes nothing either
        c = rec.run(
            frames,
            masks,
            1,
            "full",
            previous=torch.rand_like(a) * 100,
            previous_mask=torch.zeros_like(masks[0]),
        )
        # one frame and no previous output: the single-frame model, bit for bit
        d = rec.denoise_window(frames[1:], masks[1:], 0, "full")
    assert torch.equal(a, b) and torch.equal(a, c)
    assert torch.equal(d, base.denoise_tensors(frames[1], "full"))


def test_the_previous_output_is_blended_in_where_valid_and_clamped_to_frame_t(base, crop) -> None:
    m = from_single_frame(base, window=2, mode="causal", hidden=[4, 4, 4], recurrent=True).eval()
    frames = [_noisy(crop, 1), _noisy(crop, 2)]
    masks = [torch.ones_like(crop["color"][:, :1])] * 2
    prev_mask = torch.zeros_like(masks[0])
    prev_mask[..., :, :16] = 1.0
    with torch.no_grad():
        a = m.run(frames, masks, 1, "full")
        b = m.run(frames, masks, 1, "full", previous=a * 1.5, previous_mask=prev_mask)
        c = m.run(frames, masks, 1, "full", previous=a + 1e6, previous_mask=prev_mask)
    # the right half has no valid history: the same output there
    assert torch.equal(a[..., :, 17:], b[..., :, 17:])
    # the left half moves toward the (brighter) previous output, by about sigmoid(bias)
    beta = float(torch.sigmoid(torch.tensor(RECURRENT_BIAS)))
    gain = float(((b - a) / (0.5 * a + 1e-3))[..., 2:-2, 2:14].median())
    assert 0.3 * beta < gain < 1.5 * beta
    # a history far above anything frame t shows near it is clamped to frame t's 3×3 range
    assert bool(torch.isfinite(c).all())
    assert float(c.max()) <= max(float(a.max()), float(frames[1]["color"].max())) * 1.01


def test_clamp_history_to_the_noisy_neighbourhood() -> None:
    noisy = torch.zeros(1, 1, 5, 5)
    noisy[..., 2, 2] = 4.0
    prev = torch.full((1, 1, 5, 5), 10.0)
    out = clamp_history(prev, noisy)
    assert float(out[..., 2, 2]) == 4.0 and float(out[..., 1, 1]) == 4.0  # the bright pixel's 3×3
    assert float(out[..., 0, 0]) == 0.0  # nothing bright near a corner: clamped to 0
    assert torch.equal(clamp_history(noisy, noisy), noisy)  # frame t itself passes unchanged


def test_recurrent_card_round_trip_and_old_cards_still_load(base, tmp_path: Path) -> None:
    m = _recurrent(base)
    m.save(tmp_path / "r.pt")
    back = TemporalKpcn.load(tmp_path / "r.pt")
    assert back.card.recurrent and back.card.inputs == 2 and back.recurrence is not None
    card = read_card(WEIGHTS / "kpcn-temporal.pt")
    assert TemporalCard.from_dict(card).inputs in (1, 2)  # files written before the fields


def test_gradients_reach_the_recurrent_source(base, crop) -> None:
    m = _recurrent(base).train()
    frames = [_noisy(crop, 1), _noisy(crop, 2)]
    masks = [torch.ones_like(crop["color"][:, :1])] * 2
    prev = frames[0]["color"].clone().requires_grad_(True)
    out = m.run(frames, masks, 1, "full", previous=prev, previous_mask=masks[0])
    out.mean().backward()
    assert m.recurrence is not None
    assert float(m.recurrence.out.weight.grad.abs().sum()) > 0
    assert float(prev.grad.abs().sum()) > 0  # through time: the previous output's graph
