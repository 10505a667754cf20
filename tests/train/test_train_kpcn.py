"""Training the kpcn model: memorising a patch set, run folders, exact resume, encoder
fine-tuning, augmentation, and the command line.

(Named ``test_train_kpcn.py``, not ``test_kpcn.py``: ``tests/models/test_kpcn.py`` exists and
the test folders are not packages, so two files of one basename cannot be collected together.)
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner
from mcdenoise_cli.main import main

import mcdenoise.train.kpcn as train_kpcn_module
from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers
from mcdenoise.losses import l1
from mcdenoise.methods.kpcn import denoise_kpcn
from mcdenoise.models.kpcn import KpcnModel
from mcdenoise.prep.kpcn import COLOR_TENSORS, exposure_scale, prepare_tensors
from mcdenoise.train.checkpoint import RunFolder
from mcdenoise.train.config import load_config
from mcdenoise.train.kpcn import (
    BASIC_SUFFIX,
    UNUSED_SCALE_WEIGHT,
    augment_exposure,
    build,
    train_kpcn,
    use_basic_features,
)
from mcdenoise.train.patches import augment

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"
#: A tiny kpcn: 3 U-Net levels of 8 channels, 5x5 kernels at 3 scales, 32-px crops.
TINY = {
    "model": "kpcn",
    "channels": "8,8,8",
    "kernel": 5,
    "scales": 3,
    "patch": 16,
    "margin": 8,
    "batch": 4,
    "steps": 4,
    "epoch_steps": 2,
    "warmup": 1,
    "val_fraction": 0.25,
    "threads": 1,
}


#: one intra-op thread for this module (tests/conftest.py)
ONE_THREAD = True


def cfg(data: Path, **kw):
    values = {**TINY, "data": str(data), **kw}
    return load_config(None, {k: str(v) for k, v in values.items()})


@pytest.fixture(scope="module")
def base_run(tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 4-step run of the tiny model on the full and basic sources (made once per module)."""
    out = tmp_path_factory.mktemp("kpcn") / "base"
    train_kpcn(cfg(tiny_dataset), out, progress=False)
    return out


# --- (a) a tiny model memorises a tiny patch set ----------------------------------------------


def test_a_tiny_model_memorises_two_crops(tiny_dataset: Path) -> None:
    # Two 8x8 crops (+4 px context), one seen as `full`, one as `basic`, shown again every step.
    # Kernels can only average noisy neighbours, but with a free 5x5 kernel per pixel most
    # reference pixels lie in the convex hull of their neighbours' colours, so memorising goes
    # far below the noise. Measured on the crops of sampler seeds 5-8 (this machine, 1 thread):
    # L1 falls 17-62x in 300 steps with 16 channels (29x for seed 5, ~3 s); SMAPE fell only
    # 8-22x in 200 steps (dark pixels weigh like bright ones); 8 channels on 32-px crops,
    # 4.5-9x. Hence L1, 2 levels of 16 channels, one scale, two small crops.
    c = cfg(
        tiny_dataset,
        channels="16,16",
        scales=1,
        patch=8,
        margin=4,
        batch=2,
        loss="l1",
        augment="false",
    )
    torch.manual_seed(0)
    task, sampler, _ = build(c)
    model = task.model.train()
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    g = torch.Generator()
    losses = []
    for _ in range(300):
        batch = sampler.batch(c.batch, g.manual_seed(5))  # the same two crops every step
        loss = task.loss(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert sorted(batch["source"].tolist()) == [0, 1]  # both encoders were trained
    noisy = float(l1(batch["color"], batch["reference"], batch["mask"]))
    assert losses[0] / losses[-1] >= 10, (losses[0], losses[-1])
    assert losses[-1] < 0.2 * noisy  # far better than the noisy input on these crops


# --- (b) a run folder ----------------------------------------------------------------------------


def test_train_kpcn_writes_a_loadable_run(base_run: Path, tiny_dataset: Path) -> None:
    run = RunFolder(base_run)
    config = json.loads(run.config_path.read_text())
    assert config["model"] == "kpcn" and config["loss"] == "smape"  # the resolved default
    assert config["channels"] == [8, 8, 8] and config["sources"] == ["full", "basic"]
    metrics = run.read_metrics()
    assert [m["step"] for m in metrics] == [2, 4]
    last = metrics[-1]
    for src in ("full", "basic"):
        for key in (f"val_{src}_geomean", f"val_{src}_ratio_to_noisy", f"val_{src}_spp4"):
            assert last[key] > 0, key
        assert f"val_{src}_spp16" in last
    assert "val_color_geomean" not in last  # only the trained sources are validated
    assert last["val_loss"] > 0 and last["train_loss"] > 0
    assert run.latest().name == "step_000004.pt"
    model = KpcnModel.load(base_run)
    assert model.card.sources == ["full", "basic"] and model.card.kernel == 5
    assert model.card.channels == [8, 8, 8] and model.card.scales == 3
    training = model.card.training
    assert training["val_images"] and training["train_images"]
    assert not set(training["val_images"]) & set(training["train_images"])  # split by image
    assert training["validation"]["val_loss"] == pytest.approx(min(m["val_loss"] for m in metrics))
    out = denoise_kpcn(model, load_buffers(tiny_dataset / "cornell.exr", part="spp4"))
    assert out.shape == (3, 40, 40) and bool(torch.isfinite(out).all())


# --- (c) exact resume ----------------------------------------------------------------------------


def test_resume_after_a_kill_gives_identical_weights(
    tiny_dataset: Path, tmp_path: Path, interrupted_training
) -> None:
    straight, half = tmp_path / "straight", tmp_path / "half"
    train_kpcn(cfg(tiny_dataset), straight, progress=False)
    # Ctrl-C during step 4: the checkpoint of step 2 is the latest
    interrupted_training(train_kpcn, cfg(tiny_dataset), half, at=4)
    assert RunFolder(half).latest().name == "step_000002.pt"
    train_kpcn(cfg(tiny_dataset), half, resume=True, progress=False)
    a = torch.load(RunFolder(straight).latest(), weights_only=True)
    b = torch.load(RunFolder(half).latest(), weights_only=True)
    assert a["step"] == b["step"] == 4
    assert a["model"].keys() == b["model"].keys()
    for k, v in a["model"].items():
        assert torch.equal(v, b["model"][k]), k
    ma = torch.load(straight / "model.pt", weights_only=True)["state"]
    mb = torch.load(half / "model.pt", weights_only=True)["state"]
    for k, v in ma.items():
        assert torch.equal(v, mb[k]), k
    # the steps after the checkpoint did change the weights (the comparison is not vacuous)
    first = torch.load(RunFolder(straight).checkpoint_files()[0], weights_only=True)
    assert first["step"] == 2
    assert any(not torch.equal(v, first["model"][k]) for k, v in a["model"].items())
    assert [r["step"] for r in RunFolder(half).read_metrics()] == [2, 4]


# --- (d) fine-tuning a new encoder ------------------------------------------------------------


def _record_start(monkeypatch: pytest.MonkeyPatch, builder: str) -> dict[str, torch.Tensor]:
    """Wrap ``train.kpcn.<builder>`` so the returned dict receives the model's starting weights."""
    start: dict[str, torch.Tensor] = {}
    real = getattr(train_kpcn_module, builder)

    def spy(*args):
        model = real(*args)
        start.update({k: v.detach().clone() for k, v in model.state_dict().items()})
        return model

    monkeypatch.setattr(train_kpcn_module, builder, spy)
    return start


def test_finetune_encoder_trains_only_that_encoder(
    base_run: Path, tiny_dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fresh = _record_start(monkeypatch, "_finetune_model")
    out = tmp_path / "color"
    r = CliRunner().invoke(
        main,
        [
            "train",
            "--finetune-encoder",
            "color",
            "--from",
            str(base_run),
            "--data",
            str(tiny_dataset),
            "--out",
            str(out),
            "--quiet",
            *itertools.chain.from_iterable(
                ("-s", f"{k}={v}") for k, v in TINY.items() if k != "model"
            ),
        ],
    )
    assert r.exit_code == 0, r.output
    base = KpcnModel.load(base_run)
    tuned = KpcnModel.load(out)
    assert tuned.card.sources == ["full", "basic", "color"]
    # the card records where the trunk came from (and how that was trained)
    assert tuned.card.training["base"] == str(base_run)
    assert tuned.card.training["base_training"]["config"]["sources"] == ["full", "basic"]
    assert set(tuned.card.stats) == {"full", "basic", "color"}
    new = tuned.state_dict()
    old = base.state_dict()
    color = [k for k in new if k.startswith(("encoders.color.", "norms.color."))]
    assert color and all(k not in old for k in color)
    frozen = [k for k in new if k not in color]
    assert set(frozen) == set(old)  # trunk, heads, compositor, the other encoders and norms
    for k in frozen:
        assert torch.equal(new[k], old[k]), k
    weights = [k for k in color if k.startswith("encoders.color.")]
    assert fresh and any(not torch.equal(new[k], fresh[k]) for k in weights)
    metrics = RunFolder(out).read_metrics()
    assert "val_color_geomean" in metrics[-1] and "val_full_geomean" not in metrics[-1]
    # the tuned model serves colour-only inputs, and still the others as the base did
    b = load_buffers(tiny_dataset / "materials.exr", part="spp16")
    assert bool(torch.isfinite(denoise_kpcn(tuned, b.subset(["color"]))).all())
    assert torch.equal(
        denoise_kpcn(tuned, b, source="basic"), denoise_kpcn(base, b, source="basic")
    )


def test_continued_training_starts_from_every_base_weight(
    base_run: Path, tiny_dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    start = _record_start(monkeypatch, "_continued_model")
    out = tmp_path / "more"
    train_kpcn(cfg(tiny_dataset, base=base_run, lr=1e-2), out, progress=False)
    base = KpcnModel.load(base_run)
    more = KpcnModel.load(out)
    old = base.state_dict()
    assert set(start) == set(old)
    for k, v in old.items():
        assert torch.equal(start[k], v), k  # it started from the base, not a fresh init
    new = more.state_dict()
    # every part trained: trunk, heads and both encoders moved
    for prefix in ("encoders.full.", "encoders.basic.", "down.", "up.", "heads.", "alphas."):
        keys = [k for k in new if k.startswith(prefix) and new[k].is_floating_point()]
        assert keys and any(not torch.equal(new[k], old[k]) for k in keys), prefix
    assert more.card.training["base"] == str(base_run)
    assert more.card.stats["full"].names == base.card.stats["full"].names
    assert more.card.stats["full"].mean == base.card.stats["full"].mean


def test_continued_training_refuses_another_architecture(
    base_run: Path, tiny_dataset: Path, tmp_path: Path
) -> None:
    with pytest.raises(InputError, match=r"kernel 7 \(base: 5\)"):
        build(cfg(tiny_dataset, base=base_run, kernel=7))
    with pytest.raises(InputError, match="kpcn models only"):
        cfg(tiny_dataset, base=base_run, model="kalantari-xbf")


def test_a_base_without_albedo_kernels_continues_with_them(
    base_run: Path, tiny_dataset: Path, tmp_path: Path
) -> None:
    base = KpcnModel.load(base_run)
    assert not base.card.albedo_kernels
    task, _, _ = build(cfg(tiny_dataset, base=base_run, albedo_kernels="true"))
    model = task.model
    assert model.card.albedo_kernels
    old, new = base.state_dict(), model.state_dict()
    assert set(new) - set(old) == {"albedo_head.weight", "albedo_head.bias"}
    for k, v in old.items():
        assert torch.equal(new[k], v), k
    model.save(tmp_path / "m.pt")
    with pytest.raises(InputError, match=r"albedo_kernels false \(base: true\)"):
        build(cfg(tiny_dataset, base=tmp_path / "m.pt"))
    # a fresh model with them trains (the head moves)
    out = tmp_path / "fresh"
    train_kpcn(cfg(tiny_dataset, albedo_kernels="true", lr=1e-2), out, progress=False)
    trained = KpcnModel.load(out)
    assert trained.card.albedo_kernels
    assert trained.albedo_head.weight.abs().sum().item() > 0


def test_validation_reports_how_much_each_scale_is_used(tiny_dataset: Path) -> None:
    task, _, _ = build(cfg(tiny_dataset))
    res = task.validate()
    assert set(k for k in res if k.startswith("val_scale")) == {
        "val_scale1_weight",
        "val_scale2_weight",
    }
    assert all(0 < res[f"val_scale{s}_weight"] < 1 for s in (1, 2))
    with torch.no_grad():  # a closed gate: the 1/4 scale no longer enters the 1/2 one
        task.model.alphas[1].weight.zero_()
        task.model.alphas[1].bias.fill_(-10.0)
    res = task.validate()
    assert res["val_scale2_weight"] < UNUSED_SCALE_WEIGHT <= res["val_scale1_weight"]


def test_cli_train_reports_scale_use_and_an_unused_scale(
    tiny_dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(
        train_kpcn_module.KpcnTask,
        "_scale_use",
        lambda self, device: {"val_scale1_weight": 0.6, "val_scale2_weight": 0.002},
    )
    flags = itertools.chain.from_iterable(
        ("-s", f"{k}={v}") for k, v in TINY.items() if k not in ("model", "steps")
    )
    args = ["train", "--model", "kpcn", "--data", str(tiny_dataset), "--out", str(tmp_path / "r")]
    r = CliRunner().invoke(main, [*args, "--steps", "2", "--quiet", *flags])
    assert r.exit_code == 0, r.output
    assert (
        "scale use (mean compositor weight on the validation images): 1/2 0.600, 1/4 0.002; "
        "the 1/4 scale is unused (its gate closed in training)" in r.output
    )
    assert "1/2 scale is unused" not in r.output


# --- (e) augmentation ------------------------------------------------------------------------


#: Tensors of the augmentation tests and their channel counts.
AUG_KEYS = [("color", 3), ("albedo", 3), ("reference", 3), ("normal", 3), ("depth", 1), ("mask", 1)]


def _augment_batch(n: int = 64, size: int = 6) -> dict[str, torch.Tensor]:
    """Tensors sharing one random pattern per crop, each channel offset by a label
    ``10 (index + 1) + channel``, so the transform and the channel order can be read back."""
    g = torch.Generator().manual_seed(3)
    pattern = torch.rand(n, 1, size, size, generator=g)
    batch = {}
    for i, (key, ch) in enumerate(AUG_KEYS):
        labels = torch.tensor([10.0 * (i + 1) + c for c in range(ch)]).view(1, ch, 1, 1)
        batch[key] = pattern + labels
    batch["source"] = torch.arange(n) % 2
    return batch


def _dihedral(x: torch.Tensor) -> list[torch.Tensor]:
    """The 8 flips/rotations of an ``(C, H, W)`` square image."""
    rots = [torch.rot90(x, k, dims=(-2, -1)) for k in range(4)]
    return rots + [r.flip(-1) for r in rots]


def test_augment_is_deterministic_for_a_seeded_generator() -> None:
    batch = _augment_batch()
    a = augment(batch, torch.Generator().manual_seed(7), COLOR_TENSORS)
    b = augment(batch, torch.Generator().manual_seed(7), COLOR_TENSORS)
    c = augment(batch, torch.Generator().manual_seed(8), COLOR_TENSORS)
    assert a.keys() == batch.keys()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not torch.equal(a["color"], c["color"])
    assert torch.equal(a["source"], batch["source"])  # not an image: passed through


def test_augment_keeps_values_and_moves_every_tensor_alike() -> None:
    batch = _augment_batch()
    out = augment(batch, torch.Generator().manual_seed(11), COLOR_TENSORS)
    seen_transforms, seen_perms = set(), set()
    for i in range(batch["color"].shape[0]):
        for k, _ in AUG_KEYS:  # the multiset of values of every tensor of every crop is kept
            assert torch.equal(
                out[k][i].flatten().sort().values, batch[k][i].flatten().sort().values
            )
        # depth (label 50) went through one of the 8 flips/rotations of the square ...
        moved = out["depth"][i]
        which = [j for j, o in enumerate(_dihedral(batch["depth"][i])) if torch.equal(o, moved)]
        assert len(which) == 1, i
        seen_transforms.add(which[0])
        perms = {}
        for idx, (k, _) in enumerate(AUG_KEYS):
            # ... and every other tensor through the same one: it differs from depth by a
            # constant label per channel, which also tells where each channel went
            diff = out[k][i] - moved + 50.0
            labels = diff.mean((1, 2)).round()
            torch.testing.assert_close(
                diff, labels.view(-1, 1, 1).expand_as(diff), atol=1e-5, rtol=0
            )
            perms[k] = [int(v) - 10 * (idx + 1) for v in labels.tolist()]
        # one channel permutation per crop, the same for colour, albedo and reference
        assert perms["color"] == perms["albedo"] == perms["reference"], (i, perms)
        assert sorted(perms["color"]) == [0, 1, 2]
        seen_perms.add(tuple(perms["color"]))
        assert perms["normal"] == [0, 1, 2]  # the normal is not a colour: order kept
    assert len(seen_transforms) == 8 and len(seen_perms) == 6  # every variant is drawn


def test_sampler_transform_applies_the_augmentation_reproducibly(tiny_dataset: Path) -> None:
    _, sampler, _ = build(cfg(tiny_dataset))
    a = sampler.batch(4, torch.Generator().manual_seed(2))
    b = sampler.batch(4, torch.Generator().manual_seed(2))
    assert all(torch.equal(a[k], b[k]) for k in a)
    # every crop is shown as one of the trained sources, both of them in a batch of 4
    assert sorted(set(a["source"].tolist())) == [0, 1]
    assert a["color"].shape == (4, 3, 32, 32) and a["mask"].shape == (4, 1, 32, 32)


# --- (f) the command line ---------------------------------------------------------------------


def _one_line_error(result) -> str:
    assert result.exit_code not in (0, None), result.output
    err = result.stderr.strip()
    assert "Traceback" not in result.output + err
    assert len(err.splitlines()) == 1, err
    assert "internal error" not in err, err
    return err


def test_cli_train_kpcn_then_denoise_with_the_run(tiny_dataset: Path, tmp_path: Path) -> None:
    run = tmp_path / "runs" / "kpcn"
    flags = itertools.chain.from_iterable(
        ("-s", f"{k}={v}") for k, v in TINY.items() if k not in ("model", "steps")
    )
    args = ["train", "--model", "kpcn", "--data", str(tiny_dataset), "--out", str(run)]
    r = CliRunner().invoke(main, [*args, "--steps", "2", "--quiet", *flags])
    assert r.exit_code == 0, r.output
    assert "trained kpcn for 2 steps" in r.output
    assert (run / "model.pt").is_file()
    src = SAMPLES / "dof_spp4.exr"
    out = tmp_path / "out.exr"
    # no --method: the model file says it is a kpcn model
    r = CliRunner().invoke(main, ["denoise", str(src), "--model", str(run), "-o", str(out)])
    assert r.exit_code == 0, r.output
    b = load_buffers(out)
    assert b.attributes["mcdenoise:method"] == "kpcn"
    assert str(run) in b.attributes["mcdenoise:params"]
    assert b["color"].shape == (3, 128, 128)
    assert bool(torch.isfinite(b["color"]).all()) and bool((b["color"] >= 0).all())
    want = denoise_kpcn(KpcnModel.load(run), load_buffers(src), tile=1024, precision="auto")
    torch.testing.assert_close(b["color"], want)


def test_cli_kpcn_with_a_missing_model_fails_in_one_line(tmp_path: Path) -> None:
    out = tmp_path / "out.exr"
    r = CliRunner().invoke(
        main,
        [
            "denoise",
            str(SAMPLES / "cornell_spp4.exr"),
            "--method",
            "kpcn",
            "-p",
            "model=/nonexistent",
            "-o",
            str(out),
        ],
    )
    err = _one_line_error(r)
    assert "/nonexistent" in err
    assert not out.exists()


def test_the_cli_warns_when_the_model_ends_worse_than_its_noisy_input(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from mcdenoise.train.loop import TrainResult
    from mcdenoise.train.patches import LoadReport

    def collapsed(cfg, out, *, resume=False, progress=True):
        metrics = [{"step": 8, "val_full_ratio_to_noisy": 7.9, "val_basic_ratio_to_noisy": 0.2}]
        return TrainResult(8, 0.47, 0, 1.0, metrics), LoadReport(used=4)

    monkeypatch.setattr(train_kpcn_module, "train_kpcn", collapsed)
    r = CliRunner().invoke(
        main, ["train", "--model", "kpcn", "--data", str(tmp_path), "--out", str(tmp_path / "r")]
    )
    assert r.exit_code == 0, r.output
    assert "worse than its noisy input (full 7.90x)" in r.output
    assert "basic" not in r.output.split("warning:")[1]


# --- (f) prefiltered basic crops and exposure augmentation (issue 21) ---------------------------


def test_basic_crops_get_the_prefiltered_features_inference_uses(tiny_dataset: Path) -> None:
    task, sampler, _ = build(cfg(tiny_dataset, prefilter="auto", augment="false"))
    it = sampler.items[0]
    raw = load_buffers(it.entry.path, part=it.entry.part)
    basic = prepare_tensors(raw.subset(["color", "albedo", "normal"]), "basic", "auto")
    torch.testing.assert_close(it.tensors["albedo" + BASIC_SUFFIX], basic["albedo"])
    torch.testing.assert_close(it.tensors["normal" + BASIC_SUFFIX], basic["normal"])
    full = prepare_tensors(raw, "full", "off")  # the full crops keep the rendered features
    assert torch.equal(it.tensors["albedo"], full["albedo"])
    batch = sampler.batch(6, torch.Generator().manual_seed(0))
    assert not any(k.endswith(BASIC_SUFFIX) for k in batch)
    sources = task.model.card.sources
    kinds = {sources[int(c)] for c in batch["source"]}
    assert kinds == {"full", "basic"}
    # without the option the item has no extra tensors
    _, plain, _ = build(cfg(tiny_dataset))
    assert not any(k.endswith(BASIC_SUFFIX) for k in plain.items[0].tensors)


def test_use_basic_features_swaps_only_the_flagged_crops() -> None:
    a, b = torch.zeros(3, 3, 4, 4), torch.ones(3, 3, 4, 4)
    batch = {"albedo": a, "albedo" + BASIC_SUFFIX: b, "normal": a + 2, "color": a + 5}
    out = use_basic_features(batch, torch.tensor([False, True, False]))
    assert set(out) == {"albedo", "normal", "color"}
    assert torch.equal(out["albedo"][1], b[1]) and torch.equal(out["albedo"][0], a[0])
    assert torch.equal(out["normal"], a + 2)  # no prefiltered normal given: unchanged


def test_exposure_scales_colour_reference_and_variance_only() -> None:
    g = torch.Generator().manual_seed(1)
    batch = {
        k: torch.rand(2, c, 4, 4, generator=g)
        for k, c in (("color", 3), ("reference", 3), ("color_var", 1), ("albedo", 3))
    }
    out = augment_exposure(batch, torch.tensor([2.0, 0.5]))
    torch.testing.assert_close(out["color"][0], 2 * batch["color"][0])
    torch.testing.assert_close(out["reference"][1], 0.5 * batch["reference"][1])
    torch.testing.assert_close(out["color_var"][0], 4 * batch["color_var"][0])
    assert torch.equal(out["albedo"], batch["albedo"])


def test_training_with_exposure_and_prefilter_runs(tiny_dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    train_kpcn(cfg(tiny_dataset, exposure=2, prefilter="auto"), out, progress=False)
    assert KpcnModel.load(out).card.training["config"]["prefilter"] == "auto"
    # normalize_exposure: every training image (noisy and reference alike) is brought into
    # the range inference brings it to
    _, plain, _ = build(cfg(tiny_dataset, augment="false"))
    _, normed, _ = build(cfg(tiny_dataset, augment="false", normalize_exposure="true"))
    for a, b in zip(plain.items, normed.items, strict=True):
        k = exposure_scale(a.tensors["color"])
        torch.testing.assert_close(b.tensors["color"], a.tensors["color"] * k)
        torch.testing.assert_close(b.tensors["reference"], a.tensors["reference"] * k)
        assert exposure_scale(b.tensors["color"]) == pytest.approx(1.0, rel=1e-5)
    with pytest.raises(InputError, match="prefilter must be"):
        cfg(tiny_dataset, prefilter="some")
    with pytest.raises(InputError, match="exposure must be"):
        cfg(tiny_dataset, exposure=-1)


def test_finetune_keep_trains_the_base_encoder_further_and_nothing_else(
    base_run: Path, tiny_dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    start = _record_start(monkeypatch, "_finetune_model")
    out = tmp_path / "basic"
    kw = {"base": base_run, "finetune_encoder": "basic", "finetune_keep": "true", "lr": 1e-2}
    train_kpcn(cfg(tiny_dataset, prefilter="auto", **kw), out, progress=False)
    base, tuned = KpcnModel.load(base_run), KpcnModel.load(out)
    old, new = base.state_dict(), tuned.state_dict()
    assert set(new) == set(old)
    for k, v in old.items():
        assert torch.equal(start[k], v), k  # it started from the base's own encoder
    moved = [k for k in new if not torch.equal(new[k], old[k])]
    assert moved and all(k.startswith("encoders.basic.") for k in moved)
    assert tuned.card.stats["basic"].mean == base.card.stats["basic"].mean
    with pytest.raises(InputError, match="finetune_keep needs finetune_encoder"):
        cfg(tiny_dataset, finetune_keep="true")
    with pytest.raises(InputError, match="needs a base with a 'color' encoder"):
        build(cfg(tiny_dataset, **{**kw, "finetune_encoder": "color"}))
