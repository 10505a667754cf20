"""Where outputs go and where messages go: ``-o`` names with a file extension other than
``.exr`` are refused (no folder ``p.txt``), a file in the way of a folder is named, results
go to stdout and every message to stderr, for every command that writes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner
from fast_methods import add_methods, fast_method
from mcdenoise_cli.main import main

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"
NOISY = SAMPLES / "cornell_spp4.exr"


def run(*args: str):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def one_line_error(result, code: int = 1) -> str:
    assert result.exit_code == code, result.output
    assert result.stdout == "", result.stdout
    err = result.stderr.strip()
    assert "Traceback" not in err
    assert len(err.splitlines()) == 1, err
    return err


@pytest.fixture
def here(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A work folder holding a file ``text.exr``; ``nlm`` is a fast stand-in here."""
    add_methods(monkeypatch, fast_method("nlm"))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "text.exr").write_text("not an image", encoding="utf-8")
    return tmp_path


# --- -o with another file extension -------------------------------------------------------


def test_denoise_refuses_an_output_with_another_extension(here: Path) -> None:
    err = one_line_error(run("denoise", NOISY, "-m", "nlm", "-o", "outs/p.txt"))
    assert "outs/p.txt" in err and ".exr" in err and "'.txt'" in err
    assert not (here / "outs").exists()  # nothing made


@pytest.mark.parametrize(
    "args",
    [
        ["eval", "--ref", SAMPLES / "ref" / "cornell.exr", NOISY, "-o", "report.html"],
        ["render", SAMPLES.parent / "scenes" / "cornell.toml", "-o", "renders.txt"],
        ["train", "--data", "somewhere", "--out", "run.json"],
    ],
    ids=["eval", "render", "train"],
)
def test_folder_options_refuse_a_new_name_with_a_file_extension(here: Path, args) -> None:
    err = one_line_error(run(*args))
    assert "must not have a file extension" in err
    assert sorted(p.name for p in here.iterdir()) == ["text.exr"]


def test_an_existing_folder_with_a_dot_is_fine(here: Path) -> None:
    (here / "out.v2").mkdir()
    r = run("denoise", NOISY, "-m", "nlm", "-o", "out.v2")
    assert r.exit_code == 0, r.output
    assert (here / "out.v2" / "cornell_spp4_nlm.exr").is_file()


# --- a file in the way of a folder --------------------------------------------------------


@pytest.mark.parametrize(
    "args",
    [
        ["denoise", NOISY, "-m", "nlm", "-o", "text.exr/out.exr"],
        ["denoise", NOISY, "-m", "nlm", "-o", "text.exr/sub"],
        ["eval", "--ref", SAMPLES / "ref" / "cornell.exr", NOISY, "-o", "text.exr/report"],
        ["render", SAMPLES.parent / "scenes" / "cornell.toml", "-o", "text.exr/r"],
        ["train", "--data", "somewhere", "--out", "text.exr/run"],
    ],
    ids=["denoise-file", "denoise-folder", "eval", "render", "train"],
)
def test_a_file_in_the_way_is_named(here: Path, args) -> None:
    err = one_line_error(run(*args))
    assert "text.exr is a file, not a folder" in err
    assert "does not exist" not in err


# --- streams ------------------------------------------------------------------------------


def test_denoise_results_on_stdout_skipped_on_stderr(here: Path, monkeypatch) -> None:
    """``--method all``: a method whose buffer the input lacks is skipped (a message)."""
    add_methods(
        monkeypatch, fast_method("box3"), fast_method("feat", ("color", "normal")), only=True
    )
    r = run("denoise", SAMPLES / "ref" / "cornell.exr", "--method", "all", "-o", "outs")
    assert r.exit_code == 0, r.output
    assert r.stdout.splitlines()[0].startswith("outs/cornell_box3.exr  [box3, ")
    assert len(r.stdout.splitlines()) == 1
    assert (here / "outs" / "cornell_box3.exr").is_file()
    skipped = [line for line in r.stderr.splitlines() if line.startswith("skipped ")]
    assert skipped == [skipped[0]] and skipped[0].startswith("skipped feat on cornell.exr: ")
    assert "normal" in skipped[0]


def test_denoise_json_records_alone_on_stdout(here: Path) -> None:
    r = run("denoise", NOISY, NOISY.with_name("dof_spp4.exr"), "-m", "nlm", "-o", "o", "--json")
    assert r.exit_code == 0, r.output
    records = [json.loads(line) for line in r.stdout.splitlines()]
    assert [Path(rec["output"]).name for rec in records] == [
        "cornell_spp4_nlm.exr",
        "dof_spp4_nlm.exr",
    ]
    assert "denoise: 2 images" in r.stderr  # progress: stderr, as lines (not a terminal)


def test_eval_results_on_stdout_nothing_else(here: Path) -> None:
    r = run("denoise", NOISY, "-m", "nlm", "-o", "o.exr")
    assert r.exit_code == 0, r.output
    r = run("eval", "--ref", SAMPLES / "ref" / "cornell.exr", "o.exr", "-o", "rep")
    assert r.exit_code == 0, r.output
    assert r.stderr == ""
    assert "html: rep/report.html" in r.stdout


def test_info_results_on_stdout(here: Path) -> None:
    r = run("info", NOISY, "--json")
    assert r.exit_code == 0, r.output
    assert r.stderr == ""
    assert json.loads(r.stdout)["path"].endswith("cornell_spp4.exr")


def test_denoise_output_next_to_input_needs_no_o(here: Path) -> None:
    shutil.copy(NOISY, here / "n.exr")
    r = run("denoise", "n.exr", "-m", "nlm")
    assert r.exit_code == 0 and r.stdout.startswith("n_nlm.exr")


def test_two_inputs_of_one_name_are_named_when_their_outputs_would_collide(here: Path) -> None:
    """``a/x.exr`` and ``b/x.exr`` into one ``-o`` folder would both write ``x_nlm.exr``: the
    one-line refusal names both inputs and the output, and nothing is written."""
    for sub in ("a", "b"):
        (here / sub).mkdir()
        shutil.copy(NOISY, here / sub / "x.exr")
    err = one_line_error(run("denoise", "a/x.exr", "b/x.exr", "-o", "out", "-m", "nlm"))
    assert "a/x.exr and b/x.exr would both write out/x_nlm.exr" in err, err
    assert not (here / "out").exists() or not list((here / "out").iterdir())
