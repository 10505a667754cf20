"""``mcdenoise eval --experiment SPEC -o DIR`` as users meet it: the printed summary that ends
with the report's path, resuming, Ctrl-C, and one-line errors; the old ``eval --ref`` form
keeps its usage errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner
from mcdenoise_cli.main import main
from scene_specs import BALL_SCENE

from mcdenoise import registry
from mcdenoise.registry import Method

EXPERIMENT = """
name = "cli"
methods = ["xbf"]
metrics = ["relmse", "psnr"]
repetitions = 1
warmup = 0
[scenes]
specs = ["ball.toml"]
[render]
resolution = 16
spp = [1, 2]
ref_spp = 16
variant = "scalar_rgb"
"""


def run(*args: str):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


def one_line_error(result, code: int = 1) -> str:
    assert result.exit_code == code, result.output
    err = result.stderr.strip()
    assert "Traceback" not in result.output + err
    assert len(err.splitlines()) == 1, err
    return err


@pytest.fixture(scope="module")
def experiment(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cli")
    (tmp / "ball.toml").write_text(BALL_SCENE.format(name="ball"), encoding="utf-8")
    spec = tmp / "cli.toml"
    spec.write_text(EXPERIMENT, encoding="utf-8")
    out = tmp / "out"
    first = run("experiment", str(spec), "-o", str(out))
    return tmp, spec, out, first


@pytest.mark.mitsuba
def test_experiment_prints_a_summary_and_ends_with_the_report(experiment):
    _, _, out, first = experiment
    assert first.exit_code == 0, first.output + first.stderr
    lines = first.stdout.strip().splitlines()
    assert lines[0].startswith("experiment cli: 1 scene(s) x 2 spp level(s) x 2 method(s)")
    assert "rendered 1 image(s)" in lines[0] and "ran 4 unit(s)" in lines[0]
    assert lines[-1] == f"report: {out / 'report.html'}"
    assert (out / "report.html").is_file() and (out / "results.csv").is_file()
    data = json.loads((out / "results.json").read_text())
    assert {r["method"] for r in data["records"]} == {"noisy", "xbf"}


@pytest.mark.mitsuba
def test_second_run_reuses_everything(experiment):
    """The first run was ``mcdenoise experiment``; its alias ``eval --experiment`` resumes it."""
    _, spec, out, _ = experiment
    again = run("eval", "--experiment", str(spec), "-o", str(out))
    assert again.exit_code == 0, again.output + again.stderr
    assert "rendered 0 image(s), reused 1; ran 0 unit(s), reused 4 finished" in again.output


@pytest.mark.mitsuba
def test_ctrl_c_exits_130_and_a_rerun_finishes(experiment, monkeypatch):
    tmp, _, out, _ = experiment
    calls = {"n": 0}

    def interrupt_second(b, p, d):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return b["color"].clone()

    method = Method("stopper", "test", ("color",), (), {}, interrupt_second)
    monkeypatch.setitem(registry._REGISTRY, "stopper", method)
    spec = tmp / "stop.toml"
    spec.write_text(
        'methods = ["stopper"]\nmetrics = ["relmse"]\nrepetitions = 1\nwarmup = 0\n'
        f'[scenes]\nfolder = "{out / "data"}"\n',
        encoding="utf-8",
    )
    stopped = run("experiment", str(spec), "-o", str(tmp / "stop"))
    assert stopped.exit_code == 130 and "interrupted" in stopped.stderr
    assert not (tmp / "stop" / "results.json").exists()
    done = run("eval", "--experiment", str(spec), "-o", str(tmp / "stop"))
    assert done.exit_code == 0, done.output + done.stderr
    # finished before Ctrl-C: noisy and stopper at 1 spp, noisy at 2 spp
    assert "ran 1 unit(s), reused 3 finished" in done.output
    assert calls["n"] == 3


def test_experiment_errors_are_one_line(tmp_path: Path):
    msg = one_line_error(run("eval", "--experiment", str(tmp_path / "nope.toml")))
    assert "experiment spec not found" in msg
    bad = tmp_path / "bad.toml"
    bad.write_text('repetitons = 3\n[scenes]\nspecs = ["x.toml"]\n', encoding="utf-8")
    msg = one_line_error(run("experiment", str(bad), "-o", str(tmp_path / "o")))
    assert f"{bad}: top level: unknown key(s) repetitons" in msg
    bad.write_text('[scenes]\nspecs = ["x.toml"]\n', encoding="utf-8")
    msg = one_line_error(run("experiment", str(bad), "-o", str(tmp_path / "o")))
    assert f"{bad}: scenes.specs[0]: 'x.toml' not found" in msg


def test_usage_errors_of_both_forms(tmp_path: Path):
    spec = tmp_path / "e.toml"
    spec.write_text("", encoding="utf-8")
    r = run("eval", "--experiment", str(spec), "--ref", "r.exr", "out.exr")
    assert r.exit_code == 2 and "takes none of OUTPUTS, --ref" in r.stderr
    r = run("eval", str(tmp_path))
    assert r.exit_code == 2 and "Missing option '--ref'" in r.stderr
    r = run("eval", "--ref", str(tmp_path))
    assert r.exit_code == 2 and "Missing argument 'OUTPUTS...'" in r.stderr
    assert "--experiment SPEC" in run("eval", "--help").output
    r = run("eval", "--ref", "r.exr", "out.exr", "--shard", "1/2")
    assert r.exit_code == 2 and "--shard applies to --experiment SPEC" in r.stderr
    r = run("experiment", str(spec))
    assert r.exit_code == 2 and "Missing option '-o'" in r.stderr


def test_experiment_is_its_own_verb_and_eval_experiment_its_alias():
    """``mcdenoise experiment`` is listed and documents what ``eval --experiment`` only
    points to (the same command: the alias re-runs and resumes the verb's run above)."""
    top = run("--help").output
    assert "experiment" in top
    own = run("experiment", "--help").output
    for option in ("--shard", "--merge", "--allow-commands", "--threads", "--metrics", "-o"):
        assert option in own
    assert "alias" in own and "Alias of `mcdenoise experiment SPEC`" in run("eval", "--help").output
