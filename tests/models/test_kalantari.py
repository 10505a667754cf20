"""The Kalantari model: exactness at init, gradients, files, bad inputs."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers
from mcdenoise.io.buffers import MissingFeatureError
from mcdenoise.losses import relmse
from mcdenoise.methods.cross_bilateral import denoise_xbf
from mcdenoise.methods.kalantari import denoise_kalantari
from mcdenoise.methods.nlm import denoise_nlm
from mcdenoise.modelfile import CheckpointError
from mcdenoise.models.features import FeatureStats, feature_names
from mcdenoise.models.kalantari import KalantariModel, new_model, settings_class
from mcdenoise.prep.kalantari import prepare_for_model, prepare_item

GUIDES = ["albedo", "normal", "depth", "position"]


def _model(kind: str, buffers, hidden=(8,), settings=None, regional=False) -> KalantariModel:
    settings_ = settings_class(kind)(**(settings or {}))
    it = prepare_item(buffers, kind, settings_, GUIDES, regional=regional)
    with_var = [g for g in GUIDES if f"fvar.{g}" in it]
    names = feature_names(GUIDES, with_var, regional)
    stats = FeatureStats.from_samples(names, [it["features"][None]])
    return new_model(kind, GUIDES, with_var, stats, list(hidden), settings)


@pytest.fixture
def small(samples_dir):
    return load_buffers(samples_dir / "materials_spp4.exr").crop(40, 40, 32, 32)


@pytest.mark.parametrize(
    ("kind", "fixed", "settings"),
    [("xbf", denoise_xbf, {}), ("xbf", denoise_xbf, {"passes": 2}), ("nlm", denoise_nlm, {})],
)
def test_untrained_model_is_exactly_the_fixed_filter(small, kind, fixed, settings) -> None:
    m = _model(kind, small, settings=settings)
    torch.testing.assert_close(
        denoise_kalantari(m, small), fixed(small, **settings), atol=1e-5, rtol=1e-5
    )
    if settings.get("passes") == 2:
        assert m.card.outputs[-2:] == ["spatial2", "color2"] and m.radius == 20


@pytest.mark.parametrize("kind", ["xbf", "nlm"])
def test_gradcheck_from_mlp_input_through_filter_to_loss(small, kind) -> None:
    # d loss / d (normalised MLP input): MLP -> bounded log-offsets -> per-pixel bandwidths ->
    # filter weights -> remodulated output -> relMSE, in float64 on a 5x5 crop.
    settings = {"kernel_size": 5} if kind == "xbf" else {"search_radius": 2}
    crop = small.crop(3, 3, 5, 5)
    m = _model(kind, crop, hidden=(3,), settings=settings).double()
    g = torch.Generator().manual_seed(1)
    for p in m.parameters():  # move off the zero init so every path carries gradient
        p.data.copy_(torch.randn(p.shape, generator=g, dtype=p.dtype) * 0.3)
    batch = {k: v[None].double() for k, v in prepare_for_model(m.card, crop).items()}
    ref = batch["irr"] * batch["factor"] * 1.1 + 0.01
    z = torch.randn(batch["features"].shape, generator=g, dtype=torch.float64)

    def loss(z: torch.Tensor) -> torch.Tensor:
        return relmse(m.filter(batch, m.net(z)), ref)

    assert torch.autograd.gradcheck(loss, (z.requires_grad_(True),), fast_mode=True)
    (grad,) = torch.autograd.grad(loss(z), z)
    assert float(grad.abs().sum()) > 0
    (wgrad,) = torch.autograd.grad(loss(z), next(m.net.parameters()))
    assert float(wgrad.abs().sum()) > 0


def test_save_load_identical_output_and_card(small, tmp_path: Path) -> None:
    m = _model("xbf", small)
    for p in m.parameters():
        p.data.normal_(0, 0.2)
    m.save(tmp_path / "m.pt")
    back = KalantariModel.load(tmp_path / "m.pt")
    assert torch.equal(denoise_kalantari(m, small), denoise_kalantari(back, small))
    assert back.card.to_dict() == m.card.to_dict()
    assert not torch.equal(denoise_kalantari(m, small), denoise_xbf(small))  # the weights mattered


def test_incompatible_files_are_refused_with_the_difference(small, tmp_path: Path) -> None:
    m = _model("xbf", small)
    state = {"card": m.card.to_dict(), "state": m.state_dict()}
    card = dict(state["card"])
    feats = dict(card["features"])
    feats["names"] = [n for n in feats["names"] if not n.startswith("lum.mean")] + ["visibility.x"]
    feats["mean"] = [0.0] * len(feats["names"])
    feats["std"] = [1.0] * len(feats["names"])
    card["features"] = feats
    torch.save({"card": card, "state": state["state"]}, tmp_path / "other.pt")
    with pytest.raises(InputError) as err:
        KalantariModel.load(tmp_path / "other.pt")
    msg = str(err.value)
    assert "other.pt" in msg and "lum.mean.*" in msg and "visibility.x" in msg
    torch.save({"card": {**m.card.to_dict(), "format": "x/9"}, "state": {}}, tmp_path / "v.pt")
    with pytest.raises(InputError, match="format"):
        KalantariModel.load(tmp_path / "v.pt")
    (tmp_path / "trunc.pt").write_bytes((tmp_path / "other.pt").read_bytes()[:50])
    with pytest.raises(CheckpointError, match="truncated"):
        KalantariModel.load(tmp_path / "trunc.pt")


def test_input_without_a_trained_guide_is_refused_by_name(small) -> None:
    m = _model("xbf", small)
    no_albedo = small.subset([n for n in small.buffers if not n.startswith("albedo")])
    with pytest.raises(MissingFeatureError, match="albedo"):
        denoise_kalantari(m, no_albedo)


@pytest.mark.parametrize(("kind", "regional"), [("xbf", False), ("nlm", False), ("xbf", True)])
def test_hard_cases_never_give_nan(small, kind, regional) -> None:
    m = _model(kind, small, regional=regional)
    assert m.card.regional == regional
    for p in m.parameters():
        p.data.normal_(0, 1.0)
    b = small.to()
    b.buffers = {k: v.clone() for k, v in small.buffers.items()}
    b["color"][:, 5, 5] = 1e9  # firefly
    b["color"][:, 7, 7] = float("nan")
    b["color_var"][:, 9, 9] = float("inf")
    b["albedo"][:, :8] = 0.0  # zero albedo rows
    b["normal"][:, 3, 3] = float("nan")
    b["depth"][:, 4, 4] = float("inf")
    b["position"][:, 6, 6] = float("-inf")
    assert bool(
        torch.isfinite(prepare_for_model(m.card, b)["features"]).all()
    )  # no NaN spread by a window
    out = denoise_kalantari(m, b)
    assert bool(torch.isfinite(out).all()) and float(out.min()) >= 0


def test_model_file_from_a_run_folder(small, tmp_path: Path) -> None:
    m = _model("nlm", small)
    (tmp_path / "run").mkdir()
    m.save(tmp_path / "run" / "model.pt")
    assert KalantariModel.load(tmp_path / "run").card.kind == "nlm"
    shutil.rmtree(tmp_path / "run")
    with pytest.raises(CheckpointError, match="no such"):
        KalantariModel.load(tmp_path / "run" / "model.pt")
