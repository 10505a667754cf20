"""Training the temporal kpcn: pair crops, the temporal loss, the frozen trunk."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers
from mcdenoise.losses import temporal_smape
from mcdenoise.models.encoders import channel_names, source_channels
from mcdenoise.models.features import FeatureStats
from mcdenoise.models.kpcn import new_model
from mcdenoise.models.kpcn_temporal import TemporalKpcn, from_single_frame
from mcdenoise.prep.kpcn import prepare_tensors
from mcdenoise.prep.kpcn_temporal import PreparedFrame, warp_window
from mcdenoise.train.config import load_config
from mcdenoise.train.kpcn_temporal import (
    PairSampler,
    Sequence_,
    TemporalTask,
    cache_features,
    find_sequences,
    motion_targets,
)

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"
ONE_THREAD = True


def test_temporal_smape_is_zero_without_flicker_and_positive_with_it() -> None:
    r0, r1 = torch.rand(1, 3, 4, 4), torch.rand(1, 3, 4, 4)
    assert float(temporal_smape(r1 + 0.5, r0 + 0.5, r1, r0)) == pytest.approx(0.0, abs=1e-6)
    flicker = r1 * (1 + 0.5 * torch.randn(1, 3, 4, 4))
    assert float(temporal_smape(flicker, r0, r1, r0)) > 0.05


def test_no_sequence_folder_is_one_line_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="holds no sequence"):
        find_sequences(str(tmp_path))


def _tiny(**kwargs) -> tuple[dict[str, torch.Tensor], TemporalKpcn]:
    """Prepared ``full`` tensors of a 32×32 Cornell crop and a small temporal model around an
    untrained kpcn (``kwargs``: :func:`from_single_frame`'s)."""
    b = load_buffers(SAMPLES / "cornell_spp4.exr").crop(40, 40, 32, 32)
    t = {k: v[None] for k, v in prepare_tensors(b, "full").items()}
    stats = {"full": FeatureStats.from_samples(channel_names("full"), [source_channels("full", t)])}
    torch.manual_seed(0)
    base = new_model(["full"], stats, channels=(8, 8, 8), kernel=3, scales=3)
    return t, from_single_frame(base, hidden=[4, 4, 4], **kwargs)


def test_pair_crops_and_a_frozen_trunk_step() -> None:
    t, model = _tiny(window=3)
    g = torch.Generator().manual_seed(0)
    frames = []
    for i in range(3):
        tt = dict(t)
        tt["color"] = t["color"] * (1 + 0.3 * torch.randn(t["color"].shape, generator=g)).abs()
        zero = torch.zeros_like(t["color"][:, :2])
        frames.append(
            PreparedFrame(tt, zero, torch.full_like(zero[:, :1], float(i > 0)), zero, None)
        )
    seq = Sequence_("s", refs=[t["color"]] * 3, frames=frames)
    motion_targets(seq)
    for i in range(3):
        tens, masks, _ = warp_window(frames, i, model.card.offsets, fill=True)
        seq.windows.append((tens, masks))
    for q in model.base.parameters():
        q.requires_grad_(False)
    model.training_trunk = False
    cache_features(model, [seq])
    sampler = PairSampler([seq], patch=16, margin=4, aug=True)
    batch = sampler.batch(2, torch.Generator().manual_seed(1))
    assert batch["color@1"].shape == (2, 3, 24, 24) and batch["p:color@1"].shape == (2, 3, 24, 24)
    assert batch["feat2@0"].shape[-1] == 6  # the coarsest scale's features, cropped with it
    # no flips or rotations of cached features: every crop is a plain window of the frame
    for crop in [*batch["color@1"], *batch["p:color@1"]]:
        assert any(
            torch.equal(crop, w[:, y : y + 24, x : x + 24])
            for w in [seq.windows[t][0][1]["color"][0] for t in range(3)]
            for y in range(9)
            for x in range(9)
        )
    cfg = load_config(None, {"model": "kpcn-temporal", "temporal_weight": "0.5"})
    task = TemporalTask(model, cfg, [seq])
    loss = task.loss(batch)
    assert torch.isfinite(loss)
    loss.backward()
    assert all(p.grad is None for p in model.base.parameters())
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in model.mixers.parameters())
    scores = task.validate()
    assert scores["val_loss"] > 0 and "val_trelmse_ratio_to_base" in scores


def test_recurrent_triples_with_motion_and_the_warped_temporal_term() -> None:
    """A recurrent model trains on three frames unrolled; the warped temporal loss is 0 for
    outputs that follow the reference's motion exactly and positive for flicker."""
    t, model = _tiny(window=2, mode="causal", inputs=2, recurrent=True)
    g = torch.Generator().manual_seed(0)
    frames, refs = [], []
    for i in range(4):  # the content moves 1 px right per frame
        tt = {k: torch.roll(v, i, dims=-1) for k, v in t.items()}
        tt["color"] = tt["color"] * (1 + 0.3 * torch.randn(t["color"].shape, generator=g)).abs()
        motion = torch.zeros_like(t["color"][:, :2])
        motion[:, 0] = -1.0  # to the previous frame: one pixel left
        frames.append(PreparedFrame(tt, motion if i else None, None, None, None))
        refs.append(torch.roll(t["color"], i, dims=-1))
    seq = Sequence_("s", refs=refs, frames=frames)
    motion_targets(seq)
    for i in range(4):
        tens, masks, _ = warp_window(frames, i, model.card.offsets, fill=True)
        seq.windows.append((tens, masks))
    cfg = load_config(
        None,
        {"model": "kpcn-temporal", "recurrent": "true", "window": "2", "temporal_mode": "causal"},
    )
    task = TemporalTask(model, cfg, [seq])
    assert task.frames == 3
    sampler = PairSampler([seq], patch=16, margin=4, aug=True, frames=task.frames)
    batch = sampler.batch(2, torch.Generator().manual_seed(1))
    assert batch["pp:color@1"].shape == (2, 3, 24, 24) and batch["motion"].shape == (2, 2, 24, 24)
    loss = task.loss(batch)
    assert torch.isfinite(loss)
    loss.backward()
    assert model.recurrence is not None
    assert float(model.recurrence.out.weight.grad.abs().sum()) > 0
    # outputs whose error pattern moves with the content (no flicker along the motion): the
    # warped term is 0, the same-pixel term is not (the motion itself reads as flicker)
    err = 0.2 * torch.rand(refs[0].shape, generator=g)
    o1, o2 = refs[1] + torch.roll(err, 1, dims=-1), refs[2] + torch.roll(err, 2, dims=-1)
    cur, prev = {"reference": refs[2], "motion": seq.motion[2]}, {"reference": refs[1]}
    cur |= {"warped_reference": seq.warped_refs[2], "warp_mask": seq.warp_masks[2]}
    mask = torch.ones_like(refs[2][:, :1])
    assert float(task._temporal(o2, o1, cur, prev, mask)) == pytest.approx(0, abs=1e-6)
    task.cfg = load_config(None, {"model": "kpcn-temporal", "temporal_loss": "same-pixel"})
    assert float(task._temporal(o2, o1, cur, prev, mask)) > 0.05
    scores = task.validate()  # recurrent validation: frames in order, the history carried
    assert math.isfinite(scores["val_loss"])
