"""The temporal kpcn model: joint softmax over frames, window of one, gradcheck, masks."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers
from mcdenoise.models.encoders import SOURCES, channel_names, source_channels
from mcdenoise.models.features import FeatureStats
from mcdenoise.models.kpcn import KpcnModel, new_model
from mcdenoise.models.kpcn_temporal import TemporalKpcn, from_single_frame, window_offsets
from mcdenoise.models.temporal_modules import (
    apply_joint,
    frame_log_softmax,
    joint_kernel_softmax,
    tap_valid,
)
from mcdenoise.prep.kpcn import prepare_tensors
from mcdenoise.prep.kpcn_temporal import PreparedFrame, warp_window

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"
ONE_THREAD = True


@pytest.fixture(scope="module")
def crop() -> dict[str, torch.Tensor]:
    """Prepared ``full`` tensors of a 32×32 crop of the Cornell box at 4 spp."""
    b = load_buffers(SAMPLES / "cornell_spp4.exr")
    t = prepare_tensors(b, "full")
    return {k: v[None, :, 40:72, 40:72].contiguous() for k, v in t.items()}


@pytest.fixture(scope="module")
def base(crop) -> KpcnModel:
    stats = {
        s: FeatureStats.from_samples(channel_names(s), [source_channels(s, crop)])
        for s in ("full", "basic")
    }
    torch.manual_seed(0)
    return new_model(["full", "basic"], stats, channels=(8, 8, 8), kernel=3, scales=3).eval()


def _temporal(base: KpcnModel, window: int = 3, mode: str = "causal") -> TemporalKpcn:
    torch.manual_seed(1)
    m = from_single_frame(base, window=window, mode=mode, hidden=[4, 4, 4]).eval()
    # a temporal module that is not at its zero start (its output layers are zero-initialised)
    with torch.no_grad():
        for mixer in m.mixers:
            mixer.out.weight.normal_(0, 0.3)
            mixer.alpha.weight.normal_(0, 0.3)
    return m


def test_window_offsets() -> None:
    assert window_offsets(5, "offline") == [-2, -1, 0, 1, 2]
    assert window_offsets(3, "causal") == [-2, -1, 0]
    with pytest.raises(InputError, match="odd"):
        window_offsets(4, "offline")


def test_joint_softmax_sums_to_one_and_stays_finite_for_huge_and_inf_logits() -> None:
    g = torch.Generator().manual_seed(0)
    n, k, h, w = 3, 3, 6, 7
    logits = [torch.randn(2, k * k, h, w, generator=g) * 1e30 for _ in range(n)]
    logits[0][:, 4, 2, 3] = float("inf")
    logits[1][:, 0, 1, 1] = float("-inf")
    logits[1][:, 5, 3, 3] = float("nan")
    logits[2][:, :, 4, 4] = float("inf")  # every tap of frame 2 at one pixel
    masks = [torch.ones(2, 1, h, w)] + [
        (torch.rand(2, 1, h, w, generator=g) > 0.4).float() for _ in range(n - 1)
    ]
    valid = [tap_valid(m, k) for m in masks]
    wts = joint_kernel_softmax(logits, valid)
    total = sum(x.sum(dim=1) for x in wts)
    assert all(torch.isfinite(x).all() for x in wts)
    assert torch.allclose(total, torch.ones_like(total), atol=1e-5)
    for x, v in zip(wts, valid):
        assert (x[~v] == 0).all() and (x >= 0).all()  # invalid and out-of-image taps: 0


def test_window_of_one_is_the_single_frame_model_exactly(base, crop) -> None:
    m = _temporal(base, 3)
    ones = torch.ones_like(crop["color"][:, :1])
    with torch.no_grad():
        assert torch.equal(m.run([crop], [ones], 0, "full"), base.run(crop, "full"))
        assert torch.equal(
            m.denoise_window([crop], [ones], 0, "full"), base.denoise_tensors(crop, "full")
        )


def test_identical_frames_with_untrained_module_reduce_to_the_single_frame_kernels(
    base, crop
) -> None:
    """At its zero start the temporal module blends the per-frame kernels: three copies of
    one frame give the single-frame result (to rounding)."""
    m = from_single_frame(base, window=3, mode="offline").eval()
    ones = torch.ones_like(crop["color"][:, :1])
    with torch.no_grad():
        out = m.run([crop, crop, crop], [ones, ones, ones], 1, "full")
        ref = base.run(crop, "full")
    assert torch.allclose(out, ref, rtol=1e-4, atol=1e-6)


def test_gradcheck_float64_through_the_joint_kernel_application() -> None:
    g = torch.Generator().manual_seed(0)
    n, k, h, w = 2, 3, 5, 6

    def rnd(*shape):
        return torch.randn(*shape, generator=g, dtype=torch.float64, requires_grad=True)

    logits = [rnd(1, k * k, h, w) for _ in range(n)]
    images = [rnd(1, 2, h, w) for _ in range(n)]
    masks = [
        torch.ones(1, 1, h, w, dtype=torch.float64),
        torch.ones(1, 1, h, w, dtype=torch.float64),
    ]
    masks[1][..., 1:3, 2:4] = 0
    valid = [tap_valid(m, k) for m in masks]

    def f(*args):
        return apply_joint(list(args[n:]), joint_kernel_softmax(list(args[:n]), valid))

    assert torch.autograd.gradcheck(f, (*logits, *images), eps=1e-6, atol=1e-6, fast_mode=True)


def _frames(crop, n: int, seed: int = 0) -> list[PreparedFrame]:
    """``n`` static frames of the crop, each with its own noise, zero motion, all valid."""
    g = torch.Generator().manual_seed(seed)
    out = []
    for i in range(n):
        t = dict(crop)
        t["color"] = crop["color"] * (1 + 0.3 * torch.randn(crop["color"].shape, generator=g)).abs()
        zero = torch.zeros_like(crop["color"][:, :2])
        valid = torch.full_like(crop["color"][:, :1], float(i > 0))
        nxt = torch.full_like(crop["color"][:, :1], float(i < n - 1))
        out.append(PreparedFrame(t, zero, valid, zero.clone(), nxt))
    return out


def test_invalid_pixels_are_never_read(base, crop) -> None:
    """Warped pixels under a zero mask (here frame 2's motion_valid = 0 in a region) hold 0;
    replaced by NaN or 1e30 they change nothing: no kernel tap reads them."""
    m = _temporal(base, 3, "causal")
    frames = _frames(crop, 3)
    region = (slice(None), slice(None), slice(8, 20), slice(5, 17))
    frames[2].motion_valid = frames[2].motion_valid.clone()
    frames[2].motion_valid[region] = 0
    tens, masks, c = warp_window(frames, 2, [-2, -1, 0])
    assert all(float(masks[i][region].max()) == 0 for i in (0, 1))
    outs = []
    for poison in (None, float("nan"), 1e30):
        fr = [dict(t) for t in tens]
        if poison is not None:
            for i in (0, 1):
                for key, v in fr[i].items():
                    fr[i][key] = torch.where(masks[i] > 0.5, v, torch.full_like(v, poison))
        with torch.no_grad():
            outs.append(m.run(fr, masks, c, "full"))
    assert all(torch.isfinite(o).all() for o in outs)
    assert torch.equal(outs[0], outs[1]) and torch.equal(outs[0], outs[2])


def test_a_cut_drops_the_history(base, crop) -> None:
    m = _temporal(base, 3, "causal")
    a, b = _frames(crop, 3, seed=0), _frames(crop, 3, seed=5)
    for seq in (a, b):
        seq[2].motion_valid = torch.zeros_like(seq[2].motion_valid)  # a cut at frame 2
    b[2] = a[2]  # the same frame 2 after different histories
    outs = []
    for seq in (a, b):
        tens, masks, c = warp_window(seq, 2, [-2, -1, 0])
        assert all(float(mm.sum()) == 0 for i, mm in enumerate(masks) if i != c)
        with torch.no_grad():
            outs.append(m.run(tens, masks, c, "full"))
    assert torch.equal(outs[0], outs[1])


def test_model_file_round_trip(base, crop, tmp_path) -> None:
    m = _temporal(base, 5, "offline")
    m.save(tmp_path / "t.pt")
    back = TemporalKpcn.load(tmp_path / "t.pt")
    assert back.card.window == 5 and back.card.mode == "offline"
    frames = _frames(crop, 5)
    tens, masks, c = warp_window(frames, 2, back.card.offsets)
    with torch.no_grad():
        assert torch.equal(m.run(tens, masks, c, "full"), back.run(tens, masks, c, "full"))


def test_basic_source_runs(base, crop) -> None:
    m = _temporal(base, 3, "offline")
    basic = {k: v for k, v in crop.items() if k in SOURCES["basic"]}
    ones = torch.ones_like(crop["color"][:, :1])
    with torch.no_grad():
        out = m.denoise_window([basic, basic, basic], [ones, ones, ones], 1, "basic")
    assert out.shape == crop["color"].shape and torch.isfinite(out).all()


def test_a_neighbour_weighs_only_its_kernels_mass_on_valid_pixels() -> None:
    """Each frame's logits are normalised over the in-image taps, then invalid taps are
    dropped: a neighbour whose (uniform 3×3) kernel finds 1 valid tap of 9 gets 1/9 of the
    centre frame's weight there, not an equal share piled on that one tap."""
    k, h, w = 3, 5, 5
    z = torch.zeros(1, k * k, h, w)
    ones = torch.ones(1, 1, h, w)
    sparse = torch.zeros(1, 1, h, w)
    sparse[..., 1, 1] = 1  # the neighbour is valid at one pixel only
    in_image = tap_valid(ones, k)
    logits = [frame_log_softmax(z, in_image), frame_log_softmax(z, in_image)]
    wts = joint_kernel_softmax(logits, [in_image, tap_valid(sparse, k)])
    share = float(wts[1][0, :, 2, 2].sum())  # pixel (2, 2) sees (1, 1) through one tap
    assert share == pytest.approx((1 / 9) / (1 + 1 / 9), rel=1e-5)
