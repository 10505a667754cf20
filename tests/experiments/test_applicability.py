"""Only the methods that apply to a scene run on it (mcdenoise.experiments.applicability,
issue 39): a temporal method on still images, an AO estimator on colour renders and a
half-buffer method without halves are listed as not run, with the reason, and leave no
"could not run" cell; a method that applies to some scenes runs on those only."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from synthetic_data import FakeMethods, blend, make_render_folder, write_spec

from mcdenoise.experiments import applicability as A
from mcdenoise.experiments import load_experiment, run_experiment
from mcdenoise.experiments.entries import MethodEntry
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.registry import get_method


def _entry(name: str) -> MethodEntry:
    return MethodEntry(name, get_method(name).name)


def _colour(halves: bool = False) -> FeatureBuffers:
    g = torch.Generator().manual_seed(0)
    b = {k: torch.rand(3, 16, 16, generator=g) for k in ("color", "albedo", "normal")}
    b["depth"] = torch.rand(1, 16, 16, generator=g) + 1
    if halves:
        b["color_a"], b["color_b"] = b["color"] * 0.9, b["color"] * 1.1
    return FeatureBuffers(b, spp=4)


STILL = SimpleNamespace(id="still", is_sequence=False)
SEQUENCE = SimpleNamespace(id="seq", is_sequence=True)


def test_temporal_methods_apply_to_sequences_only() -> None:
    for name in ("kpcn-temporal", "svgf"):
        assert A.why_not(_entry(name), STILL, _colour()) == A.TEMPORAL_ON_STILLS
        assert A.why_not(_entry(name), SEQUENCE, _colour()) is None
    assert A.why_not(MethodEntry("noisy", "noisy"), STILL, _colour()) is None


def test_an_ao_estimator_does_not_apply_to_a_colour_render() -> None:
    b = _colour()
    b.source = "data/cornell.exr"
    b.attributes["mcdenoise:effects"] = "direct,indirect"
    why = A.why_not(_entry("gtao"), STILL, b)
    assert why is not None and why.startswith("a render of direct,indirect light, not of ambient")


def test_nfor_applies_where_the_render_has_halves() -> None:
    why = A.why_not(_entry("nfor"), STILL, _colour())
    assert why is not None and "color_a" in why
    assert A.why_not(_entry("nfor"), STILL, _colour(halves=True)) is None


def test_a_method_missing_a_required_buffer_says_which() -> None:
    plain = FeatureBuffers({"color": torch.rand(3, 8, 8)}, spp=4)
    why = A.why_not(_entry("kalantari-xbf"), STILL, plain)
    assert why is not None and "depth" in why and "position" in why


def test_the_plan_keeps_partial_methods_where_they_apply_and_drops_the_rest(monkeypatch) -> None:
    levels = (SimpleNamespace(spp=1), SimpleNamespace(spp=4))
    scenes = [SimpleNamespace(id=n, is_sequence=False, levels=levels) for n in ("a", "b")]
    # halves only at 4 spp of scene a (one sample cannot be split in two)
    bufs = {("a", 1): _colour(), ("a", 4): _colour(halves=True)}
    monkeypatch.setattr(A, "level_buffers", lambda s, lv: bufs.get((s.id, lv.spp), _colour()))
    entries = [MethodEntry("noisy", "noisy"), _entry("nlm"), _entry("nfor"), _entry("svgf")]
    plan = A.plan_applicable(entries, scenes)
    assert [e.label for e in plan.entries] == ["noisy", "nlm", "nfor"]
    assert {r for r in plan.runs if r[0] == "nfor"} == {("nfor", "a", 4)}
    assert len({r for r in plan.runs if r[0] in ("noisy", "nlm")}) == 8
    assert plan.not_run == {"svgf": A.TEMPORAL_ON_STILLS}
    assert set(plan.partial["nfor"]) == {("a", 1), ("b", 1), ("b", 4)}
    lines = plan.notes()
    assert lines[0].startswith("svgf: a temporal method")
    assert lines[1].startswith("nfor: not on a at 1 spp, b at 1 spp, b at 4 spp: needs the half")


@pytest.fixture
def experiment(tmp_path, monkeypatch):
    make_render_folder(tmp_path / "rendered", scenes=("alpha", "beta"), size=(16, 16))
    spec = write_spec(
        tmp_path / "exp.toml",
        """
name = "applies"
methods = ["box", "svgf", "gtao", "nfor"]
metrics = ["relmse"]
repetitions = 1
warmup = 0
[scenes]
folder = "rendered"
[stats]
baseline = "noisy"
bootstrap = 100
""",
    )
    FakeMethods(monkeypatch).add("box", blend)
    return run_experiment(load_experiment(spec), tmp_path / "out"), tmp_path / "out"


def test_an_experiment_runs_only_what_applies_and_says_why_in_one_line_each(experiment) -> None:
    summary, out = experiment
    result = summary.result
    assert result.labels == ["noisy", "box"]
    assert {r["method"] for r in result.records} == {"noisy", "box"}
    assert not any(r.get("error") for r in result.records)
    assert not any("could not run" in n for n in result.notes)
    lines = result.not_applicable
    assert [line.split(":")[0] for line in lines] == ["svgf", "gtao", "nfor"]
    page = (out / "report.html").read_text(encoding="utf-8")
    assert "could not run" not in page
    assert page.count("not run: ") == 3 and "not run: svgf: a temporal method" in page


def test_render_halves_is_a_spec_key(tmp_path) -> None:
    from mcdenoise.experiments.spec_fields import ExperimentError

    cornell = Path(__file__).resolve().parents[2] / "data" / "scenes" / "cornell.toml"
    body = f'name = "h"\n[scenes]\nspecs = ["{cornell}"]\n[render]\nhalves = %s\n'
    spec = write_spec(tmp_path / "a.toml", body % "true")
    assert load_experiment(spec).halves is True
    bad = write_spec(tmp_path / "b.toml", body % '"yes"')
    with pytest.raises(ExperimentError, match=r"render\.halves"):
        load_experiment(bad)
