"""Every example a user reads runs: the command lines in each command's ``--help`` (lines
starting with ``mcdenoise`` and the ``e.g. -x ...`` fragments of option help) and in the
README's ``sh`` blocks, executed through click's CliRunner in a temporary folder where
``data/`` is the repository's (samples, scenes, experiments).

The README's render -> train -> denoise --model chain and the demo experiment take minutes:
they are marked slow (``MCDENOISE_SLOW=1``) and run verbatim there; everything else runs in
the default suite.
"""

from __future__ import annotations

import re
import shlex
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner
from mcdenoise_cli.main import main

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "data" / "samples"


def invoke(args: list[str]):
    return CliRunner().invoke(main, args, catch_exceptions=False)


# --- extracting the examples --------------------------------------------------------------


def help_texts() -> dict[str, str]:
    """``--help`` of the group and of every command."""
    texts = {"": invoke(["--help"]).stdout}
    for name in sorted(main.commands):
        texts[name] = invoke([name, "--help"]).stdout
    return texts


def help_command_lines(text: str) -> list[str]:
    """Lines of a help text that are a command (``mcdenoise info noisy.exr   comment``)."""
    out = []
    for line in text.splitlines():
        m = re.match(r"\s*(mcdenoise \S.*)$", line)
        if m and not line.lstrip().startswith("Usage:"):
            out.append(re.split(r"\s{2,}", m.group(1).strip())[0])
    return out


def option_examples() -> list[tuple[str, str]]:
    """``(command, fragment)`` for every ``e.g. -x ...`` in an option's help."""
    found = []
    for name, cmd in sorted(main.commands.items()):
        for param in cmd.params:
            help_text = getattr(param, "help", None) or ""
            for m in re.finditer(r"e\.g\. (-[^;)]*?)\.?(?:$|[;)]|\. )", help_text):
                found.append((name, m.group(1).strip()))
    return found


def readme_commands() -> list[str]:
    """The ``mcdenoise ...`` lines of README.md's ```sh blocks (continuations joined)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    commands = []
    for block in re.findall(r"```sh\n(.*?)```", text, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if words[:1] == ["mcdenoise"]:
                commands.append(shlex.join(words))
    return commands


def is_slow(command: str) -> bool:
    """Renders, trains, the experiments, and what needs a trained run (minutes each)."""
    words = shlex.split(command)
    return (
        words[1] in ("render", "train", "experiment")
        or "--experiment" in words
        or "runs/" in command
        or "seq/" in command  # reads the sequence the README's render line writes
        or "renders/" in command  # reads the README's rendered data set (half buffers)
        or "est/" in command  # reads what the line before wrote from renders/
    )


# --- the work folder ----------------------------------------------------------------------


@pytest.fixture
def work(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A folder like a fresh clone's: ``data/`` (read-only use), and the placeholder files
    the help examples name (``noisy.exr``, ``ref.exr``: one sample scene)."""
    (tmp_path / "data").symlink_to(ROOT / "data")
    shutil.copy(SAMPLES / "cornell_spp4.exr", tmp_path / "noisy.exr")
    shutil.copy(SAMPLES / "ref" / "cornell.exr", tmp_path / "ref.exr")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def run_line(command: str):
    result = invoke(shlex.split(command)[1:])
    assert result.exit_code == 0, f"{command}\n{result.output}"
    return result


# --- the tests ----------------------------------------------------------------------------


def test_examples_are_found() -> None:
    """The extraction finds the examples (a change of format must not make this test vacuous)."""
    lines = [c for t in help_texts().values() for c in help_command_lines(t)]
    assert "mcdenoise denoise noisy.exr -o out.exr" in lines
    assert ("denoise", "--method nlm -p search_radius=7") in option_examples()
    assert ("train", "-s steps=2000 -s hidden=32,16") in option_examples()
    assert len(readme_commands()) >= 8


def test_help_command_lines_run(work: Path) -> None:
    lines = [c for t in help_texts().values() for c in help_command_lines(t)]
    assert lines
    for command in lines:  # in order: the denoise example writes what eval reads
        run_line(command)
    assert (work / "out.exr").is_file()
    assert (work / "report" / "report.html").is_file()


def test_denoise_option_examples_run(work: Path) -> None:
    examples = [f for c, f in option_examples() if c == "denoise"]
    assert examples
    for fragment in examples:
        out = work / "opt.exr"
        run_line(f"mcdenoise denoise noisy.exr -o {out} {fragment}")
        assert out.is_file()
        out.unlink()


def test_train_option_examples_run(work: Path, tiny_dataset: Path) -> None:
    """``-s`` examples of ``train --help`` at a tiny size (``--steps`` wins over ``-s steps``)."""
    tiny = "-s kernel=5 -s patch=16 -s margin=2 -s batch=2 -s threads=1 -s epoch_steps=1"
    examples = [f for c, f in option_examples() if c == "train"]
    assert examples
    for k, fragment in enumerate(examples):
        run_line(
            f"mcdenoise train --model kalantari-xbf --data {tiny_dataset} --out run{k} "
            f"--quiet {fragment} {tiny} --steps 1"
        )
        assert (work / f"run{k}" / "model.pt").is_file()


def test_every_option_example_is_run_by_a_test() -> None:
    """A new ``e.g. -x`` example in another command's help needs a test above."""
    assert {c for c, _ in option_examples()} <= {"denoise", "train"}


def test_readme_quick_commands_run(work: Path) -> None:
    quick = [c for c in readme_commands() if not is_slow(c)]
    assert any(" eval --ref " in c for c in quick)
    for command in quick:
        run_line(command)
    assert (work / "report" / "report.html").is_file()


@pytest.mark.slow
@pytest.mark.mitsuba
def test_readme_render_train_denoise_chain_runs(work: Path) -> None:
    """All but the demo, in the README's order (its later commands use earlier outputs)."""
    commands = [c for c in readme_commands() if "--experiment" not in c]
    chain = [c for c in commands if is_slow(c)]
    assert [shlex.split(c)[1] for c in chain] == [
        *("render", "train", "denoise"),  # a data set, a model trained on it, the model used
        *("render", "denoise", "eval"),  # a sequence, svgf over it, temporal metrics
        *("denoise", "eval"),  # errors estimated from the half buffers, eval without --ref
    ]
    for command in commands:
        run_line(command)
    assert (work / "out" / "mine.exr").is_file()


@pytest.mark.slow
@pytest.mark.mitsuba
def test_readme_demo_experiment_runs(work: Path) -> None:
    (demo,) = [c for c in readme_commands() if c.startswith("mcdenoise experiment ")]
    run_line(demo)
    assert (work / "demo-out" / "report.html").is_file()


# --- aliases ------------------------------------------------------------------------------


def test_methods_lists_aliases_and_method_help_mentions_them() -> None:
    from mcdenoise.registry import method_aliases

    lines = invoke(["methods"]).stdout.splitlines()
    table = method_aliases()
    assert table["cross-bilateral"] == ["cross_bilateral", "xbf"]
    for name, aliases in table.items():
        at = next(i for i, line in enumerate(lines) if line.startswith(f"{name} "))
        assert lines[at + 1].strip() == f"alias: {', '.join(aliases)}"
    help_text = " ".join(invoke(["denoise", "--help"]).stdout.split())
    assert "aliases" in help_text and "xbf" in help_text


def test_an_alias_works_like_its_method(work: Path) -> None:
    run_line("mcdenoise denoise noisy.exr --method xbf -o a.exr")
    from mcdenoise.io import load_buffers

    assert load_buffers(work / "a.exr").attributes["mcdenoise:method"] == "cross-bilateral"
