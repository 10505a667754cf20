"""benchmarks/bench_robust.py (issue 22's robustness rules) on a synthetic results.csv.

One scene, five spp levels, the noisy input, OIDN and three methods whose relMSE values are
chosen so that each rule fires where it must and stays silent just beside it: 10x OIDN's at
1 spp (rule (a) starts at 2 spp), 2.8x OIDN's (under 3x), a rise of 1.07x (under 1.1x), a
rise of 1.8x where the noisy input falls only 1.25x (rule (b) does not apply), a failed unit.
"""

from __future__ import annotations

import csv
import importlib.util
import json
import math
import sys
from pathlib import Path

import pytest

from mcdenoise.experiments.report_tables import CSV_HEAD, CSV_TAIL

ROOT = Path(__file__).resolve().parents[2]

SPP = (1, 2, 4, 8, 16)
#: relMSE per method and level; None: the unit produced no relMSE (a refused input).
VALUES = {
    "noisy": (10.0, 5.0, 2.5, 2.0, 1.0),  # falls 2x, 2x, 1.25x (8 spp: no rule b), 2x
    "oidn": (0.1, 0.08, 0.06, 0.05, 0.04),
    "m1": (1.0, 0.25, 0.17, 0.3, 0.32),  # a at 2 (3.1x), 8 (6x), 16 (8x); 4: 2.8x; 16: +7 %
    "m2": (0.1, 0.12, 0.13, 2.5, None),  # b at 2 (+20 %); 4: +8 %; a and c at 8 (> noisy)
    "m3": (0.1, 0.1, math.nan, 0.05, 0.04),  # NaN at 4: a, b and c
}
EXPECTED = {
    ("a", "m1", 2),
    ("a", "m1", 8),
    ("a", "m1", 16),
    ("a", "m2", 8),
    ("a", "m3", 4),
    ("b", "m2", 2),
    ("b", "m3", 4),
    ("c", "m2", 8),
    ("c", "m3", 4),
}


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location(
        "bench_robust", ROOT / "benchmarks" / "bench_robust.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop(spec.name, None)


def write_results(folder: Path, values=VALUES, scene: str = "glass") -> Path:
    """A results.csv with the columns the experiment report writes (relMSE only filled)."""
    folder.mkdir(parents=True, exist_ok=True)
    columns = [*CSV_HEAD, "relmse", *CSV_TAIL]
    with (folder / "results.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, columns)
        w.writeheader()
        for method, row in values.items():
            for spp, v in zip(SPP, row, strict=True):
                cells = dict.fromkeys(columns, "")
                cells.update(scene=scene, method=method, base_method=method, spp=spp)
                if v is None:
                    cells["error"] = "needs albedo"
                else:
                    cells["relmse"] = "nan" if math.isnan(v) else repr(v)
                w.writerow(cells)
    return folder


def test_each_rule_is_found_and_nothing_else(bench, tmp_path):
    rows, partial = bench.read_rows(write_results(tmp_path / "exp"))
    a = bench.analyse(rows, folder="exp")
    assert not partial
    assert {(v.rule, v.method, v.spp) for v in a.violations} == EXPECTED
    assert len(a.violations) == len(EXPECTED)  # no duplicates
    assert a.counts() == {"a": 5, "b": 2, "c": 2}
    assert a.by_method()["oidn"] == {"a": 0, "b": 0, "c": 0}
    assert [(m, n) for _, m, n, _ in a.not_measured] == [("m2", 16)]
    assert a.ratio("glass", "m1", 8) == pytest.approx(6.0)
    (b,) = [v for v in a.violations if (v.rule, v.method) == ("b", "m2")]
    assert b.factor == pytest.approx(1.2) and b.bound == pytest.approx(1.1 * 0.1)


def test_rule_b_applies_only_where_the_noisy_input_falls(bench, tmp_path):
    a = bench.analyse(bench.read_rows(write_results(tmp_path / "exp"))[0])
    assert [n for n in SPP if bench.b_applies(a, "glass", n)] == [2, 4, 16]


def test_without_oidn_rule_a_is_reported_unchecked(bench, tmp_path):
    values = {k: v for k, v in VALUES.items() if k != "oidn"}
    a = bench.analyse(bench.read_rows(write_results(tmp_path / "exp", values))[0])
    assert a.counts()["a"] == 0 and any(u.startswith("a:") for u in a.unchecked)
    assert a.counts()["b"] == 2 and a.counts()["c"] == 2


def test_command_line_table_json_and_comparison(bench, tmp_path, capsys):
    base = write_results(tmp_path / "base")
    fixed = dict(VALUES, m1=(1.0, 0.2, 0.17, 0.14, 0.1))  # m1 now within 3x OIDN
    new = write_results(tmp_path / "new", fixed)
    assert bench.main([str(base), str(new), "--json", str(tmp_path / "r.json")]) == 0
    out = capsys.readouterr().out
    assert "| glass | m1 | 10.0 | **3.12** a | 2.83 | **6.00** a | **8.00** a |" in out
    assert "| (a) | 5 | 2 |" in out and "| total | 9 | 6 |" in out
    assert "  - m2 / glass / 16 spp: needs albedo" in out  # listed, no rule broken
    # the relMSE change per method and spp (the no-regression target at 16/64 spp)
    assert "| m1 | 1.000 (1.00 glass) | 0.800 (0.80 glass) | 1.000 (1.00 glass) | " in out
    three = write_results(tmp_path / "three", {k: v for k, v in VALUES.items() if k != "m3"})
    assert bench.main([str(base), str(three)]) == 0
    out = capsys.readouterr().out
    assert "| (a)/(b)/(c) of the 3 methods in all | 4/1/1 | 4/1/1 |" in out
    assert f"{base} also has: m3" in out
    doc = json.loads((tmp_path / "r.json").read_text())
    assert [e["counts"] for e in doc["experiments"]] == [
        {"a": 5, "b": 2, "c": 2},
        {"a": 2, "b": 2, "c": 2},
    ]
    assert doc["relmse_changes"][0]["by_method"]["m1"]["16"]["geomean"] == pytest.approx(0.3125)
    assert bench.main([str(base), "--json", "-"]) == 0
    assert json.loads(capsys.readouterr().out)["experiments"][0]["total"] == 9
    assert bench.main([str(base), "--spp", "1,2,16", "--json", "-"]) == 0  # m1 at 2, 16; m2 1->2
    sub = json.loads(capsys.readouterr().out)["experiments"][0]
    assert sub["spp"] == [1, 2, 16] and sub["counts"] == {"a": 2, "b": 1, "c": 0}


def test_partial_experiment_is_read_from_the_unit_records(bench, tmp_path):
    work = tmp_path / "exp" / "work" / "glass"
    for method, row in VALUES.items():
        for spp, v in zip(SPP, row, strict=True):
            (work / f"spp{spp}").mkdir(parents=True, exist_ok=True)
            record = {"scene": "glass", "spp": spp, "method": method}
            record["metrics"] = {"relmse": None if v is None or math.isnan(v) else v}
            (work / f"spp{spp}" / f"{method}.json").write_text(json.dumps(record))
    rows, partial = bench.read_rows(tmp_path / "exp")
    assert partial and len(rows) == len(VALUES) * len(SPP)


@pytest.mark.parametrize(
    "content", [None, "scene,spp\nx,1\n", "scene,method,spp,relmse\nx,m,two,1\n"]
)
def test_unreadable_input_is_one_line_and_status_2(bench, tmp_path, capsys, content):
    folder = tmp_path / "exp"
    if content is not None:
        folder.mkdir()
        (folder / "results.csv").write_text(content)
    assert bench.main([str(folder)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bench_robust: error: ") and err.count("\n") == 1


def _synthetic():
    """tests/experiments/synthetic_data.py: a render folder without Mitsuba, fake methods."""
    path = ROOT / "tests" / "experiments" / "synthetic_data.py"
    spec = importlib.util.spec_from_file_location("_synthetic_data_for_bench_robust", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_run_re_denoises_on_copied_renders_without_rendering(bench, tmp_path, monkeypatch, capsys):
    synthetic = _synthetic()
    src = synthetic.make_render_folder(tmp_path / "base" / "data", spp=(1, 2, 4))
    manifest = (src / "manifest.json").read_text()
    fake = synthetic.FakeMethods(monkeypatch)
    fake.add("fine")  # a 3x3 box filter

    def spiky(b, p, d):  # "fine" but 50x too bright at 2 spp: worse than the noisy input
        return synthetic.box3(b["color"]) * (50.0 if b.spp == 2 else 1.0)

    fake.add("spiky", spiky)
    # the spec names a scene that would need Mitsuba: --renders must keep it from rendering
    spec = tmp_path / "exp.toml"
    spec.write_text(
        f"""name = "t"
methods = ["fine", "spiky"]
metrics = ["relmse"]
[scenes]
specs = ["{ROOT / "data" / "scenes" / "cornell.toml"}"]
[render]
resolution = [32, 24]
spp = [1, 2, 4]
[stats]
baseline = "noisy"
[report]
strip_spp = 2
""",
        encoding="utf-8",
    )
    out = tmp_path / "new"
    argv = ["--run", str(spec), "-o", str(out), "--renders", str(tmp_path / "base")]
    assert bench.main([*argv, "--baseline", "fine", "--json", "-"]) == 0
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    assert "ran 18 unit(s)" in captured.err  # 2 scenes x 3 levels x (noisy, fine, spiky)
    (exp,) = doc["experiments"]
    assert exp["scenes"] == ["alpha", "beta"] and exp["spp"] == [1, 2, 4]
    assert {(v["rule"], v["method"], v["spp"]) for v in exp["violations"]} == {
        ("a", "spiky", 2),
        ("b", "spiky", 2),
        ("c", "spiky", 2),
    } and exp["counts"] == {"a": 2, "b": 2, "c": 2}  # both scenes
    assert fake.calls == {"fine": 6, "spiky": 6}  # one run per unit, no warm-up
    assert (out / "data" / "manifest.json").read_text() == manifest
    assert (src / "manifest.json").read_text() == manifest
    # a subset of the ladder
    argv2 = ["--run", str(spec), "-o", str(tmp_path / "sub"), "--renders", str(tmp_path / "base")]
    assert bench.main([*argv2, "--spp", "2,4", "--baseline", "fine", "--json", "-"]) == 0
    assert json.loads(capsys.readouterr().out)["experiments"][0]["spp"] == [2, 4]
    # a second run into the same folder would reuse the first run's units: refused
    assert bench.main(argv) == 2
    assert "--resume" in capsys.readouterr().err


def test_run_refuses_a_folder_with_unit_records(bench, tmp_path, capsys):
    (tmp_path / "old" / "work").mkdir(parents=True)
    assert bench.main(["--run", "demo", "-o", str(tmp_path / "old")]) == 2
    assert "--resume" in capsys.readouterr().err


def test_the_robust_subset_spec_loads():
    from mcdenoise.experiments import load_experiment

    spec = load_experiment(ROOT / "data" / "experiments" / "robust.toml")
    full = load_experiment(ROOT / "data" / "experiments" / "full.toml")
    assert set(spec.scene_specs) == set(full.scene_specs) and 0 < spec.random <= full.random
    assert (spec.width, spec.height, spec.spp) == (128, 128, (1, 2, 4, 8, 16, 32, 64))
    assert spec.methods == "all" and spec.baseline == "oidn" and spec.threads == 1
