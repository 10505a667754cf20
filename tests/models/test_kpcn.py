"""The kernel-predicting CNN: source choice, tiling, determinism, hard inputs, files, autocast."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.filters.albedo import ALBEDO_EPS
from mcdenoise.io import load_buffers
from mcdenoise.io.buffers import FeatureBuffers, MissingFeatureError
from mcdenoise.losses import smape
from mcdenoise.methods.kpcn import denoise_kpcn
from mcdenoise.modelfile import CheckpointError
from mcdenoise.models.encoders import SOURCES, channel_names, shared_layout, source_channels
from mcdenoise.models.features import FeatureStats
from mcdenoise.models.kpcn import KpcnCard, KpcnModel, new_model
from mcdenoise.prep.kpcn import prepare_tensors

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"
ALL = list(SOURCES)  # full, basic, color
FULL_BUFFERS = set(SOURCES["full"])


#: one intra-op thread for this module (tests/conftest.py)
ONE_THREAD = True


@pytest.fixture(scope="module")
def cornell() -> FeatureBuffers:
    """The 128x128 Cornell box at 4 spp, every buffer."""
    return load_buffers(SAMPLES / "cornell_spp4.exr")


@pytest.fixture(scope="module")
def stats(cornell: FeatureBuffers) -> dict[str, FeatureStats]:
    out = {}
    for s in ALL:
        t = {k: v[None] for k, v in prepare_tensors(cornell, s).items()}
        out[s] = FeatureStats.from_samples(channel_names(s), [source_channels(s, t)])
    return out


def _tiny(stats, sources=ALL, seed: int = 0, **kw) -> KpcnModel:
    torch.manual_seed(seed)
    kw = {"channels": (8, 8, 8), "kernel": 5, "scales": 3, **kw}
    return new_model(sources, stats, **kw).eval()


@pytest.fixture(scope="module")
def model(stats) -> KpcnModel:
    """An untrained 3-level, 3-scale, 5x5-kernel model with an encoder for every source."""
    return _tiny(stats)


def _copy(b: FeatureBuffers) -> FeatureBuffers:
    out = b.to()
    out.buffers = {k: v.clone() for k, v in b.buffers.items()}
    return out


def _batch(b: FeatureBuffers, sources: list[int]) -> dict[str, torch.Tensor]:
    """Prepared full-source tensors of ``len(sources)`` 16x16 crops, as a training batch
    (features not prefiltered: the trainer's default, ``-s prefilter=off``)."""
    crops = [
        prepare_tensors(b.crop(8 * i, 10 * i, 16, 16), "full", "off") for i in range(len(sources))
    ]
    batch = {k: torch.stack([c[k] for c in crops]) for k in crops[0]}
    batch["source"] = torch.tensor(sources)
    return batch


# --- choosing the source -------------------------------------------------------------------


@pytest.mark.parametrize(
    ("sources", "keep", "named"),
    [
        (["full", "basic"], ["color"], ["albedo", "normal"]),
        (["full"], ["color", "albedo", "normal"], ["color_var", "depth", "position"]),
        (["basic"], ["color", "albedo"], ["normal"]),
    ],
)
def test_missing_buffers_raise_one_line_naming_them(cornell, stats, sources, keep, named) -> None:
    m = _tiny(stats, sources, channels=(8, 8), kernel=3, scales=1)
    with pytest.raises(MissingFeatureError) as info:
        denoise_kpcn(m, cornell.crop(0, 0, 8, 8).subset(keep))
    msg = str(info.value)
    assert len(msg.splitlines()) == 1, msg
    assert "cornell_spp4.exr" in msg
    needs = msg.split(" needs ")[1].split(";")[0]
    assert needs.split(", ") == named, msg


def test_forcing_a_source_the_input_cannot_feed(cornell, model, stats) -> None:
    with pytest.raises(MissingFeatureError, match="needs color_var, depth, position"):
        denoise_kpcn(
            model, cornell.crop(0, 0, 8, 8).subset(["color", "albedo", "normal"]), source="full"
        )
    basic_only = _tiny(stats, ["basic"], channels=(8, 8), kernel=3, scales=1)
    with pytest.raises(InputError, match="no 'full' source"):
        denoise_kpcn(basic_only, cornell.crop(0, 0, 8, 8), source="full")


# --- tiling, strips, determinism -----------------------------------------------------------


@pytest.mark.parametrize(
    "arch",
    [
        {"channels": (8, 8, 8), "kernel": 5, "scales": 3},
        {"channels": (8, 8, 8, 8), "kernel": 3, "scales": 2},
        {"channels": (8, 8, 8), "kernel": 5, "scales": 3, "albedo_kernels": True},
    ],
    ids=["3lvl-k5-s3", "4lvl-k3-s2", "3lvl-k5-s3-albedo"],
)
def test_tiled_equals_untiled_on_an_odd_size(cornell, stats, arch) -> None:
    m = _tiny(stats, **arch)
    assert m.halo % m.multiple == 0
    crop = cornell.crop(20, 10, 75, 100)  # 100x75: a multiple of neither tile nor pooling
    whole = denoise_kpcn(m, crop, tile=1024, strip=1024)
    assert whole.shape == (3, 75, 100)
    # the network does something: the result is not the noisy input
    assert float((whole - crop["color"]).abs().mean()) > 1e-3
    for tile in (32, 48):
        tiled = denoise_kpcn(m, crop, tile=tile, strip=7)
        # 1e-5 is the promise; measured ~3e-8 (rounding). 1e-6 also catches a halo too small:
        # the 3-level model (halo 48) is off by 9e-6 with a 16-px halo, by 6e-3 with 8 px.
        # Plus 2 float32 eps of the value: the crop holds the light (14.1), where 1e-6 is one
        # ulp, and a tile's other convolution shapes may round otherwise on another CPU;
        # 1e-6 + 2 * eps32 * 14.1 = 4.4e-6 still catches the 9e-6.
        eps32 = torch.finfo(torch.float32).eps
        torch.testing.assert_close(tiled, whole, atol=1e-6, rtol=2 * eps32, msg=f"tile {tile}")


# --- albedo kernels ---------------------------------------------------------------------------


def _flat_noisy_albedo(cornell: FeatureBuffers) -> FeatureBuffers:
    """A crop whose irradiance is exactly 1 everywhere under a noisy albedo."""
    b = _copy(cornell.crop(0, 0, 32, 32))
    g = torch.Generator().manual_seed(9)
    albedo = (0.5 + 0.3 * (torch.rand(3, 32, 32, generator=g) - 0.5)).float()
    b.buffers["albedo"] = albedo
    b.buffers["color"] = albedo + ALBEDO_EPS  # demodulated: exactly 1
    return b


def test_albedo_kernels_start_near_a_delta_and_can_remove_albedo_noise(cornell, stats) -> None:
    b = _flat_noisy_albedo(cornell)
    plain = _tiny(stats)
    m = _tiny(stats, albedo_kernels=True)
    w = torch.softmax(m.albedo_head.bias.detach(), 0)
    assert w[12].item() == pytest.approx(math.exp(4) / (math.exp(4) + 24), abs=1e-6)
    assert w[12].item() == pytest.approx(0.69, abs=0.01)
    # every kernel averages a constant irradiance to itself, so without albedo kernels the
    # output is the noisy albedo; uniform albedo kernels (a 5x5 box) remove most of its noise
    noisy = denoise_kpcn(plain, b, source="full")
    torch.testing.assert_close(noisy, b["albedo"] + ALBEDO_EPS, atol=1e-5, rtol=1e-5)
    with torch.no_grad():
        m.albedo_head.bias.zero_()
    box = denoise_kpcn(m, b, source="full")
    inner = (slice(None), slice(4, -4), slice(4, -4))
    assert box[inner].std().item() < 0.35 * noisy[inner].std().item()
    torch.testing.assert_close(box[inner].mean(), noisy[inner].mean(), atol=5e-3, rtol=0)


def test_albedo_kernels_survive_save_and_load(cornell, stats, tmp_path) -> None:
    m = _tiny(stats, albedo_kernels=True)
    with torch.no_grad():
        m.albedo_head.weight.normal_(0, 0.1)
    m.save(tmp_path / "m.pt")
    again = KpcnModel.load(tmp_path / "m.pt")
    assert again.card.albedo_kernels
    crop = cornell.crop(3, 4, 40, 36)
    assert torch.equal(denoise_kpcn(again, crop), denoise_kpcn(m, crop))
    # model files written before the option have no field: no albedo kernels
    d = m.card.to_dict()
    del d["albedo_kernels"]
    assert not KpcnCard.from_dict(d).albedo_kernels


def test_same_input_three_times_gives_identical_bytes(cornell, model) -> None:
    crop = cornell.crop(5, 7, 40, 36)
    outs = [denoise_kpcn(model, crop, tile=32, strip=9) for _ in range(3)]
    assert outs[0].numpy().tobytes() == outs[1].numpy().tobytes() == outs[2].numpy().tobytes()


def test_training_forward_routes_each_crop_to_its_source(cornell, model) -> None:
    sources = [2, 0, 1, 0]
    batch = _batch(cornell, sources)
    with torch.no_grad():
        out = model(batch)
        assert out.shape == (4, 3, 16, 16) and out.dtype == torch.float32
        for i, s in enumerate(sources):
            name = model.card.sources[s]
            if name == "full":
                t = {k: v[i : i + 1] for k, v in batch.items() if k != "source"}
                want = model.run(t, name)[0]
            else:
                # a basic/colour crop is exactly what inference sees for that source: e.g. a
                # colour-only crop is not demodulated by the albedo the batch holds
                # (training crops are neither prefiltered nor exposure-scaled here)
                crop = cornell.crop(8 * i, 10 * i, 16, 16)
                want = denoise_kpcn(model, crop, source=name, prefilter="off", exposure="off")
            torch.testing.assert_close(out[i], want, atol=1e-6, rtol=1e-6, msg=name)
        # the same crop seen through different sources gives different results
        same = _batch(cornell, [0])
        same = {k: v.expand(3, *v.shape[1:]) for k, v in same.items() if k != "source"}
        res = model({**same, "source": torch.tensor([0, 1, 2])})
    assert not torch.allclose(res[0], res[2], atol=1e-4)


# --- hard inputs (docs/hard-cases.md items 13, 14, 16, 23, 24) ----------------------------------------------


def _nan_inf_colour(b: FeatureBuffers) -> FeatureBuffers:
    b["color"][0, 3, 3] = float("nan")
    b["color"][1, 5, 5] = float("inf")
    b["color"][2, 6, 6] = float("-inf")
    b["color_var"][:, 9, 9] = float("nan")
    return b


def _nan_inf_features(b: FeatureBuffers) -> FeatureBuffers:
    b["albedo"][:, 2, 2] = float("nan")
    b["normal"][:, 4, 4] = float("inf")
    b["depth"][:, 7, 7] = float("nan")
    b["position"][:, 8, 8] = float("-inf")
    b["albedo_var"][:, 1, 1] = float("inf")
    return b


def _firefly(b: FeatureBuffers) -> FeatureBuffers:
    b["color"][:, 4, 4] = 1e6
    return b


def _zero_albedo(b: FeatureBuffers) -> FeatureBuffers:
    b["albedo"].zero_()
    b["albedo_var"].zero_()
    return b


def _black(b: FeatureBuffers) -> FeatureBuffers:
    b["color"].zero_()
    b["color_var"].zero_()
    return b


HARD: dict[str, tuple[Callable[[FeatureBuffers], FeatureBuffers], tuple[int, int]]] = {
    "nan-inf-colour": (_nan_inf_colour, (16, 16)),
    "nan-inf-features": (_nan_inf_features, (16, 16)),
    "firefly-1e6": (_firefly, (16, 16)),
    "zero-albedo": (_zero_albedo, (16, 16)),
    "all-black": (_black, (16, 16)),
    "1x1": (lambda b: b, (1, 1)),
    "3x5": (lambda b: b, (3, 5)),
    "1x2": (lambda b: b, (1, 2)),
}


@pytest.mark.parametrize("case", list(HARD))
def test_hard_inputs_give_finite_non_negative_output(cornell, model, case) -> None:
    make, (h, w) = HARD[case]
    b = make(_copy(cornell.crop(50, 50, h, w)))
    for src in ALL:
        out = denoise_kpcn(model, b, source=src, tile=32, strip=4)
        assert out.shape == (3, h, w) and out.dtype == torch.float32
        assert bool(torch.isfinite(out).all()), (case, src)
        assert bool((out >= 0).all()), (case, src)
        if case == "all-black":
            assert torch.equal(out, torch.zeros_like(out)), src


def test_a_constant_image_stays_constant(cornell, model) -> None:
    # the kernels are normalised at every scale and the compositor moves no energy: a flat
    # colour over a flat albedo comes back, whatever the (varying) normals and depth predict
    b = _copy(cornell.crop(30, 30, 21, 19))
    b["color"].fill_(0.3)
    b["albedo"].fill_(0.5)
    for src in ALL:
        out = denoise_kpcn(model, b, source=src, tile=32, strip=5)
        torch.testing.assert_close(out, torch.full_like(out, 0.3), atol=1e-6, rtol=1e-5)


# --- files --------------------------------------------------------------------------------


def test_save_load_gives_identical_output(cornell, model, tmp_path) -> None:
    path = tmp_path / "m.pt"
    model.save(path)
    again = KpcnModel.load(path)
    assert again.card.to_dict() == model.card.to_dict()
    crop = cornell.crop(10, 10, 24, 24)
    for src in ALL:
        assert torch.equal(
            denoise_kpcn(again, crop, source=src), denoise_kpcn(model, crop, source=src)
        )
    # a run folder loads its model.pt
    (tmp_path / "run").mkdir()
    model.save(tmp_path / "run" / "model.pt")
    assert KpcnModel.load(tmp_path / "run").card.sources == ALL


def test_a_file_with_other_input_channels_is_refused_naming_them(model, tmp_path) -> None:
    path = tmp_path / "m.pt"
    model.save(path)
    state = torch.load(path, weights_only=True)
    names = state["card"]["stats"]["basic"]["names"]
    names[names.index("grad_normal")] = "grad_shading"
    torch.save(state, path)
    with pytest.raises(InputError) as info:
        KpcnModel.load(path)
    msg = str(info.value)
    assert len(msg.splitlines()) == 1 and str(path) in msg
    assert "'basic'" in msg and "grad_normal" in msg and "grad_shading" in msg


def test_weights_that_do_not_fit_the_card_are_refused(model, tmp_path) -> None:
    path = tmp_path / "m.pt"
    model.save(path)
    state = torch.load(path, weights_only=True)
    state["card"]["channels"] = [8, 8, 16]
    torch.save(state, path)
    with pytest.raises(InputError, match="weights do not match the model card") as info:
        KpcnModel.load(path)
    msg = str(info.value)  # one line saying what differs, not only torch's heading
    assert len(msg.splitlines()) == 1 and "size mismatch" in msg and not msg.endswith(":)")


def test_truncated_or_foreign_files_give_checkpoint_errors(model, tmp_path) -> None:
    path = tmp_path / "m.pt"
    model.save(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match="truncated or corrupt") as info:
        KpcnModel.load(path)
    assert len(str(info.value).splitlines()) == 1
    torch.save({"weights": torch.zeros(3)}, path)
    with pytest.raises(CheckpointError, match="no model card"):
        KpcnModel.load(path)
    with pytest.raises(CheckpointError, match="no such"):
        KpcnModel.load(tmp_path / "missing.pt")


# --- mixed precision (docs/hard-cases.md item 22) ------------------------------------------------------------


def test_bf16_autocast_keeps_kernels_and_output_float32(cornell, model, kernel_dtypes) -> None:
    seen = kernel_dtypes
    conv_dtypes: list[torch.dtype] = []
    hook = model.up[0].register_forward_hook(lambda m, i, o: conv_dtypes.append(o.dtype))
    batch = _batch(cornell, [0, 1, 2])
    batch["color"] = batch["color"] * 1e5  # HDR near 1e5: overflows half precision, not float32
    try:
        with torch.autocast("cpu", dtype=torch.bfloat16):
            out = model(batch)
            tiled = denoise_kpcn(model, cornell.crop(0, 0, 20, 18), tile=8, strip=3)
    finally:
        hook.remove()
    assert conv_dtypes and set(conv_dtypes) == {torch.bfloat16}  # autocast was in effect
    assert out.dtype == torch.float32 and bool(torch.isfinite(out).all())
    assert tiled.dtype == torch.float32 and bool(torch.isfinite(tiled).all())
    # 3 scales x 3 sources for the batch, more for the tiles: every call saw float32 only
    assert len(seen) >= 9
    assert set(seen) == {(torch.float32, torch.float32)}


def test_bf16_autocast_training_step_has_finite_gradients(cornell, stats) -> None:
    m = _tiny(stats).train()
    batch = _batch(cornell, [0, 1, 2])
    batch["color"] = batch["color"] * 1e5
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = m(batch)
        loss = smape(out, batch["color"].mean((2, 3), keepdim=True).expand_as(out))
    assert loss.dtype == torch.float32 and bool(torch.isfinite(loss))
    loss.backward()
    grads = [p.grad for p in m.parameters() if p.grad is not None]
    assert grads and all(bool(torch.isfinite(g).all()) for g in grads)


# --- the shared-encoder ablation ---------------------------------------------------------------


def test_shared_encoder_runs_for_every_source(cornell, stats) -> None:
    m = _tiny(stats, encoder="shared")
    assert list(m.encoders) == ["shared"]
    crop = cornell.crop(40, 40, 24, 20)
    outs = {}
    for src in ALL:
        outs[src] = denoise_kpcn(m, crop, source=src, tile=16, strip=6)
        assert outs[src].shape == (3, 24, 20) and bool(torch.isfinite(outs[src]).all())
        assert bool((outs[src] >= 0).all())
    # the missing channels are zero-filled, not ignored: the sources see different inputs
    assert not torch.allclose(outs["full"], outs["color"], atol=1e-4)
    with torch.no_grad():
        out = m(_batch(cornell, [0, 1, 2]))
    assert out.shape == (3, 3, 16, 16) and bool(torch.isfinite(out).all())


@pytest.mark.parametrize("source", ["basic", "color"])
def test_shared_layout_keeps_channels_last(source) -> None:
    # the encoder hands channels-last tensors on (1.3-1.8x faster convolutions on CPU); the
    # zero-filled full layout must keep that format, and hold the source's channels unchanged
    full = channel_names("full")
    index = [full.index(n) for n in channel_names(source)]
    z = torch.randn(2, len(index), 8, 6).contiguous(memory_format=torch.channels_last)
    out = shared_layout(z, source)
    assert out.shape == (2, len(full), 8, 6)
    assert out.is_contiguous(memory_format=torch.channels_last)
    assert torch.equal(out[:, index], z)
    rest = [i for i in range(len(full)) if i not in index]
    assert bool((out[:, rest] == 0).all())
