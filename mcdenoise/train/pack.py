"""A packed training set: the prepared training and validation items of a data set in one
``.npz`` file, read with numpy and torch alone.

``mcdenoise train --model kpcn --data DIR --pack SET.npz`` scans, splits and prepares ``DIR``
exactly as training does (:func:`~mcdenoise.train.patches.scan_dataset`,
:func:`~mcdenoise.train.patches.split_images`, :func:`~mcdenoise.train.patches.load_items` with
the model's ``prepare`` hook) and writes the tensors; ``mcdenoise train --data SET.npz`` then
trains from the file (a ``.npz`` ``data`` is a pack) without reading an EXR, so without
OpenImageIO, OpenEXR or Mitsuba: a machine with only torch and numpy can train.

Exactness: with ``dtype="float32"`` the items are the folder's bit for bit, and training gives
the same weights for the same config. ``float16`` (the default: half the size) rounds every
value to 11 significant bits (relative error <= 2^-11); an array with a finite value beyond
float16's range (65504, e.g. a firefly's colour variance) is kept in float32. Tiny values
(feature variances below ~6e-8) become 0 or subnormal; the model sees variances through
``log1p(sqrt(var))``, where that changes nothing measurable.

The pack records the config keys its preparation depends on (the model's ``keys``, e.g. the
split's ``seed``, ``val_fraction``, ``levels``, ``max_images`` and kpcn's ``prefilter``); a
training config that differs in one of them is refused, naming the difference. The crop size
is not one of them: training images are packed whatever their size, and those smaller than
the run's crop are skipped when the pack is read, with the reason the folder would give.
Each level's reference is stored once per image when the levels share it.
"""

from __future__ import annotations

import contextlib
import json
import os
import zipfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mcdenoise.errors import InputError
from mcdenoise.io.atomic import atomic_path
from mcdenoise.progress import Mode
from mcdenoise.train.patches import (
    REFERENCE,
    Entry,
    Item,
    LoadReport,
    load_items,
    load_split,
    scan_dataset,
    split_images,
)

#: File name suffix that makes a ``data`` path a pack.
PACK_SUFFIX = ".npz"
#: Format version written into (and required of) a pack.
PACK_VERSION = 1
#: Storage dtypes of :func:`write_pack`.
PACK_DTYPES = ("float16", "float32")
#: Largest finite float16 value: an array beyond it is stored in float32.
FLOAT16_MAX = float(np.finfo(np.float16).max)
_META = "meta"


def is_pack(data: str | os.PathLike[str] | None) -> bool:
    """Whether a ``data`` path names a pack (its name ends in :data:`PACK_SUFFIX`)."""
    return bool(data) and str(data).lower().endswith(PACK_SUFFIX)


@dataclass
class PackSummary:
    """What :func:`write_pack` wrote."""

    path: Path
    train_levels: int
    val_levels: int
    arrays: int
    float32_arrays: int
    bytes: int
    files: int = 1

    def line(self) -> str:
        parts = f" in {self.files} files" if self.files > 1 else ""
        return (
            f"packed {self.train_levels} training and {self.val_levels} validation level(s) "
            f"into {self.path} ({self.bytes / 2**20:.1f} MiB{parts}, {self.arrays} arrays, "
            f"{self.float32_arrays} kept in float32)"
        )


def _stored(v: torch.Tensor, dtype: str) -> np.ndarray:
    a = v.detach().cpu().float().contiguous().numpy()
    if dtype == "float16" and float(np.abs(a).max(initial=0.0)) <= FLOAT16_MAX:
        return a.astype(np.float16)
    return a


def write_pack(
    path: str | os.PathLike[str],
    train: Sequence[Item],
    val: Sequence[Item],
    report: LoadReport,
    *,
    config: Mapping[str, Any],
    source: str,
    dtype: str = "float16",
    compress: bool = True,
    shard_bytes: int = 0,
) -> PackSummary:
    """Write prepared items to the pack ``path`` (atomically: temporary files, renamed).

    Args:
        config: the config values the preparation depended on (checked when read).
        source: the data folder the items came from (recorded).
        dtype: ``float16`` (values beyond float16's range keep float32) or ``float32``.
        compress: zip deflate (as ``np.savez_compressed``) rather than stored (``np.savez``).
        shard_bytes: > 0: once a file holds this many bytes, the next arrays go to a new
            file beside it, ``SET.part1.npz``, ``SET.part2.npz``, ... (each about
            ``shard_bytes``, the main file also the metadata): parts that travel separately.
            The reader needs every part beside the main file.
    """
    if dtype not in PACK_DTYPES:
        raise InputError(f"pack dtype must be one of {', '.join(PACK_DTYPES)}, got {dtype!r}")
    out = Path(path)
    if not is_pack(out):
        raise InputError(f"{out}: a pack's name must end in {PACK_SUFFIX}")
    arrays: dict[str, np.ndarray] = {}
    records: list[dict[str, Any]] = []
    shared: list[tuple[str, torch.Tensor]] = []  # (array name, reference) of earlier levels

    def add(v: torch.Tensor) -> str:
        name = f"a{len(arrays)}"
        arrays[name] = _stored(v, dtype)
        return name

    for split, items in (("train", train), ("val", val)):
        for it in items:
            e = it.entry
            names = {}
            for key, v in it.tensors.items():
                if key == REFERENCE:
                    same = [n for n, r in shared if r is v or torch.equal(r, v)]
                    if same:
                        names[key] = same[0]
                        continue
                    names[key] = add(v)
                    shared = [(names[key], v)]  # levels of one image are consecutive
                else:
                    names[key] = add(v)
            records.append(
                {
                    "split": split,
                    "image": e.image,
                    "path": str(e.path),
                    "part": e.part,
                    "reference": str(e.reference),
                    "spp": e.spp,
                    "arrays": names,
                }
            )
    meta = {
        "format": "mcdenoise training pack",
        "version": PACK_VERSION,
        "source": source,
        "dtype": dtype,
        "config": dict(config),
        "items": records,
        "skipped": [list(s) for s in report.skipped],
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    files = _write_shards(out, arrays, meta, compress=compress, shard_bytes=shard_bytes)
    n32 = sum(1 for a in arrays.values() if a.dtype == np.float32)
    return PackSummary(
        out,
        len(train),
        len(val),
        len(arrays),
        n32 if dtype == "float16" else 0,
        sum(f.stat().st_size for f in files),
        len(files),
    )


def shard_path(path: Path, index: int) -> Path:
    """File ``index`` (>= 1) of a pack split into shards: ``SET.part<index>.npz``."""
    return path.with_name(f"{path.name[: -len(PACK_SUFFIX)]}.part{index}{PACK_SUFFIX}")


def _write_shards(
    out: Path,
    arrays: Mapping[str, np.ndarray],
    meta: dict[str, Any],
    *,
    compress: bool,
    shard_bytes: int,
) -> list[Path]:
    """The arrays into ``out`` (with the metadata) and, past ``shard_bytes`` of written file
    (0: no limit), into ``out``'s shards; each a ``.npz`` as ``np.savez`` writes it. Each
    file is written as every file of the tool is (:func:`~mcdenoise.io.atomic.atomic_path`:
    a temporary, flushed to the disk, checked to be a complete zip archive, renamed), the
    main file last, so a reader never finds a main file whose shards are missing. Returns
    the files."""
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    zips: list[zipfile.ZipFile] = []
    finals: list[Path] = []

    def complete(tmp: Path) -> None:
        if not zipfile.is_zipfile(tmp):
            raise OSError(0, f"the pack written is incomplete ({tmp.stat().st_size} bytes)")

    def put(zf: zipfile.ZipFile, name: str, a: np.ndarray) -> None:
        with zf.open(f"{name}.npy", "w", force_zip64=True) as fid:
            np.lib.format.write_array(fid, a, allow_pickle=False)

    # contexts leave in reverse order: the main file (entered first) is renamed last
    with contextlib.ExitStack() as stack:

        def open_zip(index: int) -> zipfile.ZipFile:
            final = out if index == 0 else shard_path(out, index)
            tmp = stack.enter_context(atomic_path(final, verify=complete))
            finals.append(final)
            zips.append(zipfile.ZipFile(tmp, "w", compression=method, allowZip64=True))
            return zips[-1]

        shard_of: dict[str, int] = {}
        try:
            current = open_zip(0)
            for name, a in arrays.items():
                if shard_bytes > 0 and current.fp is not None and current.fp.tell() >= shard_bytes:
                    if len(zips) > 1:
                        current.close()
                    current = open_zip(len(zips))
                put(current, name, a)
                if len(zips) > 1:
                    shard_of[name] = len(zips) - 1
            meta = {
                **meta,
                "shards": [shard_path(out, i).name for i in range(1, len(zips))],
                "shard_of": shard_of,
            }
            put(zips[0], _META, np.array(json.dumps(meta)))
        finally:
            for zf in zips:
                zf.close()
    return finals


def pack_items(
    cfg: Any,
    prepare: Callable[..., dict[str, torch.Tensor]],
    path: str | os.PathLike[str],
    *,
    keys: Sequence[str],
    dtype: str = "float16",
    compress: bool = True,
    shard_bytes: int = 0,
    progress: Mode = False,
) -> PackSummary:
    """Scan, split and prepare ``cfg.data`` as :func:`~mcdenoise.train.patches.load_split`
    does (every training image whatever its size) and write the pack ``path``; ``keys``: the
    config keys the preparation depends on.

    Raises:
        InputError: no usable training image, a bad ``dtype`` or file name.
    """
    entries = scan_dataset(cfg.data, cfg.levels)
    train_e, val_e = split_images(entries, cfg.val_fraction, cfg.seed, cfg.max_images)
    train, report = load_items(train_e, prepare, min_size=1, progress=progress)
    val, val_report = load_items(val_e, prepare, min_size=1, progress=progress)
    report.skipped += val_report.skipped
    if not train:
        raise InputError(f"{cfg.data}: no usable training image\n{report.summary()}")
    values = cfg.to_dict()
    return write_pack(
        path,
        train,
        val,
        report,
        config={k: values[k] for k in keys},
        source=str(cfg.data),
        dtype=dtype,
        compress=compress,
        shard_bytes=shard_bytes,
    )


def _open(path: Path) -> Any:
    if not path.is_file():
        raise InputError(f"{path}: no such pack (make one with mcdenoise train --pack)")
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError) as err:
        raise InputError(f"{path}: not a readable training pack ({err})") from None


def pack_meta(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The metadata of the pack ``path`` (source folder, dtype, config, items, skipped)."""
    p = Path(path)
    with _open(p) as z:
        if _META not in z.files:
            raise InputError(f"{p}: not a training pack (no metadata)")
        try:
            meta = json.loads(str(z[_META]))
        except (ValueError, RecursionError):
            meta = None
    if not isinstance(meta, dict) or not isinstance(meta.get("config"), dict):
        raise InputError(f"{p}: not a training pack (its metadata is not a pack's)")
    if meta.get("version") != PACK_VERSION:
        raise InputError(f"{p}: pack version {meta.get('version')!r}, expected {PACK_VERSION}")
    return meta


def read_pack(
    cfg: Any, *, crop: int, keys: Sequence[str] = ()
) -> tuple[list[Item], list[Item], LoadReport]:
    """The pack ``cfg.data`` as :func:`~mcdenoise.train.patches.load_split` returns a folder:
    ``(train items, validation items, report)``; training images smaller than ``crop`` are
    skipped and reported.

    Raises:
        InputError: not a pack, a config that differs from the pack's in one of ``keys`` (or
            of the keys the pack recorded), or no usable training image.
    """
    path = Path(cfg.data)
    meta = pack_meta(path)
    values = cfg.to_dict()
    packed = meta["config"]
    diff = [
        f"{k}: pack {packed.get(k)!r}, config {values.get(k)!r}"
        for k in sorted({*packed, *keys})
        if packed.get(k) != values.get(k)
    ]
    if diff:
        raise InputError(
            f"{path}: the pack was prepared with another config ({'; '.join(diff)}); "
            "pack the data again with these settings"
        )
    try:
        return _read_items(path, meta, crop)
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as err:
        # a pack is a file from anywhere: metadata that does not hold together is refused
        why = f"{type(err).__name__}: {err}"[:200]
        raise InputError(f"{path}: not a valid training pack ({why})") from None


def _read_items(
    path: Path, meta: dict[str, Any], crop: int
) -> tuple[list[Item], list[Item], LoadReport]:
    """:func:`read_pack`'s reading, after the config check. The shards are the files
    :func:`shard_path` names beside ``path`` (never a path the metadata gives: a pack may
    come from anyone)."""
    report = LoadReport(skipped=[(str(a), str(b)) for a, b in meta["skipped"]])
    train: list[Item] = []
    val: list[Item] = []
    shard_of: dict[str, int] = meta.get("shard_of", {})
    with contextlib.ExitStack() as stack:
        files = [stack.enter_context(_open(path))]
        for i, name in enumerate(meta.get("shards", []), start=1):
            shard = shard_path(path, i)
            if name != shard.name:
                raise ValueError(f"shard {i} is named {name!r}, not {shard.name!r}")
            files.append(stack.enter_context(_open(shard)))
        cache: dict[str, torch.Tensor] = {}

        def tensor(name: str) -> torch.Tensor:
            if name not in cache:
                a = files[shard_of.get(name, 0)][name]
                cache[name] = torch.from_numpy(a).float().contiguous()
            return cache[name]

        for rec in meta["items"]:
            entry = Entry(
                rec["image"], Path(rec["path"]), rec["part"], Path(rec["reference"]), rec["spp"]
            )
            item = Item(entry, {k: tensor(n) for k, n in rec["arrays"].items()})
            if rec["split"] == "train":
                if min(item.size) < crop:
                    report.skipped.append((entry.name, f"smaller than a training crop ({crop} px)"))
                    continue
                train.append(item)
            else:
                val.append(item)
            # only a reference is shared (by the levels of one image, which are consecutive)
            cache = {k: v for k, v in cache.items() if k == rec["arrays"].get(REFERENCE)}
    report.used = len(train)  # as load_split reports it
    if not train:
        raise InputError(f"{path}: no usable training image\n{report.summary()}")
    return train, val, report


def load_training_data(
    cfg: Any,
    prepare: Callable[..., dict[str, torch.Tensor]],
    *,
    crop: int,
    keys: Sequence[str] = (),
    progress: Mode = False,
) -> tuple[list[Item], list[Item], LoadReport]:
    """:func:`read_pack` when ``cfg.data`` is a pack, else
    :func:`~mcdenoise.train.patches.load_split` of the folder."""
    if is_pack(cfg.data):
        return read_pack(cfg, crop=crop, keys=keys)
    return load_split(cfg, prepare, crop=crop, progress=progress)


__all__ = [
    "FLOAT16_MAX",
    "PACK_DTYPES",
    "PACK_SUFFIX",
    "PackSummary",
    "is_pack",
    "load_training_data",
    "pack_items",
    "pack_meta",
    "read_pack",
    "shard_path",
    "write_pack",
]
