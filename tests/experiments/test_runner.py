"""Tests of ``mcdenoise/experiments/runner.py`` on synthetic render folders (no Mitsuba):
units, timing bookkeeping, numbers recomputed from the written EXRs, resume after an
interruption, skipped and refusing methods, the reference's noise floor."""

from __future__ import annotations

import json
import math
import statistics
from pathlib import Path

import numpy as np
import pytest
from synthetic_data import (
    JIT_SECONDS,
    FakeMethods,
    blend,
    make_render_folder,
    refuse,
    write_spec,
)

from mcdenoise.eval.metrics import compute_metrics
from mcdenoise.experiments import ExperimentError, load_experiment, plan_methods, run_experiment
from mcdenoise.experiments.units import WORK, read_unit
from mcdenoise.io import load_buffers
from mcdenoise.io.atomic import TMP_PREFIX

RATE = 0.01  # synthetic seconds per spp


def no_constants(name):
    raise AssertionError(f"bare {name} in JSON")


def load_json(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"), parse_constant=no_constants)


def spec_file(tmp_path: Path, methods: str, extra: str = "", **folder_kw) -> Path:
    make_render_folder(tmp_path / "rendered", **folder_kw)
    return write_spec(
        tmp_path / "exp.toml",
        f"""
name = "synthetic"
methods = {methods}
metrics = ["relmse", "psnr"]
repetitions = 2
warmup = 1
[scenes]
folder = "rendered"
[report]
strip_spp = 2
{extra}
""",
    )


@pytest.fixture(scope="module")
def run_box(tmp_path_factory):
    """One experiment on two synthetic scenes with two fake methods, shared by the tests
    that only read its results."""
    tmp_path = tmp_path_factory.mktemp("runner")
    with pytest.MonkeyPatch.context() as mp:
        fake = FakeMethods(mp)
        fake.add("box", blend)
        fake.add("soft", blend, defaults={"strength": 0.5})
        spec = load_experiment(spec_file(tmp_path, '["box", "soft"]'))
        out = tmp_path / "out"
        summary = run_experiment(spec, out)
        yield summary, out, fake


def test_every_unit_runs_once_with_warmup_and_repetitions(run_box):
    summary, out, fake = run_box
    assert len(summary.ran) == 2 * 3 * 3 and summary.reused == []
    # 6 inputs per method, 1 warm-up + 2 timed runs each
    assert fake.calls == {"box": 18, "soft": 18}
    data = load_json(out / "results.json")
    assert data["schema"] == "mcdenoise.experiment/1"
    assert [m["label"] for m in data["methods"]] == ["noisy", "box", "soft"]
    recs = data["records"]
    assert len(recs) == 18
    for r in recs:
        n = r["spp"]
        # the manifest's cumulative seconds minus the JIT share of the first level
        assert r["render_seconds"] == pytest.approx(n * RATE, abs=1e-9)
        assert r["render_jit_seconds_excluded"] == pytest.approx(JIT_SECONDS)
        assert r["total_seconds"] == pytest.approx(r["render_seconds"] + r["denoise_seconds"])
        if r["method"] == "noisy":
            assert r["denoise_seconds"] == 0 and r["timing"] is None and r["output"] is None
        else:
            t = r["timing"]
            assert len(t["runs"]) == 2 and len(t["warmup"]) == 1
            assert r["denoise_seconds"] == statistics.median(t["runs"]) > 0
            assert t["threads"] >= 1 and r["device"] == "cpu"


def test_numbers_match_metrics_recomputed_from_the_written_exrs(run_box):
    _, out, _ = run_box
    data = load_json(out / "results.json")
    refs = {s["id"]: load_buffers(s["reference_file"])["color"] for s in data["scenes"]}
    checked = 0
    for r in data["records"]:
        if r["method"] == "noisy":
            image = load_buffers(r["input"]["file"], part=r["input"]["part"])["color"]
        else:
            exr = out / r["output"]
            image = load_buffers(exr)["color"]
            header = load_buffers(exr).attributes
            assert header["mcdenoise:label"] == r["method"]
            assert float(header["mcdenoise:seconds"]) == pytest.approx(r["denoise_seconds"])
        again = compute_metrics(image, refs[r["scene"]], ["relmse", "psnr"])
        assert r["metrics"]["relmse"] == again.values["relmse"]
        assert r["metrics"]["psnr"] == again.values["psnr"]
        checked += 1
    assert checked == 18
    csv_rows = (out / "results.csv").read_text().splitlines()
    assert len(csv_rows) == 19 and "relmse" in csv_rows[0].split(",")


def test_noisy_curve_floor_and_equal_quality_follow_the_synthetic_model(run_box):
    _, out, _ = run_box
    data = load_json(out / "results.json")
    for scene in data["scenes"]:
        curve = scene["noisy_curve"]
        assert curve["loglog_slope"] == pytest.approx(-1.0, abs=0.2)
        assert curve["seconds_per_spp"] == pytest.approx(RATE)
        ref = load_buffers(scene["reference_file"])["color"].double().numpy()
        expected = float(np.mean((0.3**2 / 4096) / (ref**2 + 0.01)))
        assert scene["noise_floor"] == pytest.approx(expected, rel=1e-5)
    for r in data["records"]:
        eq = r["equal_quality"]
        if r["method"] == "noisy":
            assert eq is None
            continue
        # a 3×3 box filter cuts white-noise variance ~9×: worth several times its spp
        if r["method"] == "box":
            assert eq["spp"] > 3 * r["spp"]
        assert (eq["extrapolated"] == "extrapolated") == (eq["spp"] > 4)
        assert eq["seconds"] == pytest.approx(eq["spp"] * RATE)
        assert eq["speedup"] == pytest.approx(eq["seconds"] / r["total_seconds"])
        assert r["relmse_vs_noisy"] < 1


def test_interrupted_run_resumes_without_redoing_finished_units(tmp_path: Path, fake_methods):
    fake_methods.add("box", blend)
    state = {"calls": 0}

    def explode_on_third(b, p, d):
        state["calls"] += 1
        if state["calls"] == 3:
            raise RuntimeError("simulated crash")
        return blend(b, p, d)

    fake_methods.add("boom", explode_on_third)
    path = spec_file(tmp_path, '["box", "boom"]', extra="", seed=1)
    text = path.read_text().replace("repetitions = 2\nwarmup = 1", "repetitions = 1\nwarmup = 0")
    path.write_text(text)
    spec = load_experiment(path)
    out = tmp_path / "out"
    with pytest.raises(RuntimeError, match="simulated crash"):
        run_experiment(spec, out)
    # scene alpha: spp1 and spp2 complete (3 units each), spp4: noisy and box done
    done = sorted(p.relative_to(out / WORK).as_posix() for p in (out / WORK).rglob("*.json"))
    assert len(done) == 8
    assert not (out / "results.json").exists()
    assert not any(p.name.startswith(TMP_PREFIX) for p in out.rglob("*"))
    before = {p: read_unit(out / WORK / p) for p in done}
    assert all(rec is not None and rec["schema"] for rec in before.values())  # complete JSON

    fake_methods.calls.clear()
    fake_methods.add("boom", blend)  # the same method (same parameters), no longer crashing
    summary = run_experiment(spec, out)
    assert len(summary.reused) == 8 and len(summary.ran) == 10
    assert fake_methods.calls == {"box": 3, "boom": 4}
    data = load_json(out / "results.json")
    assert len(data["records"]) == 18
    for p, rec in before.items():
        assert read_unit(out / WORK / p) == rec  # untouched
    by_key = {(r["scene"], r["spp"], r["method"]): r for r in data["records"]}
    for rec in before.values():
        assert by_key[(rec["scene"], rec["spp"], rec["method"])]["metrics"] == rec["metrics"]

    # a third run has nothing left to do
    fake_methods.calls.clear()
    again = run_experiment(spec, out)
    assert again.ran == [] and len(again.reused) == 18 and fake_methods.calls == {}


def test_retrained_weights_rerun_the_method_that_loads_them(tmp_path: Path, fake_methods):
    weights = tmp_path / "run" / "model.pt"
    weights.parent.mkdir()
    weights.write_bytes(b"first weights")
    fake_methods.add("box", blend)
    fake_methods.add("learned", blend, defaults={"strength": 1.0, "model": str(weights.parent)})
    path = spec_file(tmp_path, '["box", "learned"]', scenes=("alpha",))
    out = tmp_path / "out"
    run_experiment(load_experiment(path), out)
    fake_methods.calls.clear()
    assert run_experiment(load_experiment(path), out).ran == []  # same weights: all reused
    weights.write_bytes(b"retrained weights")  # same path, same parameters, other content
    summary = run_experiment(load_experiment(path), out)
    assert sorted(k[2] for k in summary.ran) == ["learned"] * 3 and len(summary.reused) == 6


def test_changed_parameters_rerun_only_that_method(tmp_path: Path, fake_methods):
    fake_methods.add("box", blend)
    fake_methods.add("soft", blend, defaults={"strength": 0.5})
    path = spec_file(tmp_path, '["box", "soft"]', scenes=("alpha",))
    out = tmp_path / "out"
    run_experiment(load_experiment(path), out)
    path.write_text(path.read_text() + "\n[params.soft]\nstrength = 0.25\n")
    fake_methods.calls.clear()
    summary = run_experiment(load_experiment(path), out)
    assert sorted(k[2] for k in summary.ran) == ["soft"] * 3 and len(summary.reused) == 6
    data = load_json(out / "results.json")
    assert {r["params"]["strength"] for r in data["records"] if r["method"] == "soft"} == {0.25}


def test_refusing_and_unavailable_methods_are_reported_not_fatal(tmp_path: Path, fake_methods):
    fake_methods.add("box", blend)
    fake_methods.add("picky", refuse)
    fake_methods.add("absent", unavailable=lambda: "needs the frobnicator package")
    spec = load_experiment(spec_file(tmp_path, '["box", "picky", "absent"]', scenes=("alpha",)))
    entries, skipped = plan_methods(spec)
    assert [e.label for e in entries] == ["noisy", "box", "picky"]
    assert skipped == {"absent": "needs the frobnicator package"}
    out = tmp_path / "out"
    run_experiment(spec, out)
    data = load_json(out / "results.json")
    assert data["skipped_methods"] == [
        {"label": "absent", "reason": "needs the frobnicator package"}
    ]
    picky = [r for r in data["records"] if r["method"] == "picky"]
    assert len(picky) == 3
    assert all(r["failed"] and r["error"] == "this method refuses every input" for r in picky)
    assert all(r["metrics"]["relmse"] is None and r["equal_quality"] is None for r in picky)
    assert any("picky could not run on 3 of 3 inputs" in n for n in data["notes"])
    page = (out / "report.html").read_text()
    assert "needs the frobnicator package" in page and "this method refuses every input" in page
    # the statistics leave the refusing method out instead of averaging nothing
    rows = [s for s in data["statistics"]["rows"] if s["method"] == "picky"]
    assert all(s["scenes"] == 0 and s["ratio"] is None for s in rows)


def test_all_methods_means_every_registered_one(tmp_path: Path, fake_methods):
    from mcdenoise.registry import methods

    fake_methods.add("zz-new", blend)
    fake_methods.add("zz-absent", unavailable=lambda: "not here")
    spec = load_experiment(spec_file(tmp_path, '"all"', scenes=("alpha",)))
    entries, skipped = plan_methods(spec)
    registered = [m.name for m in methods()]
    assert [e.label for e in entries] == ["noisy", *(n for n in registered if n not in skipped)]
    assert "zz-new" in [e.label for e in entries] and skipped["zz-absent"] == "not here"


def test_sweeps_get_labels_and_their_parameters(tmp_path: Path, fake_methods):
    fake_methods.add("box", blend)
    extra = '[[sweep]]\nmethod = "box"\nparam = "strength"\nvalues = [0.25, 1.0]\n'
    spec = load_experiment(spec_file(tmp_path, '["box"]', extra=extra, scenes=("alpha",)))
    entries, _ = plan_methods(spec)
    assert [e.label for e in entries] == ["noisy", "box", "box[strength=0.25]", "box[strength=1.0]"]
    assert entries[2].params() == {"strength": 0.25}
    # box and box[strength=1.0] are the same filter: identical errors
    out = tmp_path / "out"
    run_experiment(spec, out)
    data = load_json(out / "results.json")
    err = {(r["method"], r["spp"]): r["metrics"]["relmse"] for r in data["records"]}
    assert all(err[("box", n)] == err[("box[strength=1.0]", n)] for n in (1, 2, 4))
    assert all(err[("box[strength=0.25]", n)] > err[("box", n)] for n in (1, 2, 4))


def test_results_limited_by_a_noisy_reference_are_flagged(tmp_path: Path, fake_methods):
    fake_methods.add("box", blend)
    spec = load_experiment(spec_file(tmp_path, '["box"]', scenes=("alpha",), ref_spp=4))
    out = tmp_path / "out"
    run_experiment(spec, out)
    data = load_json(out / "results.json")
    floor = data["scenes"][0]["noise_floor"]
    for r in data["records"]:
        e = r["metrics"]["relmse"]
        assert r["limited_by_reference"] == (e < 2 * floor)
    flagged = {r["method"] for r in data["records"] if r["limited_by_reference"]}
    assert flagged == {"box"}  # the box filter's error is mostly the reference's own noise
    assert "the reference limits what can be measured" in (out / "report.html").read_text()


def test_outputs_strip_keeps_only_the_strip_level(tmp_path: Path, fake_methods):
    fake_methods.add("box", blend)
    extra = 'outputs = "strip"'
    spec = load_experiment(spec_file(tmp_path, '["box"]', extra=extra, scenes=("alpha",)))
    out = tmp_path / "out"
    run_experiment(spec, out)
    assert sorted(p.name for p in (out / "outputs").glob("*.exr")) == ["alpha_spp2_box.exr"]
    data = load_json(out / "results.json")
    kept = {r["spp"]: r["output"] for r in data["records"] if r["method"] == "box"}
    assert kept == {1: None, 2: "outputs/alpha_spp2_box.exr", 4: None}
    assert all(math.isfinite(r["metrics"]["relmse"]) for r in data["records"])


def test_a_render_folder_of_other_settings_is_refused(tmp_path: Path):
    scenes = Path(__file__).resolve().parents[2] / "data" / "scenes"
    make_render_folder(tmp_path / "out" / "data", shard_settings={"width": 7})
    path = write_spec(
        tmp_path / "exp.toml",
        f'[scenes]\nspecs = ["{scenes / "cornell.toml"}"]\n[render]\nresolution = 16\n'
        "spp = [1, 2]\nref_spp = 8\n",
    )
    with pytest.raises(ExperimentError, match="holds images rendered with other settings"):
        run_experiment(load_experiment(path), tmp_path / "out")


def test_every_unit_goes_through_the_one_entry_point(
    tmp_path: Path, fake_methods, monkeypatch: pytest.MonkeyPatch
):
    """The runner denoises through ``mcdenoise.denoise.denoise_sequence`` (a one-frame
    sequence per run), like ``mcdenoise denoise``: the same checks, sanitising and timing."""
    import mcdenoise.denoise as dn

    seen: list[tuple[str, int]] = []
    real = dn.denoise_sequence

    def spy(frames, method="auto", **kw):
        frames = list(frames)
        seen.append((method.name if isinstance(method, dn.Method) else method, len(frames)))
        return real(frames, method, **kw)

    monkeypatch.setattr(dn, "denoise_sequence", spy)
    fake_methods.add("box", blend)
    spec = load_experiment(spec_file(tmp_path, '["box"]', scenes=("alpha",)))
    run_experiment(spec, tmp_path / "out")
    # 3 spp levels, 1 warm-up + 2 timed runs each, one frame per call
    assert seen == [("box", 1)] * 9 and fake_methods.calls == {"box": 9}
