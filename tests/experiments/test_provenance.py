"""Tests of ``mcdenoise/experiments/provenance.py``: data hash, git commit, versions."""

from __future__ import annotations

import re
from pathlib import Path

from mcdenoise.experiments.provenance import data_hash, git_commit, package_versions


def test_data_hash_depends_on_bytes_and_names_not_on_order(tmp_path: Path):
    (tmp_path / "ref").mkdir()
    a, b = tmp_path / "a.exr", tmp_path / "ref" / "a.exr"
    a.write_bytes(b"noisy")
    b.write_bytes(b"reference")
    h = data_hash(tmp_path, [a, b])
    assert re.fullmatch(r"[0-9a-f]{64}", h)
    assert data_hash(tmp_path, [b, a]) == h == data_hash(tmp_path, ["ref/a.exr", "a.exr"])
    b.write_bytes(b"referencf")
    assert data_hash(tmp_path, [a, b]) != h
    b.write_bytes(b"reference")
    b.rename(tmp_path / "ref" / "c.exr")  # same bytes, other name
    assert data_hash(tmp_path, [a, tmp_path / "ref" / "c.exr"]) != h


def test_git_commit_and_versions(tmp_path: Path):
    assert git_commit(tmp_path) == "unknown"  # not a git checkout
    here = git_commit()
    assert here == "unknown" or re.fullmatch(r"[0-9a-f]{40}", here)
    versions = package_versions(["numpy", "no-such-package-xyz"])
    assert versions["numpy"] and versions["no-such-package-xyz"] is None
