"""Experiments larger than one machine: shares of the units, shard records, the merge.

``mcdenoise experiment SPEC -o DIR --shard I/N`` runs a deterministic share of the
experiment's (scene, spp, method) units, so a cluster job array (Slurm ``--array=1-N``, or
any scheduler that hands out an index) spreads one experiment over ``N`` machines that share
the folder ``DIR``; ``--merge`` then builds the one report from every shard's records.

Which units a shard runs (:func:`shard_units`), a function of the spec alone, never of what
the folder holds, so shards started at different times agree:

* a spec that **renders** its scenes: whole scenes, the ones ``mcdenoise render --shard I/N``
  renders (scene ``k`` of the spec's list goes to shard ``k mod N + 1``). Rendering makes every
  level and the reference of an image at once, so a scene's units belong where its image is
  made: each shard renders its own images (``DIR/data/manifest.shard-I-of-N.json``) and
  denoises them, never waits for another shard and never renders an image twice. A spec of
  ``S`` scenes keeps at most ``S`` shards busy.
* a spec with ``[scenes] folder`` (the data exists): unit ``k`` of the plan (scene by scene,
  lowest level first, ``noisy`` first) goes to shard ``k mod N + 1``, like the images of
  ``mcdenoise render --shard``: every shard gets every method and level, so the shares take
  about equal time.

Who may run in ``DIR`` at once (:func:`folder_lock`): a plain run (or a merge) holds
``DIR/work/experiment.lock``, shard ``I/N`` holds ``DIR/work/shards/shard-I-of-N.lock``
(:class:`~mcdenoise.io.lockfile.LockFile`: host, PID, a heartbeat; a dead or silent holder's
lock is taken over). Shards on several hosts therefore share the folder, while a second
process for the same shard, a plain run beside running shards, or two plain runs are refused
in one line naming the holder: two runs would run the same units twice and time them against
each other.

Every unit record is written into ``DIR/work`` as in a single run, with the host that ran it
(``host``, ``cpu``), and every shard writes ``DIR/work/shards/shard-I-of-N.json`` (host,
start and end, units run, reused and refused), so the merge can say which shards have not
finished. The merge runs nothing: it reads the records whose fingerprint matches the spec
(the device recorded by each shard, so a merge on a machine without the shards' GPU still
finds them) and refuses, in one line, when a unit has none. A plain run of the spec once every
shard is done also reuses every record (when it resolves the same device) and writes the same
report.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import json
import socket
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from mcdenoise.experiments.spec_fields import ExperimentError
from mcdenoise.io.atomic import write_text_atomic
from mcdenoise.io.lockfile import LockError, LockFile, live_holder
from mcdenoise.render.manifest import MANIFEST, load_manifest

#: Folder of the shard records, under ``DIR/work``.
SHARDS = "shards"
#: Version of the shard records.
SHARD_SCHEMA = "mcdenoise.experiment-shard/1"


def host_name() -> str:
    """This machine's host name (what a unit record's ``host`` is)."""
    return socket.gethostname() or "unknown"


def shard_units(
    units: Sequence[Any],
    shard: tuple[int, int],
    *,
    scene_index: Mapping[str, int] | None = None,
) -> list[Any]:
    """The units of shard ``shard = (i, n)`` (1-based), see the module docstring.

    ``scene_index``: scene id -> index of its image in the spec's render jobs; given, whole
    scenes are shared (``index mod n``); otherwise single units (position ``mod n``).

    >>> units = ["a1", "a2", "a3", "b1", "b2", "b3"]
    >>> shard_units(units, (1, 2)), shard_units(units, (2, 2))
    (['a1', 'a3', 'b2'], ['a2', 'b1', 'b3'])
    """
    i, n = shard
    if scene_index is None:
        return [u for k, u in enumerate(units) if k % n == i - 1]
    return [u for u in units if scene_index[u.scene.id] % n == i - 1]


def shard_path(out: Path, shard: tuple[int, int]) -> Path:
    """``DIR/work/shards/shard-<i>-of-<n>.json``."""
    return out / "work" / SHARDS / f"shard-{shard[0]}-of-{shard[1]}.json"


def lock_path(out: Path, shard: tuple[int, int] | None) -> Path:
    """The lock file of a run: ``DIR/work/experiment.lock``, or a shard's beside its record."""
    if shard is None:
        return out / "work" / "experiment.lock"
    return shard_path(out, shard).with_suffix(".lock")


@contextlib.contextmanager
def folder_lock(out: Path, shard: tuple[int, int] | None) -> Iterator[LockFile]:
    """Hold the lock of a plain run or merge (``shard=None``) or of shard ``shard`` of the
    experiment folder ``out`` for the block (see the module docstring).

    Raises:
        LockError: another live process holds this lock, or holds a lock this one excludes
            (a plain run and any shard); one line naming it.
    """
    what = "an experiment run" if shard is None else f"shard {shard[0]}/{shard[1]}"
    with LockFile(lock_path(out, shard), what) as lock:
        # taken first, checked second: two that start together both refuse, never both run
        others = [lock_path(out, None)] if shard is not None else []
        if shard is None and (out / "work" / SHARDS).is_dir():
            others = sorted((out / "work" / SHARDS).glob("shard-*-of-*.lock"))
        for other in others:
            holder = live_holder(other)
            if holder is not None:
                raise LockError(
                    f"{out} is in use: {holder.describe()} holds {other}; "
                    + (
                        "run the shards, then --merge, once every shard has finished"
                        if shard is None
                        else "a plain run and shards cannot share the folder at once"
                    )
                )
        yield lock


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).astimezone().isoformat(timespec="seconds")


def write_shard_record(
    out: Path,
    shard: tuple[int, int],
    *,
    units: Sequence[tuple[str, int, str]],
    started: str,
    finished: bool,
    ran: Sequence[tuple[str, int, str]] = (),
    reused: Sequence[tuple[str, int, str]] = (),
    refused: Sequence[tuple[str, int, str]] = (),
    machine: Mapping[str, Any] | None = None,
) -> Path:
    """Write shard ``shard``'s record (atomically): what it was given and what it did."""
    path = shard_path(out, shard)
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {
        "schema": SHARD_SCHEMA,
        "shard": list(shard),
        "host": host_name(),
        "machine": dict(machine or {}),
        "started": started,
        "finished": _now() if finished else None,
        "units": [list(k) for k in units],
        "ran": len(ran),
        "reused": len(reused),
        "refused": [list(k) for k in refused],
    }
    write_text_atomic(path, json.dumps(record, indent=1, allow_nan=False) + "\n")
    return path


def read_shard_records(out: Path) -> list[dict[str, Any]]:
    """Every readable shard record of ``DIR``, by shard number."""
    folder = out / "work" / SHARDS
    records = []
    for p in sorted(folder.glob("shard-*-of-*.json")) if folder.is_dir() else []:
        try:
            data = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            continue
        if isinstance(data, dict) and data.get("schema") == SHARD_SCHEMA:
            records.append(data)
    return sorted(records, key=lambda r: tuple(r.get("shard") or (0, 0)))


def missing_message(
    out: Path,
    missing: Sequence[tuple[str, int, str]] | Sequence[str],
    total: int,
    *,
    what: str = "units have no finished record",
) -> str:
    """One line for a merge that lacks ``missing`` (unit keys, or image ids with ``what``):
    how many, which shards have not finished (from their records), and what to do."""
    shards = read_shard_records(out)
    counts = {int(r["shard"][1]) for r in shards if r.get("shard")}
    where = ""
    if len(counts) == 1:
        n = counts.pop()
        done = {int(r["shard"][0]) for r in shards if r.get("finished") and r["shard"][1] == n}
        started = {int(r["shard"][0]) for r in shards if r["shard"][1] == n}
        running = sorted(started - done)
        never = sorted(set(range(1, n + 1)) - started)
        bits = []
        if running:
            bits.append("started, not finished: " + ", ".join(f"{i}/{n}" for i in running))
        if never:
            bits.append("never started: " + ", ".join(f"{i}/{n}" for i in never))
        where = f" (shards {'; '.join(bits)})" if bits else ""
    named = [m if isinstance(m, str) else f"{m[0]} {m[1]} spp {m[2]}" for m in missing]
    first = ", ".join(named[:3])
    more = f" and {len(named) - 3} more" if len(named) > 3 else ""
    return (
        f"{out}: {len(named)} of {total} {what}{where}: {first}{more}; "
        "run the missing shards (--shard I/N) and merge again"
    )


def check_rendered(folder: Path, ids: Sequence[str], out: Path) -> None:
    """For a merge of a rendering spec: raise :class:`ExperimentError` (one line: how many
    images, which shards) unless the render folder's manifest lists every image ``ids``."""

    have: set[str] = set()
    if (folder / MANIFEST).is_file():
        have = {str(r.get("id")) for r in load_manifest(folder).get("images", [])}
    missing = [x for x in ids if x not in have]
    if missing:
        raise ExperimentError(
            missing_message(out, missing, len(ids), what="images are not rendered yet")
        )


def timing_hosts(records: Sequence[Mapping[str, Any]]) -> dict[str, int]:
    """Host -> number of timed units (a denoiser ran and was timed) it ran; records written
    before hosts were recorded count as ``"unknown"``."""
    hosts: dict[str, int] = {}
    for r in records:
        if r.get("timing") is None:
            continue
        h = str(r.get("host") or "unknown")
        hosts[h] = hosts.get(h, 0) + 1
    return dict(sorted(hosts.items()))


def hosts_note(hosts: Mapping[str, int]) -> str | None:
    """The report's note when denoise times come from more than one machine (``None`` for
    one): every time comparison across methods then compares machines too."""
    if len(hosts) < 2:
        return None
    listed = ", ".join(f"{h} ({c} units)" for h, c in hosts.items())
    return (
        f"denoise times were measured on {len(hosts)} machines: {listed} (results.csv column "
        "'host'). Total times, the Pareto fronts, the equal-time tables and the speed-ups "
        "compare methods timed on different machines; render times come from the render "
        "folder's manifest, from whichever machine rendered each image"
    )


def with_device(settings: Any, device: str | None) -> Any:
    """``settings`` with the device a shard recorded (its fingerprint's device)."""
    if device is None or device == settings.device:
        return settings
    return dataclasses.replace(settings, device=device)
