"""The training set's ``loading`` stage and the fixed filters' ``grid`` search report through
:func:`mcdenoise.progress.progress_bar` like every other long stage: plain lines in a log (no
carriage returns), nothing when off, a bar on a terminal."""

from __future__ import annotations

import io
import re
from pathlib import Path

import pytest

from mcdenoise import progress
from mcdenoise.models.kalantari import settings_class
from mcdenoise.prep.kalantari import prepare_item
from mcdenoise.train import grid
from mcdenoise.train import patches as dataset
from mcdenoise.train.grid import grid_search
from mcdenoise.train.patches import load_items, scan_dataset

ONE_THREAD = True
GUIDES = ["albedo", "normal", "depth", "position"]


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.fixture
def stderr(monkeypatch: pytest.MonkeyPatch):
    """``set(stream)``: make ``stream`` what the progress helper writes to."""

    def use(stream: io.StringIO) -> io.StringIO:
        monkeypatch.setattr(progress, "_stream", lambda: stream)
        return stream

    return use


def _color(buffers, ref):
    return {"color": buffers["color"], "reference": ref}


def test_loading_writes_a_start_and_an_end_line_into_a_log(tiny_dataset: Path, stderr) -> None:
    log = stderr(io.StringIO())
    entries = scan_dataset(tiny_dataset)
    items, _ = load_items(entries, _color, progress=True)
    assert len(items) == len(entries) == 8
    lines = log.getvalue().splitlines()
    assert lines[0] == "loading: 8 levels ..."
    assert re.fullmatch(r"loading: 8 levels done in \d+(\.\d)? s", lines[-1])
    assert len(lines) == 2 and "\r" not in log.getvalue()


def test_loading_is_silent_when_off_and_a_bar_on_a_terminal(tiny_dataset: Path, stderr) -> None:
    entries = scan_dataset(tiny_dataset)[:2]
    log = stderr(io.StringIO())
    load_items(entries, _color, progress=False)
    assert log.getvalue() == ""
    term = stderr(Terminal())
    load_items(entries, _color, progress=True)
    assert "\r" in term.getvalue() and "loading" in term.getvalue()


def test_grid_search_writes_lines_into_a_log(tiny_dataset: Path, stderr) -> None:
    settings = settings_class("xbf")()
    entries = [e for e in scan_dataset(tiny_dataset) if e.spp == 4][:2]
    items, _ = load_items(entries, lambda b, r: prepare_item(b, "xbf", settings, GUIDES, r))
    log = stderr(io.StringIO())
    small = {"sigma_spatial": [2.0, 4.0], "sigma_color": [2.0], "feature_scale": [1.0]}
    result = grid_search("xbf", items, small, progress=True)
    assert len(result.trials) == 2 and set(result.best) == {4}
    lines = log.getvalue().splitlines()
    assert lines[0] == "grid xbf: 2 settings ..."
    assert lines[-1].startswith("grid xbf: 2 settings done in ")
    assert len(lines) == 2 and "\r" not in log.getvalue()


def test_neither_module_uses_tqdm_directly() -> None:
    for module in (dataset, grid):
        text = Path(module.__file__).read_text(encoding="utf-8")
        assert not re.search(r"\bprint\(|from tqdm|import tqdm", text), module.__name__
