"""The documentation stays true to the tree: links resolve, named tests exist, README fits.

* every relative link in README.md, docs/ and data/recipes/ names a file that exists, and an
  anchor names a heading of the target (GitHub's slugs);
* every ``tests/...py::test_name`` that docs/hard-cases.md cites exists (a renamed or deleted
  test makes its hard case uncovered, which the list must then say);
* the README stays a front door: at most 12 KB.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LINK = re.compile(r"(?<!\!)\[([^\]]*)\]\(([^)\s]+)\)")
FENCE = re.compile(r"```.*?```", flags=re.S)


def _slug(heading: str) -> str:
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    out, fence = set(), False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            fence = not fence
        if not fence and re.match(r"#{1,6} ", line):
            out.add(_slug(re.sub(r"^#+ ", "", line)))
    return out


def _doc_files() -> list[Path]:
    return [
        REPO / "README.md",
        *sorted((REPO / "docs").rglob("*.md")),
        *sorted((REPO / "data" / "recipes").glob("*.md")),
    ]


def _broken_links(path: Path) -> list[str]:
    bad = []
    for m in LINK.finditer(FENCE.sub("", path.read_text(encoding="utf-8"))):
        target = m.group(2)
        if re.match(r"[a-z]+:", target):
            continue  # http:, mailto:, ...
        file, _, anchor = target.partition("#")
        dest = (path.parent / file).resolve() if file else path
        if not dest.exists():
            bad.append(f"missing {target}")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            bad.append(f"no heading #{anchor} in {dest.name}")
    return bad


def test_the_link_checker_finds_broken_links(tmp_path):
    page = tmp_path / "page.md"
    (tmp_path / "there.md").write_text("# A heading\n", encoding="utf-8")
    page.write_text(
        "[ok](there.md#a-heading) [gone](nowhere.md) [anchor](there.md#nope)\n", encoding="utf-8"
    )
    assert len(_broken_links(page)) == 2


@pytest.mark.parametrize("path", _doc_files(), ids=lambda p: str(p.relative_to(REPO)))
def test_links_resolve(path):
    assert not _broken_links(path)


def test_hard_cases_name_existing_tests():
    text = (REPO / "docs" / "hard-cases.md").read_text(encoding="utf-8")
    refs = set(re.findall(r"`(tests/[\w/]+\.py)::(\w+)`", text))
    assert len(refs) > 50
    missing = []
    for file, name in sorted(refs):
        source = REPO / file
        if not source.exists() or not re.search(
            rf"^\s*(async )?def {name}\(", source.read_text(encoding="utf-8"), flags=re.M
        ):
            missing.append(f"{file}::{name}")
    assert not missing


def test_hard_cases_keep_every_item():
    text = (REPO / "docs" / "hard-cases.md").read_text(encoding="utf-8")
    numbers = [int(n) for n in re.findall(r"^(\d+)\. ", text, flags=re.M)]
    # the 43 items of the shared list, then the project's own, numbered on
    assert sorted(set(numbers)) == list(range(1, max(44, max(numbers) + 1)))


def test_readme_is_a_front_door():
    assert (REPO / "README.md").stat().st_size <= 12 * 1024
