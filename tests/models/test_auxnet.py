"""The learned auxiliary-buffer prefilter (issue 34): the net, its card, the tiled prefilter,
``kpcn -p prefilter=learned`` and training it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner
from mcdenoise_cli.main import main

from mcdenoise.denoise import denoise
from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers, save_buffers
from mcdenoise.io.buffer_files import save_buffers_parts
from mcdenoise.models.auxnet import FORMAT, AuxCard, AuxNet, apply_kernels, net_inputs
from mcdenoise.models.weights import load_auxnet, load_kpcn, model_method, shipped_model_path
from mcdenoise.prep.aux_prefilter import mixing_mask, prefilter_aux
from mcdenoise.prep.kpcn import prepare_tensors
from mcdenoise.prep.learned_prefilter import learned_aux, learned_prefilter
from mcdenoise.train.auxnet import build, train_auxnet
from mcdenoise.train.config import load_config

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"
ONE_THREAD = True
TINY = {
    "model": "auxnet",
    "channels": "8,8,8",
    "kernel": 3,
    "patch": 16,
    "margin": 8,
    "batch": 4,
    "steps": 4,
    "epoch_steps": 2,
    "warmup": 1,
    "val_fraction": 0.25,
    "threads": 1,
}


def random_net(seed: int = 0, **card: object) -> AuxNet:
    torch.manual_seed(seed)
    net = AuxNet(AuxCard(**card))  # type: ignore[arg-type]
    with torch.no_grad():  # a head that does more than keep the centre pixel
        net.head.weight.normal_(0, 0.5)
    return net.eval()


def inputs(h: int = 40, w: int = 56, seed: int = 1) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {
        "albedo": torch.rand(1, 3, h, w, generator=g),
        "normal": torch.nn.functional.normalize(torch.randn(1, 3, h, w, generator=g), dim=1),
        "color": torch.rand(1, 3, h, w, generator=g) * 4,
        "color_var": torch.rand(1, 1, h, w, generator=g) * 0.1,
    }


def x_of(t: dict[str, torch.Tensor]) -> torch.Tensor:
    noise = torch.full_like(t["color_var"], 0.1)
    return net_inputs(t["albedo"], t["normal"], t["color"], noise, noise)


def test_kernels_are_normalised_and_keep_values_in_range() -> None:
    net = random_net()
    t = inputs(32, 32)
    w = net(x_of(t))
    assert w.shape == (1, 2 * 49, 32, 32)
    assert torch.allclose(w.view(1, 2, 49, 32, 32).sum(2), torch.ones(1, 2, 32, 32), atol=1e-5)
    out = net.filter(w, {"albedo": t["albedo"], "normal": t["normal"]})
    # a convex combination of the 7x7 neighbourhood: never outside its min / max
    pool = torch.nn.functional.max_pool2d
    hi = pool(torch.nn.functional.pad(t["albedo"], (3, 3, 3, 3), mode="replicate"), 7, 1)
    lo = -pool(torch.nn.functional.pad(-t["albedo"], (3, 3, 3, 3), mode="replicate"), 7, 1)
    assert bool((out["albedo"] <= hi + 1e-6).all() and (out["albedo"] >= lo - 1e-6).all())


def test_fresh_net_keeps_the_pixel_mostly() -> None:
    net = AuxNet(AuxCard()).eval()
    t = inputs()
    with torch.no_grad():
        w = net(x_of(t)[..., :32, :48])
    assert float(w[:, 24].min()) > 0.04  # the centre tap starts preferred, not saturated
    assert float(w[:, 24].min()) > 2 * float(w[:, 23].max())


def test_apply_kernels_identity_and_box() -> None:
    x = torch.rand(1, 3, 9, 11)
    ident = torch.zeros(1, 9, 9, 11)
    ident[:, 4] = 1
    assert torch.equal(apply_kernels(x, ident, 3), x)
    box = torch.full((1, 9, 9, 11), 1 / 9)
    want = torch.nn.functional.avg_pool2d(
        torch.nn.functional.pad(x, (1, 1, 1, 1), mode="replicate"), 3, 1
    )
    assert torch.allclose(apply_kernels(x, box, 3), want, atol=1e-6)


def test_tiles_give_the_whole_image_result() -> None:
    net = random_net(widths=[8, 8, 8])
    t = inputs(100, 76)
    feats = {"albedo": t["albedo"], "normal": t["normal"]}
    whole = learned_prefilter(feats, {}, t["color"], t["color_var"], net, tile=512)
    tiled = learned_prefilter(feats, {}, t["color"], t["color_var"], net, tile=24)
    for k in ("albedo", "normal"):
        assert whole[k].shape == feats[k].shape
        assert torch.allclose(whole[k], tiled[k], atol=1e-5), k
    assert not torch.allclose(whole["albedo"], feats["albedo"])


def test_variances_are_used_only_with_both() -> None:
    net = random_net()
    t = inputs(32, 32)
    feats = {"albedo": t["albedo"], "normal": t["normal"]}
    v = {"albedo": torch.full((1, 3, 32, 32), 0.05)}
    no_var = learned_prefilter(feats, {}, t["color"], t["color_var"], net)
    one_var = learned_prefilter(feats, v, t["color"], t["color_var"], net)
    assert torch.equal(no_var["albedo"], one_var["albedo"])
    v["normal"] = torch.full((1, 3, 32, 32), 0.05)
    both = learned_prefilter(feats, v, t["color"], t["color_var"], net)
    assert not torch.equal(no_var["albedo"], both["albedo"])
    assert learned_prefilter({"albedo": t["albedo"]}, {}, t["color"], t["color_var"], net) == {}


def test_bad_values_do_not_leak() -> None:
    net = random_net()
    t = inputs(32, 32)
    t["color"][0, :, 3, 3] = float("inf")
    t["color"][0, :, 5, 5] = float("nan")
    feats = {"albedo": t["albedo"], "normal": t["normal"]}
    out = learned_prefilter(feats, {}, t["color"], t["color_var"], net)
    assert all(bool(torch.isfinite(v).all()) for v in out.values())


def test_card_round_trip_and_refusals(tmp_path: Path) -> None:
    net = random_net(widths=[8, 12], kernel=3)
    path = tmp_path / "aux.pt"
    net.save(path)
    back = AuxNet.load(path)
    assert back.card.widths == [8, 12] and back.card.kernel == 3
    assert model_method(path) == "auxnet"
    x = torch.rand(1, 15, 16, 16)
    assert torch.equal(back(x), net(x))
    with pytest.raises(InputError, match="kernel"):
        AuxCard.from_dict({"format": FORMAT, "widths": [8, 8], "kernel": 4})
    with pytest.raises(InputError, match="format"):
        AuxCard.from_dict({"format": "other", "widths": [8, 8], "kernel": 3})


@pytest.mark.skipif(not shipped_model_path("auxnet").is_file(), reason="no shipped auxnet")
def test_shipped_weights_clean_a_noisy_albedo() -> None:
    """On the shipped depth-of-field sample at 4 spp, in the pixels that mix surfaces, the
    net's albedo is closer to the 16-spp one (a cleaner estimate of the same quantity) than
    the noisy albedo is (measured: 0.49x); learned_aux takes it there and nowhere else."""
    net = load_auxnet(shipped_model_path("auxnet"))
    assert net.card.training.get("hardware", {}).get("steps", 0) > 0
    b4 = load_buffers(SAMPLES / "dof_spp4.exr")
    b16 = load_buffers(SAMPLES / "dof_spp16.exr")
    feats = {k: b4[k][None] for k in ("albedo", "normal")}
    var = b4["color_var"].mean(0, keepdim=True)[None]
    out = learned_prefilter(feats, {}, b4["color"][None], var, net)
    mixing = mixing_mask(feats["normal"]).expand(-1, 3, -1, -1)
    target = b16["albedo"][None]
    noisy_err = float((feats["albedo"] - target).square()[mixing].mean())
    learned_err = float((out["albedo"] - target).square()[mixing].mean())
    assert learned_err < 0.6 * noisy_err, (learned_err, noisy_err)
    both = learned_aux(feats, {}, b4["color"][None], var, net)
    adaptive = prefilter_aux(feats, {}, b4["color"][None], var)
    assert torch.equal(both["albedo"][~mixing], adaptive["albedo"][~mixing])
    assert torch.equal(both["albedo"][mixing], out["albedo"][mixing])


@pytest.mark.skipif(not shipped_model_path("auxnet").is_file(), reason="no shipped auxnet")
def test_kpcn_prepares_learned_features() -> None:
    b = load_buffers(SAMPLES / "dof_spp4.exr")
    plain = b.subset(["color", "albedo", "normal"])
    learned = prepare_tensors(plain, "basic", "learned")
    off = prepare_tensors(plain, "basic", "off")
    assert set(learned) == set(off)
    assert torch.equal(learned["color"], off["color"])
    assert not torch.equal(learned["albedo"], off["albedo"])
    full = prepare_tensors(b, "full", "learned")
    adaptive = prepare_tensors(b, "full", "adaptive")
    assert torch.equal(full["depth"], adaptive["depth"])  # depth / position as adaptive
    assert not torch.equal(full["albedo"], adaptive["albedo"])
    # only the pixels that mix surfaces change
    mixing = mixing_mask(b["normal"][None])[0].expand(3, -1, -1)
    assert torch.equal(full["albedo"][~mixing], adaptive["albedo"][~mixing])


def make_aux_dataset(folder: Path, size: int = 40) -> Path:
    """Crops of the sample renders; the reference holds the reference colour and, as its
    auxiliary buffers, the 16-spp level's (the samples' references carry colour only)."""
    (folder / "ref").mkdir(parents=True, exist_ok=True)
    for ref in sorted((SAMPLES / "ref").glob("*.exr")):
        scene = ref.stem
        parts = {
            f"spp{spp}": load_buffers(SAMPLES / f"{scene}_spp{spp}.exr").crop(44, 44, size, size)
            for spp in (4, 16)
        }
        for fb in parts.values():
            fb.data_window = fb.display_window = (0, 0, size - 1, size - 1)
        save_buffers_parts(folder / f"{scene}.exr", parts)
        rb = load_buffers(ref).crop(44, 44, size, size)
        rb.data_window = rb.display_window = (0, 0, size - 1, size - 1)
        for k in ("albedo", "normal"):
            rb.buffers[k] = parts["spp16"][k]
        save_buffers(folder / "ref" / f"{scene}.exr", rb)
    return folder


def test_training_runs_resumes_and_writes_a_card(tmp_path: Path) -> None:
    data = make_aux_dataset(tmp_path / "data")
    cfg = load_config(None, {k: str(v) for k, v in {**TINY, "data": str(data)}.items()})
    task, sampler, _ = build(cfg)
    batch = sampler.batch(4, torch.Generator().manual_seed(0))
    assert set(batch["has_var"].flatten().tolist()) <= {0.0, 1.0}
    loss = task.loss(batch)
    assert loss.ndim == 0 and bool(torch.isfinite(loss))
    out = tmp_path / "run"
    train_auxnet(cfg, out, progress=False)
    net = AuxNet.load(out / "model.pt")
    assert net.card.kernel == 3 and net.card.widths == [8, 8, 8]
    val = net.card.training["validation"]
    assert {"val_albedo_relmse", "val_albedo_relmse_noisy"} <= set(val)
    metrics = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    assert metrics


def test_cli_trains_auxnet_and_kpcn_accepts_the_mode(tmp_path: Path) -> None:
    data = make_aux_dataset(tmp_path / "data")
    args = ["train", "--model", "auxnet", "--data", str(data), "--out", str(tmp_path / "r")]
    for k, v in TINY.items():
        if k != "model":
            args += ["-s", f"{k}={v}"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    assert (tmp_path / "r" / "model.pt").is_file()
    bad = CliRunner().invoke(
        main,
        [
            "denoise",
            str(SAMPLES / "cornell_spp4.exr"),
            "-m",
            "kpcn",
            "-p",
            "prefilter=nope",
            "-o",
            str(tmp_path / "x.exr"),
        ],
    )
    assert bad.exit_code != 0 and "learned" in bad.output


def test_denoise_with_an_auxnet_file_says_what_it_is(tmp_path: Path) -> None:
    model = tmp_path / "aux.pt"
    random_net(widths=[8, 8]).save(model)
    res = CliRunner().invoke(
        main,
        ["denoise", str(SAMPLES / "cornell_spp4.exr"), "--model", str(model), "-o",
         str(tmp_path / "out.exr")],
    )  # fmt: skip
    assert res.exit_code == 1
    assert "not a denoiser" in res.output and "Traceback" not in res.output
    assert not (tmp_path / "out.exr").exists()


@pytest.mark.skipif(not shipped_model_path("auxnet").is_file(), reason="no shipped auxnet")
def test_prefilter_learned_runs_the_weights_trained_on_it() -> None:
    """With the shipped weights, ``-p prefilter=learned`` loads ``kpcn-learned.pt`` (trained
    on learned features); an explicit model is used as given."""
    from mcdenoise.methods import kpcn as kpcn_method

    b = load_buffers(SAMPLES / "dof_spp4.exr").subset(["color", "albedo", "normal"])
    variant = shipped_model_path("kpcn", "learned")
    assert variant.is_file()
    m = kpcn_method._model({"model": "shipped", "prefilter": "learned"})
    assert m is load_kpcn(variant)
    assert kpcn_method._model({"model": "shipped", "prefilter": "adaptive"}) is load_kpcn(
        shipped_model_path("kpcn")
    )
    given = kpcn_method._model({"model": str(shipped_model_path("kpcn")), "prefilter": "learned"})
    assert given is load_kpcn(shipped_model_path("kpcn"))
    out = denoise(b, "kpcn", params={"prefilter": "learned"}, device="cpu").image
    assert out.shape == b["color"].shape and bool(torch.isfinite(out).all())


@pytest.mark.skipif(not shipped_model_path("auxnet").is_file(), reason="no shipped auxnet")
@pytest.mark.parametrize("size", [(1, 1), (3, 5), (9, 17)])
def test_learned_prefilter_on_images_smaller_than_its_tiles(size: tuple[int, int]) -> None:
    h, w = size
    b = load_buffers(SAMPLES / "cornell_spp4.exr").subset(["color", "albedo", "normal"])
    c = b.crop(0, 0, h, w)
    c.data_window = c.display_window = (0, 0, w - 1, h - 1)
    c.buffers["albedo"][0, 0, 0] = float("nan")  # sanitised before the net sees it
    out = denoise(c, "kpcn", params={"prefilter": "learned"}, device="cpu").image
    assert out.shape == (3, h, w) and bool(torch.isfinite(out).all())
