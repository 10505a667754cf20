"""Progress on stderr: a tqdm bar on a terminal, plain lines in a log (no carriage returns),
nothing with ``--no-progress``; ``eval --experiment`` reports every stage (render, denoise
units with the current scene, report)."""

from __future__ import annotations

import importlib.util
import io
import os
import re
import select
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner
from fast_methods import add_methods, fast_method
from mcdenoise_cli.main import main

from mcdenoise import progress

SAMPLES = Path(__file__).resolve().parents[2] / "data" / "samples"


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def run(*args: str):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture
def box(monkeypatch: pytest.MonkeyPatch) -> str:
    """A fast method (a 3x3 box filter), so the commands' progress is what is tested."""
    add_methods(monkeypatch, fast_method("box3"))
    return "box3"


# --- the helper ---------------------------------------------------------------------------


def test_lines_in_a_log(monkeypatch: pytest.MonkeyPatch) -> None:
    log = io.StringIO()
    monkeypatch.setattr(progress, "_stream", lambda: log)
    with progress.progress_bar(total=3, desc="render", unit="image") as bar:
        for scene in ("a", "b", "c"):
            bar.set_postfix_str(scene)
            bar.update(1)
    lines = log.getvalue().splitlines()
    assert lines[0] == "render: 3 images ..."
    assert lines[-1].startswith("render: 3 images done in ") and lines[-1].endswith(" s")
    assert len(lines) == 2 and "\r" not in log.getvalue()


def test_a_line_a_minute_with_done_total_item_and_time_left(monkeypatch) -> None:
    log = io.StringIO()
    monkeypatch.setattr(progress, "_stream", lambda: log)
    monkeypatch.setattr(progress, "LOG_INTERVAL", 0.0)  # every update is "a minute later"
    bar = progress.progress_bar(total=4, desc="denoise", unit="unit")
    bar.set_postfix_str("cornell 8 spp nlm")
    bar.update(1)
    bar.close()
    lines = log.getvalue().splitlines()
    assert lines[1].startswith("denoise: 1/4 units, cornell 8 spp nlm, about ")
    assert lines[1].endswith(" left")
    assert lines[2].startswith("denoise: stopped after 1/4 units")  # closed early


def test_a_bar_on_a_terminal_and_nothing_when_off(monkeypatch) -> None:
    term = Terminal()
    monkeypatch.setattr(progress, "_stream", lambda: term)
    assert progress.resolve_mode(True) == "bar"
    for _ in progress.progress_bar(range(3), desc="train", unit="step"):
        pass
    assert "\r" in term.getvalue() and "3/3" in term.getvalue()
    quiet = Terminal()
    monkeypatch.setattr(progress, "_stream", lambda: quiet)
    for _ in progress.progress_bar(range(3), desc="train", progress=False):
        pass
    assert quiet.getvalue() == ""


def test_a_terminal_without_a_size_still_gets_a_bar(monkeypatch) -> None:
    """A fresh pty reports 0 x 0 (``script``, some CI runners): tqdm alone draws nothing."""
    master, slave = os.openpty()
    with os.fdopen(slave, "w", encoding="utf-8") as term:
        assert os.get_terminal_size(term.fileno()).lines == 0
        monkeypatch.setattr(progress, "_stream", lambda: term)
        for _ in progress.progress_bar(range(2), desc="render", unit="image"):
            pass
        term.flush()
        chunks = []  # a pty hands over what it holds per read: read until it is empty
        while select.select([master], [], [], 0.5)[0]:
            chunks.append(os.read(master, 65536))
        drawn = b"".join(chunks).decode("utf-8", "replace")
    os.close(master)
    assert "render: 100%" in drawn and "2/2" in drawn


def test_a_resumed_stage_says_what_is_left(monkeypatch) -> None:
    log = io.StringIO()
    monkeypatch.setattr(progress, "_stream", lambda: log)
    with progress.progress_bar(total=10, initial=7, desc="denoise", unit="unit") as bar:
        bar.update(3)
    assert log.getvalue().splitlines() == [
        "denoise: 3 of 10 units left ...",
        log.getvalue().splitlines()[1],
    ]
    assert log.getvalue().splitlines()[1].startswith("denoise: 10 units done in ")


def test_library_code_does_not_print() -> None:
    """Only the progress helper writes to stderr; no print() in the modules it serves."""
    root = Path(progress.__file__).parent
    for rel in (
        "denoise.py",
        "experiments/runner.py",
        "eval/evaluate.py",
        "eval/evaluate_sequences.py",
        "render/generate.py",
        "train/loop.py",
    ):
        text = (root / rel).read_text(encoding="utf-8")
        assert not re.search(r"\bprint\(|from tqdm|import tqdm", text), rel


# --- the commands -------------------------------------------------------------------------


def test_denoise_writes_stage_lines_not_bars_into_a_log(tmp_path: Path, box: str) -> None:
    r = run(
        "denoise", SAMPLES / "cornell_spp4.exr", SAMPLES / "dof_spp4.exr", "-m", box, "-o", tmp_path
    )
    assert r.exit_code == 0, r.output
    assert "\r" not in r.stderr
    lines = r.stderr.splitlines()
    assert lines[0] == "denoise: 2 images ..."
    assert lines[-1].startswith("denoise: 2 images done in ")
    assert len(r.stdout.splitlines()) == 2  # the results


def test_one_input_needs_no_progress(tmp_path: Path, box: str) -> None:
    r = run("denoise", SAMPLES / "cornell_spp4.exr", "-m", box, "-o", tmp_path / "o.exr")
    assert r.exit_code == 0 and r.stderr == ""


def _synthetic():
    """tests/experiments/synthetic_data.py (a render folder without Mitsuba)."""
    path = Path(__file__).resolve().parents[1] / "experiments" / "synthetic_data.py"
    spec = importlib.util.spec_from_file_location("_synthetic_data_for_cli", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_experiment_reports_every_stage(tmp_path: Path, box: str) -> None:
    _synthetic().make_render_folder(tmp_path / "rendered", scenes=("alpha", "beta"), spp=(1, 2))
    spec = tmp_path / "exp.toml"
    spec.write_text(
        f"""
name = "progress"
methods = ["{box}"]
metrics = ["relmse"]
repetitions = 1
warmup = 0
[scenes]
folder = "rendered"
[report]
strip_spp = 2
""",
        encoding="utf-8",
    )
    r = run("eval", "--experiment", spec, "-o", tmp_path / "out")
    assert r.exit_code == 0, r.output
    assert "\r" not in r.stderr
    lines = r.stderr.splitlines()
    # 2 scenes x 2 levels x (noisy + box3)
    assert "denoise: 8 units ..." in lines
    assert any(line.startswith("denoise: 8 units done in ") for line in lines)
    assert "report: 2 steps ..." in lines
    assert r.stdout.splitlines()[-1] == f"report: {tmp_path / 'out' / 'report.html'}"
    again = run("eval", "--experiment", spec, "-o", tmp_path / "out", "--no-progress")
    assert again.exit_code == 0 and again.stderr == ""
