"""``mcdenoise eval --experiment SPEC --shard I/N`` and ``--merge`` (issue 26 item 5): two
shards and a merge give the results.csv of one run (up to the timing columns); the merge
refuses, in one line naming the shards, while a share is missing; unit records name their
host and the report says when times come from several machines."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from click.testing import CliRunner
from mcdenoise_cli.main import main
from scene_specs import BALL_SCENE
from synthetic_data import blend, make_render_folder, write_spec

from mcdenoise.experiments.shards import host_name, shard_units

SPEC = """
name = "shards"
methods = ["box", "soft"]
metrics = ["relmse", "psnr"]
repetitions = 1
warmup = 0
[scenes]
folder = "rendered"
[report]
strip_spp = 2
"""
#: Columns of results.csv that depend on the clock or the machine, not on the data.
TIMING = {"denoise_seconds", "total_seconds", "denoise_runs", "pareto", "speedup", "host"}


def run(*args: str):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as f:
        return [{k: v for k, v in r.items() if k not in TIMING} for r in csv.DictReader(f)]


@pytest.fixture
def spec(tmp_path, fake_methods, monkeypatch):
    # no figures: what is compared here is the data (and drawing them is most of a report's time)
    monkeypatch.setattr(
        "mcdenoise.experiments.plots.plots_unavailable", lambda: "not drawn in tests"
    )
    fake_methods.add("box", blend)
    fake_methods.add("soft", blend, defaults={"strength": 0.5})
    make_render_folder(tmp_path / "rendered", scenes=("alpha", "beta"), size=(16, 16))
    return write_spec(tmp_path / "exp.toml", SPEC)


def test_two_shards_and_a_merge_equal_one_run(tmp_path, spec, fake_methods):
    one = run("eval", "--experiment", spec, "-o", tmp_path / "one")
    assert one.exit_code == 0, one.output
    calls = dict(fake_methods.calls)
    fake_methods.calls.clear()
    out = tmp_path / "sharded"
    first = run("eval", "--experiment", spec, "-o", out, "--shard", "1/2")
    assert first.exit_code == 0, first.output
    assert "shard 1/2: 9 unit(s)" in first.output  # 2 scenes x 3 levels x 3 columns = 18
    assert not (out / "results.csv").exists()  # a shard writes no report

    early = run("eval", "--experiment", spec, "-o", out, "--merge")
    assert early.exit_code == 1
    err = early.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in early.output
    assert "9 of 18 units have no finished record" in err
    assert "never started: 2/2" in err

    second = run("eval", "--experiment", spec, "-o", out, "--shard", "2/2")
    assert second.exit_code == 0, second.output
    assert "shard 2/2: 9 unit(s)" in second.output
    # every unit ran exactly once over the two shards
    assert fake_methods.calls == calls
    fake_methods.calls.clear()
    merged = run("eval", "--experiment", spec, "-o", out, "--merge")
    assert merged.exit_code == 0, merged.output
    assert "ran 0 unit(s), reused 18 finished" in merged.output
    assert fake_methods.calls == {}
    assert rows(out / "results.csv") == rows(tmp_path / "one" / "results.csv")

    shard_record = json.loads((out / "work" / "shards" / "shard-2-of-2.json").read_text())
    assert shard_record["finished"] and len(shard_record["units"]) == 9
    with open(out / "results.csv", newline="", encoding="utf-8") as f:
        assert {r["host"] for r in csv.DictReader(f)} == {host_name()}


def test_a_merge_takes_each_shards_device_and_says_when_hosts_differ(tmp_path, spec):
    """Shards on GPU nodes record device cuda: a merge on a CPU-only machine still finds
    their records (the fingerprint is checked with the recorded device), and a record whose
    fingerprint matches no device is missing. Records of two hosts: the report says so."""
    from mcdenoise.experiments import load_experiment, plan_methods
    from mcdenoise.experiments.dataset import load_dataset
    from mcdenoise.experiments.runner import plan_units
    from mcdenoise.experiments.units import RunSettings, fingerprint

    out = tmp_path / "out"
    for i in (1, 2):
        assert run("eval", "--experiment", spec, "-o", out, "--shard", f"{i}/2").exit_code == 0
    settings = RunSettings(
        metrics=("relmse", "psnr"),
        repetitions=1,
        warmup=0,
        device="cuda",
        threads=None,
        save_output=lambda spp: True,
    )
    entries = plan_methods(load_experiment(spec))[0]
    units = plan_units(load_dataset(tmp_path / "rendered"), entries)
    for unit in units:
        rec = json.loads(unit.path(out).read_text())
        assert rec["run_device"] == "cpu" and rec["host"] == host_name()
        rec["run_device"] = "cuda"
        rec["fingerprint"] = fingerprint(unit, settings)
        if unit.entry.label == "soft":  # "ran on another machine"
            rec["host"] = "node-b"
        unit.path(out).write_text(json.dumps(rec))
    merged = run("eval", "--experiment", spec, "-o", out, "--merge")
    assert merged.exit_code == 0, merged.output + merged.stderr
    data = json.loads((out / "results.json").read_text())
    assert data["provenance"]["timing_hosts"] == {host_name(): 6, "node-b": 6}
    note = next(n for n in data["notes"] if "machines" in n)
    assert "measured on 2 machines" in note and "node-b (6 units)" in note
    html = (out / "report.html").read_text(encoding="utf-8")
    assert "measured on 2 machines" in html
    assert "<th>device, host</th>" in html and '<span class="sub">node-b</span>' in html

    for unit in units:  # fingerprinted with cuda, recorded as cpu: not this spec's record
        if unit.entry.label == "box":
            rec = json.loads(unit.path(out).read_text())
            rec["run_device"] = "cpu"
            unit.path(out).write_text(json.dumps(rec))
    bad = run("eval", "--experiment", spec, "-o", out, "--merge")
    assert bad.exit_code == 1 and "6 of 18 units have no finished record" in bad.stderr


def test_usage_errors_are_one_line(tmp_path, spec):
    both = run("eval", "--experiment", spec, "-o", tmp_path / "o", "--shard", "1/2", "--merge")
    assert both.exit_code == 2 and "not both" in both.output
    bad = run("eval", "--experiment", spec, "-o", tmp_path / "o", "--shard", "3/2")
    assert bad.exit_code != 0 and "1 <= i <= n" in bad.stderr
    alone = run("eval", "--ref", spec, "x.exr", "--merge")
    assert alone.exit_code == 2 and "--merge applies to --experiment" in alone.output


def test_shares_are_whole_scenes_when_the_spec_renders():
    class U:
        def __init__(self, scene, k):
            self.scene = type("S", (), {"id": scene})()
            self.k = k

    units = [U(s, k) for s in ("a", "b", "c") for k in range(4)]
    index = {"a": 0, "b": 1, "c": 2}
    one = shard_units(units, (1, 2), scene_index=index)
    two = shard_units(units, (2, 2), scene_index=index)
    assert {u.scene.id for u in one} == {"a", "c"} and {u.scene.id for u in two} == {"b"}
    assert len(one) + len(two) == len(units)


RENDER_SPEC = """
name = "render-shards"
methods = ["box"]
metrics = ["relmse"]
repetitions = 1
warmup = 0
[scenes]
specs = ["one.toml", "two.toml"]
[render]
resolution = 16
spp = [1, 2]
ref_spp = 16
variant = "scalar_rgb"
"""


@pytest.mark.mitsuba
@pytest.mark.slow
def test_shards_of_a_rendering_spec_render_and_run_their_own_scenes(tmp_path, fake_methods):
    fake_methods.add("box", blend)
    for name in ("one", "two"):
        (tmp_path / f"{name}.toml").write_text(BALL_SCENE.format(name=name), encoding="utf-8")
    spec = write_spec(tmp_path / "exp.toml", RENDER_SPEC)
    out = tmp_path / "out"
    first = run("eval", "--experiment", spec, "-o", out, "--shard", "1/2")
    assert first.exit_code == 0, first.output
    assert "rendered 1 image(s)" in first.output and "4 unit(s)" in first.output
    assert (out / "data" / "manifest.shard-1-of-2.json").is_file()
    assert sorted(p.name for p in (out / "work").iterdir()) == ["one", "shards"]
    early = run("eval", "--experiment", spec, "-o", out, "--merge")
    assert early.exit_code == 1
    assert "1 of 2 images are not rendered yet (shards never started: 2/2): two" in early.stderr
    extra = run("eval", "--experiment", spec, "-o", out, "--shard", "3/3")
    assert extra.exit_code == 0  # more shards than scenes: nothing to do
    second = run("eval", "--experiment", spec, "-o", out, "--shard", "2/2")
    assert "rendered 1 image(s)" in second.output
    merged = run("eval", "--experiment", spec, "-o", out, "--merge")
    assert merged.exit_code == 0, merged.output + merged.stderr
    assert "2 scene(s) x 2 spp level(s) x 2 method(s)" in merged.output
    # the plain command, once every share is done, renders nothing and reuses every unit
    plain = run("eval", "--experiment", spec, "-o", out)
    assert "rendered 0 image(s), reused 2; ran 0 unit(s), reused 8 finished" in plain.output
