"""The shipped Kalantari weights: present, loadable, and useful right after install."""

from __future__ import annotations

import pytest

from mcdenoise.denoise import denoise
from mcdenoise.eval.metrics import relmse
from mcdenoise.io import load_buffers
from mcdenoise.models.weights import load_kalantari, shipped_model_path
from mcdenoise.prep.kpcn import source_for


@pytest.mark.parametrize("kind", ["xbf", "nlm"])
def test_shipped_models_load_and_denoise_a_sample(samples_dir, kind) -> None:
    path = shipped_model_path(f"kalantari-{kind}")
    assert path.is_file() and path.stat().st_size < 500_000
    model = load_kalantari(path)
    assert model.card.kind == kind and model.card.guides == [
        "albedo",
        "normal",
        "depth",
        "position",
    ]
    # trained on data disjoint from every reported evaluation (seed 1000 random scenes)
    # the random scenes of seed 1000 and the wide ones of seed 5000 (issue 34), never the
    # held-out seed 2000 or a hand-written scene
    assert all(
        name.startswith(("random_s1000_", "random_wide_s5000_"))
        for name in model.card.training["train_images"]
    )
    b = load_buffers(samples_dir / "cornell_spp16.exr")
    ref = load_buffers(samples_dir / "ref" / "cornell.exr")["color"]
    out = denoise(b, f"kalantari-{kind}").image
    assert relmse(out, ref) < 0.2 * relmse(b["color"], ref)


def test_auto_prefers_the_learned_filters_and_falls_back_without_features(samples_dir) -> None:
    from mcdenoise.registry import best_method

    b = load_buffers(samples_dir / "cornell_spp4.exr")
    kpcn = shipped_model_path("kpcn").is_file()
    assert best_method(b).name == ("kpcn" if kpcn else "kalantari-xbf")
    assert best_method(b.subset([n for n in b.names() if n != "albedo"])).name == "kalantari-xbf"
    colour_only = b.subset(["color", "color_var"])
    assert best_method(colour_only).name == "nlm"


def test_inputs_without_albedo_use_the_shipped_no_albedo_variant(samples_dir) -> None:
    from mcdenoise.models.weights import NO_ALBEDO
    from mcdenoise.registry import best_method

    variant = shipped_model_path("kalantari-xbf", NO_ALBEDO)
    assert variant.is_file()
    assert load_kalantari(variant).card.guides == ["normal", "depth", "position"]
    b = load_buffers(samples_dir / "cornell_spp16.exr")
    no_albedo = b.subset([n for n in b.buffers if not n.startswith("albedo")])
    assert best_method(no_albedo).name == "kalantari-xbf"
    ref = load_buffers(samples_dir / "ref" / "cornell.exr")["color"]
    out = denoise(no_albedo, "kalantari-xbf").image
    assert relmse(out, ref) < 0.2 * relmse(b["color"], ref)
    # the NLM model has no such variant: it still refuses by name
    import pytest as _pytest

    from mcdenoise.io.buffers import MissingFeatureError

    with _pytest.raises(MissingFeatureError, match="albedo"):
        denoise(no_albedo, "kalantari-nlm")


def test_shipped_kpcn_loads_and_denoises_both_sources(samples_dir) -> None:
    from mcdenoise.models.weights import load_kpcn, model_method

    path = shipped_model_path("kpcn")
    assert path.is_file() and path.stat().st_size < 5_000_000  # "a few MB"
    assert model_method(path) == "kpcn"
    model = load_kpcn(path)
    assert model.card.sources == ["full", "basic"]
    # the random scenes of seed 1000 and the wide ones of seed 5000 (issue 34), never the
    # held-out seed 2000 or a hand-written scene
    assert all(
        name.startswith(("random_s1000_", "random_wide_s5000_"))
        for name in model.card.training["train_images"]
    )
    ref = load_buffers(samples_dir / "ref" / "cornell.exr")["color"]
    # at 16 spp most of what is left is light bled into the dark ceiling pixels along the
    # emitter's edge (0.35x / 0.24x the noisy relMSE, 73 % of it in 30 pixels; the weights
    # shipped before 2026-11-22's second session: 0.16x / 0.18x); the per-scale-loss model of
    # docs/results/kpcn.md (runs/kpcn8-sl05), which bleeds more, fails the 0.4 bound on `basic` (0.49x)
    for spp, bound in ((4, 0.2), (16, 0.4)):
        b = load_buffers(samples_dir / f"cornell_spp{spp}.exr")
        full = denoise(b, "kpcn").image
        basic = denoise(b.subset(["color", "albedo", "normal"]), "kpcn").image
        assert source_for(b, model.card.sources) == "full"
        noisy = relmse(b["color"], ref)
        assert relmse(full, ref) < bound * noisy and relmse(basic, ref) < bound * noisy, spp
    # ranked first (issue 21: out of distribution and at 4K, docs/results/ood.md), also on
    # full renders; nlm without the normal
    from mcdenoise.registry import best_method

    assert best_method(b).name == "kpcn"
    assert best_method(b.subset(["color", "albedo", "normal"])).name == "kpcn"
    assert best_method(b.subset(["color", "albedo"])).name == "nlm"  # kpcn needs the normal


def test_every_shipped_model_file_names_its_own_method() -> None:
    """``denoise --model FILE`` without ``--method`` runs the method the file's card names:
    every shipped file, nnao's included (it was taken for a Kalantari file and refused)."""
    from mcdenoise.models.weights import model_method

    folder = shipped_model_path("kpcn").parent
    got = {p.stem: model_method(p) for p in sorted(folder.glob("*.pt"))}
    assert got == {
        "auxnet": "auxnet",
        "kalantari-nlm": "kalantari-nlm",
        "kalantari-xbf-noalbedo": "kalantari-xbf",
        "kalantari-xbf": "kalantari-xbf",
        "kpcn-learned": "kpcn",
        "kpcn-temporal": "kpcn-temporal",
        "kpcn-temporal-causal": "kpcn-temporal",
        "kpcn": "kpcn",
        "nnao": "nnao",
    }
