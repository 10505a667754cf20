"""Render manifests: what a render folder holds, shard by shard, merged.

Every ``mcdenoise render`` run writes its own shard manifest
``manifest.shard-<i>-of-<n>.json`` (one record per finished image or sequence) and then
rebuilds ``manifest.json`` from all shard manifests present, under an exclusive lock on
``.manifest.lock``, so n jobs of a cluster array writing into one shared folder end with one
merged manifest. An image recorded by several shards keeps its latest record. All writes are
atomic (:func:`mcdenoise.io.atomic.write_text_atomic`).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from mcdenoise.errors import McdenoiseError
from mcdenoise.io.atomic import write_text_atomic

MANIFEST = "manifest.json"
MANIFEST_FORMAT = "mcdenoise-render"
MANIFEST_VERSION = 1
LOCK_FILE = ".manifest.lock"
_SHARD_RE = re.compile(r"^manifest\.shard-(\d+)-of-(\d+)\.json$")


class ManifestError(McdenoiseError, ValueError):
    """A manifest is unreadable, of another format/version, or shards disagree."""


def shard_manifest_name(i: int, n: int) -> str:
    return f"manifest.shard-{i}-of-{n}.json"


def read_manifest(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ManifestError(f"{path}: unreadable manifest ({' '.join(str(err).split())})") from None
    if not isinstance(data, dict) or data.get("format") != MANIFEST_FORMAT:
        raise ManifestError(f"{path}: not an mcdenoise render manifest")
    if data.get("version") != MANIFEST_VERSION:
        raise ManifestError(
            f"{path}: manifest version {data.get('version')!r}, this mcdenoise reads "
            f"{MANIFEST_VERSION}"
        )
    return data


def shard_manifests(out: str | os.PathLike[str]) -> dict[str, dict[str, Any]]:
    """File name -> content of every ``manifest.shard-<i>-of-<n>.json`` in ``out``."""
    folder = Path(out)
    found = {}
    if folder.is_dir():
        for p in sorted(folder.iterdir()):
            if _SHARD_RE.match(p.name):
                found[p.name] = read_manifest(p)
    return found


def latest_records(records: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """id -> the most recently finished record of that id."""
    best: dict[str, dict[str, Any]] = {}
    for r in records:
        rid = r.get("id")
        if isinstance(rid, str) and (
            rid not in best
            or str(r.get("finished_at", "")) >= str(best[rid].get("finished_at", ""))
        ):
            best[rid] = dict(r)
    return best


@contextlib.contextmanager
def _folder_lock(out: Path) -> Iterator[None]:
    """An exclusive ``flock`` on ``out/.manifest.lock`` (a no-op where flock is missing)."""
    try:
        import fcntl  # lazy: optional, see except
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    with open(out / LOCK_FILE, "a+") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def merge_manifests(out: str | os.PathLike[str]) -> dict[str, Any] | None:
    """Rebuild ``out/manifest.json`` from every shard manifest in ``out``; return it
    (``None`` when there is no shard manifest). Images recorded twice keep their latest record.

    Raises:
        RenderError: shard manifests of different settings, or an unreadable manifest.
    """
    folder = Path(out)
    with _folder_lock(folder):
        shards = shard_manifests(folder)
        if not shards:
            return None
        settings = [m.get("settings") for m in shards.values()]
        if any(s != settings[0] for s in settings):
            raise ManifestError(f"{folder}: shard manifests record different settings: {settings}")
        images = sorted(
            latest_records([r for m in shards.values() for r in m.get("images", [])]).values(),
            key=lambda r: (r.get("index", 0), r.get("id", "")),
        )
        merged = {
            "format": MANIFEST_FORMAT,
            "version": MANIFEST_VERSION,
            "settings": settings[0],
            "variants": sorted({str(r.get("variant")) for r in images}),
            "mitsuba_versions": sorted({str(r.get("mitsuba_version")) for r in images}),
            "shards": sorted(shards),
            "image_count": len(images),
            "render_seconds": round(sum(record_seconds(r) for r in images), 3),
            "images": images,
        }
        write_text_atomic(folder / MANIFEST, json.dumps(merged, indent=1, allow_nan=False) + "\n")
    return merged


def load_manifest(out: str | os.PathLike[str]) -> dict[str, Any]:
    """The merged ``manifest.json`` of a render folder (or of the file given)."""
    p = Path(out)
    return read_manifest(p / MANIFEST if p.is_dir() else p)


def record_seconds(record: Mapping[str, Any]) -> float:
    """Render seconds of an image or frame record (last level + reference), or of a sequence
    record (the sum over its frames)."""
    if isinstance(record.get("frames"), list):
        return float(sum(record_seconds(f) for f in record["frames"]))
    levels = record.get("levels") or []
    return float(levels[-1]["render_seconds"] if levels else 0.0) + float(
        (record.get("reference") or {}).get("render_seconds", 0.0)
    )


def write_shard_manifest(
    out: Path,
    name: str,
    settings: Mapping[str, Any],
    i: int,
    n: int,
    records: Mapping[str, Mapping[str, Any]],
) -> None:
    data = {
        "format": MANIFEST_FORMAT,
        "version": MANIFEST_VERSION,
        "settings": dict(settings),
        "shard": {"index": i, "count": n},
        "images": sorted(records.values(), key=lambda r: (r.get("index", 0), r.get("id", ""))),
    }
    write_text_atomic(out / name, json.dumps(data, indent=1, allow_nan=False) + "\n")
