"""Named external methods in experiment specs (``[[external]]``, issue 26) and the report's
marking of their whole-process times."""

from __future__ import annotations

import csv
import json
import shutil
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner
from mcdenoise_cli.main import main
from synthetic_data import make_render_folder

from mcdenoise import registry
from mcdenoise.experiments.entries import plan_methods
from mcdenoise.experiments.spec import load_experiment, parse_experiment
from mcdenoise.experiments.spec_fields import ExperimentError

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "tests" / "data" / "external_denoiser.py"
PY = sys.executable


@pytest.fixture(autouse=True)
def _own_commands(monkeypatch: pytest.MonkeyPatch) -> None:
    """Commands registered by a test are forgotten afterwards (names are process-wide)."""
    monkeypatch.setattr(registry, "_COMMANDS", dict(registry._COMMANDS))


def _spec(externals: str, methods: str = '["mine"]', **extra: str) -> dict:
    import tomllib

    text = f"methods = {methods}\n{externals}\n[scenes]\nrandom = 1\n"
    for k, v in extra.items():
        text = f"{k} = {v}\n" + text
    return tomllib.loads(text)


def _entry(name: str, args: str = "blur {input} {output}", extra: str = "") -> str:
    cmd = json.dumps(f"{PY} {SCRIPT} {args}")
    return f"[[external]]\nname = {json.dumps(name)}\ncommand = {cmd}\n{extra}"


def _parse(data: dict, **kw: object):
    """A spec that runs programs, allowed (``--allow-commands``)."""
    return parse_experiment(data, source="x.toml", allow_commands=True, **kw)


def test_a_named_external_method_is_a_method_of_the_spec() -> None:
    spec = _parse(_spec(_entry("mine", extra="timeout = 30\n")))
    assert [e.name for e in spec.externals] == ["mine"]
    assert spec.params["mine"] == {"timeout": 30.0}
    assert registry.get_method("mine").defaults["command"].endswith("blur {input} {output}")
    entries, skipped = plan_methods(spec)
    assert [e.label for e in entries] == ["noisy", "mine"] and not skipped
    assert entries[1].params()["timeout"] == 30.0
    assert spec.to_dict()["external"][0]["name"] == "mine"


def test_all_never_includes_an_external_method() -> None:
    """Commands are never part of ``all``; an ``[[external]]`` that ``all`` would leave out
    (nothing names it) is refused rather than silently not run; swept, it runs."""
    with pytest.raises(ExperimentError, match=r"external\[0\]\.name: 'mine' would never run"):
        _parse(_spec(_entry("mine"), methods='"all"'))
    sweep = '[[sweep]]\nmethod = "mine"\nparam = "timeout"\nvalues = [5, 9]\n'
    spec = _parse(_spec(_entry("mine") + sweep, methods='"all"'))
    labels = [e.label for e in plan_methods(spec)[0]]
    assert "nlm" in labels and "mine" not in labels
    assert labels[-2:] == ["mine[timeout=5]", "mine[timeout=9]"]


def test_a_script_beside_the_spec_is_found_from_anywhere(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    shutil.copy(SCRIPT, tmp_path / "den.py")
    (tmp_path / "exp.toml").write_text(
        f'methods = ["mine"]\n[[external]]\nname = "mine"\n'
        f'command = "{PY} den.py blur {{input}} {{output}}"\n[scenes]\nrandom = 1\n',
        encoding="utf-8",
    )
    monkeypatch.chdir(REPO)
    spec = load_experiment(tmp_path / "exp.toml", allow_commands=True)
    assert str(tmp_path / "den.py") in spec.externals[0].command


@pytest.mark.parametrize(
    ("externals", "methods", "message"),
    [
        ('[[external]]\ncommand = "x {input} {output}"\n', "[]", "external[0].name: missing"),
        ('[[external]]\nname = "a"\n', "[]", "external[0].command: missing"),
        (_entry("a") + _entry("a"), '["a"]', "'a' names two [[external]] entries"),
        (_entry("nlm"), '["nlm"]', "'nlm' is a built-in method"),
        (_entry("xbf"), '["xbf"]', "'xbf' is a built-in method"),
        (_entry("noisy"), '["noisy"]', "'noisy' is a built-in method"),
        (_entry("a", "blur {input}"), '["a"]', "external[0]: "),
        (_entry("a", extra="timeout = -1\n"), '["a"]', "external[0].timeout: must be seconds"),
        (_entry("a", extra="args = 1\n"), '["a"]', "unknown key(s) args"),
        ('external = "x"\n', '["nlm"]', "external: must be a list"),
        (
            _entry("a", extra="timeout = 3\n") + "[params.a]\ntimeout = 5\n",
            '["a"]',
            "params.a.timeout: also given",
        ),
    ],
)
def test_bad_entries_are_refused_with_one_line(externals: str, methods: str, message: str) -> None:
    with pytest.raises(ExperimentError) as err:
        _parse(_spec(externals, methods=methods))
    text = str(err.value)
    assert message in text and "\n" not in text and text.startswith("x.toml: ")


def test_bad_entry_through_the_cli_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "data").mkdir()
    (tmp_path / "exp.toml").write_text(_spec_text(_entry("nlm"), '["nlm"]'), encoding="utf-8")
    r = CliRunner().invoke(
        main, ["eval", "--experiment", str(tmp_path / "exp.toml"), "-o", "o", "--allow-commands"]
    )
    assert r.exit_code != 0 and "Traceback" not in r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and "'nlm' is a built-in method" in lines[0], r.output


def _spec_text(externals: str, methods: str) -> str:
    return (
        f"methods = {methods}\nmetrics = ['relmse']\nrepetitions = 1\nwarmup = 0\n"
        f"threads = 1\n{externals}\n[scenes]\nfolder = 'data'\n"
    )


def test_an_experiment_runs_a_named_command_and_marks_its_times(tmp_path: Path) -> None:
    """End to end: ``mcdenoise eval --experiment`` with one ``[[external]]`` (the blur of
    tests/data/external_denoiser.py) next to an in-process method on a synthetic folder."""
    make_render_folder(tmp_path / "data", scenes=("alpha",), size=(12, 16), spp=(1, 2))
    (tmp_path / "exp.toml").write_text(
        _spec_text(_entry("myblur", extra="timeout = 60\n"), '["myblur", "xbf"]'),
        encoding="utf-8",
    )
    out = tmp_path / "rep"
    args = ["eval", "--experiment", str(tmp_path / "exp.toml"), "-o", str(out)]
    r = CliRunner().invoke(main, args)
    assert r.exit_code != 0 and "--allow-commands" in r.output and not out.exists()
    r = CliRunner().invoke(main, [*args, "--allow-commands"])
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader((out / "results.csv").open(encoding="utf-8")))
    by = {(row["method"], row["spp"]): row for row in rows}
    for spp in ("1", "2"):
        mine, noisy, xbf = by["myblur", spp], by["noisy", spp], by["xbf", spp]
        assert mine["failed"] == "false" and mine["base_method"] == "myblur"
        assert mine["timing_clock"] == "process" and float(mine["denoise_seconds"]) > 0
        assert xbf["timing_clock"] == "in-process" and noisy["timing_clock"] == ""
        # a 3x3 blur of pure Gaussian noise on a smooth image lowers the error
        assert float(mine["relmse"]) < float(noisy["relmse"])
    data = json.loads((out / "results.json").read_text(encoding="utf-8"))
    clocks = {r["method"]: r["timing_clock"] for r in data["records"]}
    assert clocks == {"noisy": None, "myblur": "process", "xbf": "in-process"}
    assert data["spec"]["external"][0]["timeout"] == 60.0
    html = (out / "report.html").read_text(encoding="utf-8")
    assert "an external command&#x27;s time is the whole process" in html or (
        "an external command's time is the whole process" in html
    )
    assert html.count("‡") >= 2
    assert "myblur: external command(s), timed as whole processes" in html
