"""Provenance of an experiment: versions, git commit, machine, and a hash of the input data.

Numbers without their conditions cannot be compared or reproduced, so every report records
the mcdenoise version, the git commit of the checkout it ran from (``"unknown"`` outside a git
checkout; read with ``git rev-parse HEAD``, which changes nothing), the versions of torch,
numpy, Mitsuba, OpenImageIO and the optional packages, the machine (:func:`machine_info`),
and :func:`data_hash`: the SHA-256 of the bytes of every input EXR (each noisy file with all
its levels and each reference), taken in a fixed order with each file's name.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import os
import subprocess
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from mcdenoise import __version__
from mcdenoise.experiments.timing import machine_info

#: Distributions whose versions are recorded (absent ones are written as ``null``).
PACKAGES = ("torch", "numpy", "mitsuba", "OpenImageIO", "OpenEXR", "pyoidn", "flip-evaluator")

#: How :func:`data_hash` is computed, for reports.
DATA_HASH_METHOD = (
    "sha256 over every input EXR (noisy files with all their spp levels, and references), "
    "sorted by path relative to the data folder; each file contributes its relative path and "
    "its bytes"
)


def package_versions(names: Iterable[str] = PACKAGES) -> dict[str, str | None]:
    """Installed version of each distribution (``None`` when not installed)."""
    out: dict[str, str | None] = {}
    for name in names:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = None
    return out


def git_commit(where: str | os.PathLike[str] | None = None) -> str:
    """The commit checked out at ``where`` (default: this package's folder), or ``"unknown"``."""
    folder = Path(where) if where is not None else Path(__file__).resolve().parent
    with contextlib.suppress(OSError, subprocess.SubprocessError):
        done = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=folder,
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
        commit = done.stdout.strip()
        if done.returncode == 0 and len(commit) == 40:
            return commit
    return "unknown"


def data_hash(root: str | os.PathLike[str], files: Iterable[str | os.PathLike[str]]) -> str:
    """SHA-256 (hex) of ``files`` (paths under ``root``), see :data:`DATA_HASH_METHOD`.

    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp()); _ = (d / "a.exr").write_bytes(b"x")
    >>> data_hash(d, [d / "a.exr"]) == data_hash(d, ["a.exr"])
    True
    """
    base = Path(root).resolve()
    rel = sorted({_relative(base, Path(f)) for f in files})
    h = hashlib.sha256()
    for name in rel:
        h.update(name.encode("utf-8") + b"\0")
        with open(base / name, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        h.update(b"\0")
    return h.hexdigest()


def _relative(base: Path, p: Path) -> str:
    full = p if p.is_absolute() else base / p
    try:
        return full.resolve().relative_to(base).as_posix()
    except ValueError:
        return full.resolve().as_posix()


def provenance(
    *, data_root: str | os.PathLike[str], files: Iterable[str | os.PathLike[str]]
) -> dict[str, Any]:
    """Everything a reader needs to know where the numbers come from (JSON-ready)."""
    return {
        "mcdenoise_version": __version__,
        "git_commit": git_commit(),
        "packages": package_versions(),
        "machine": machine_info(),
        "data_folder": str(Path(data_root).resolve()),
        "data_hash": data_hash(data_root, files),
        "data_hash_method": DATA_HASH_METHOD,
    }
