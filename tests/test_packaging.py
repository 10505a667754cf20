"""The distribution holds every package and every data file (issue 33, item 8).

A hand-kept package list in pyproject.toml left out ``mcdenoise.ao``: the editable install of
the checkout worked, an installed wheel could not load its methods. The packages are now found
by setup.py; these tests check what setuptools is configured to put in the distribution
against the folders and files git tracks. ``make wheel-check`` (.ci/wheel_check) builds and
installs the wheel itself.
"""

from __future__ import annotations

import json
import runpy
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _tracked(*paths: str) -> list[str]:
    """Files git tracks (or that are new and not ignored) under ``paths``."""
    if shutil.which("git") is None or not (REPO / ".git").exists():
        pytest.skip("needs a git checkout")
    out = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard", "--", *paths],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    return [line for line in out.splitlines() if (REPO / line).is_file()]


def test_every_folder_of_the_package_is_a_package_of_the_distribution():
    packages = runpy.run_path(str(REPO / "setup.py"), run_name="setup")["packages"]()
    folders = {
        ".".join(p.relative_to(REPO).parts)
        for p in [REPO / "mcdenoise", *(REPO / "mcdenoise").rglob("*")]
        if p.is_dir() and "__pycache__" not in p.parts and any(p.iterdir())
    }
    assert "mcdenoise.ao" in packages and "mcdenoise_cli" in packages
    assert folders - set(packages) == set()
    assert set(packages) - folders == {"mcdenoise_cli"}


def test_package_data_takes_every_file_but_modules():
    tool = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "packages" not in tool  # found by setup.py, never listed by hand again
    assert tool["package-dir"] == {"mcdenoise": "mcdenoise", "mcdenoise_cli": "cli"}
    assert tool["package-data"] == {"*": ["*"]}


_LIST_DISTRIBUTION = """
import json, setuptools
from distutils.core import run_setup
dist = run_setup("setup.py", stop_after="config")
build = dist.get_command_obj("build_py")
build.ensure_finalized()
files = [m[2] for m in build.find_all_modules()]
files += [f"{src}/{name}" for _, src, _, names in build.data_files for name in names]
print(json.dumps(sorted(set(files))))
"""


def test_the_distribution_holds_every_tracked_file(tmp_path):
    """setuptools' own view of the files it would build (modules and package data), from a copy
    of the sources (its egg_info step writes beside them), against git's list."""
    tracked = _tracked("mcdenoise", "cli")
    src = tmp_path / "src"
    for rel in [*tracked, *_tracked("pyproject.toml", "setup.py", "README.md")]:
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / rel, src / rel)
    if not (src / "setup.py").exists():  # a layout configured in pyproject.toml alone
        (src / "setup.py").write_text("from setuptools import setup\n\nsetup()\n")
    out = subprocess.run(
        [sys.executable, "-c", _LIST_DISTRIBUTION],
        cwd=src,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    built = {str(Path(f)) for f in json.loads(out.strip().splitlines()[-1])}
    missing = sorted(set(tracked) - built)
    assert not missing, f"{len(missing)} tracked file(s) not in the distribution: {missing[:10]}"
    assert "mcdenoise/ao/ssao.py" in built and "mcdenoise/models/weights/kpcn.pt" in built
