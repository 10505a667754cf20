"""The training-data layout of Intel Open Image Denoise's toolkit: read it and write it.

OIDN's training scripts (``training/`` of the OIDN sources; ``doc/training.md``) read a data
set as a folder tree of single-feature EXR files named

    <name>_<spp or ref>.<feature>.exr      e.g. view1_0004spp.hdr.exr, view1_ref.alb.exr

matching ``.+_([0-9]+(spp)?|ref|reference|gt|target)\\.(hdr|ldr|alb|nrm)\\.exr``: ``hdr``
is the HDR colour, ``ldr`` an LDR one, ``alb`` the albedo and ``nrm`` the normal, three
channels each (OIDN's reader takes the first three channels of the file). Every version of
one image (its noisy levels and its reference) sits in the same folder; the number of spp is
zero-padded to a fixed width; an image without an explicit ``ref``/``reference``/``gt``/
``target`` version takes the version with the most samples as its reference. Multi-channel
EXRs are not part of that layout (``split_exr.py`` makes them).

This module maps that layout onto :class:`~mcdenoise.io.buffers.FeatureBuffers` and back:

* :func:`find_oidn_images` finds every image of a tree: its id (the folder relative to the
  root joined with ``name``: ``scene1/view1``), its noisy versions by spp and its reference;
* :func:`read_oidn_level` reads one version's ``hdr`` (as ``color``), ``alb`` (``albedo``) and
  ``nrm`` (``normal``) files into one :class:`FeatureBuffers` with ``spp`` set. ``ldr``
  colour is not read: mcdenoise's methods and metrics are for linear HDR colour;
* :func:`write_oidn_layout` writes a render folder of ``mcdenoise render`` (``<id>.exr`` with
  parts ``spp<n>``, ``ref/<id>.exr``, ``manifest.json``) as such a tree: per image and level
  ``<id>_<spp:04d>spp.hdr.exr`` (+ ``.alb.exr``, ``.nrm.exr`` where the level has the
  feature) and ``<id>_ref.hdr.exr`` (+ the reference's features), channels ``R,G,B``,
  float32, so ``preprocess.py hdr alb nrm`` of OIDN's toolkit reads it. OIDN's normals are
  world- or camera-space unit vectors like mcdenoise's canonical ``normal``, its albedo the
  first-hit reflectance; both are written as stored. Everything else (variances, depth,
  motion) has no place in that layout and is left out.

Only still images: a folder of sequences (``--frames``) is refused with one line.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from mcdenoise.errors import InputError
from mcdenoise.io.atomic import TMP_PREFIX
from mcdenoise.io.buffer_files import load_buffers
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.io.exr import probe_exr, read_exr
from mcdenoise.io.exr_write import write_exr

#: The file names OIDN's toolkit reads (doc/training.md), with named groups.
OIDN_NAME = re.compile(
    r"^(?P<name>.+)_(?P<tag>[0-9]+(?:spp)?|ref|reference|gt|target)"
    r"\.(?P<feature>hdr|ldr|alb|nrm)\.exr$"
)
#: OIDN feature id -> mcdenoise buffer (``ldr`` has no buffer: not read).
FEATURES = {"hdr": "color", "alb": "albedo", "nrm": "normal"}
#: Tags that name the reference explicitly.
REFERENCE_TAGS = ("ref", "reference", "gt", "target")
#: Digits of the zero-padded spp that :func:`write_oidn_layout` writes (``0004spp``).
SPP_DIGITS = 4


@dataclass(frozen=True)
class OidnImage:
    """One image of an OIDN data set: ``id``, its noisy versions (spp -> ``.hdr.exr`` path)
    and its reference (``.hdr.exr`` path)."""

    id: str
    levels: dict[int, Path] = field(default_factory=dict)
    reference: Path | None = None


def parse_oidn_name(filename: str) -> tuple[str, str, str] | None:
    """``(name, tag, feature)`` of an OIDN file name, ``None`` for any other name.

    >>> parse_oidn_name("view1_0004spp.hdr.exr"), parse_oidn_name("cornell_spp4.exr")
    (('view1', '0004spp', 'hdr'), None)
    """
    m = OIDN_NAME.match(filename)
    return None if m is None else (m["name"], m["tag"], m["feature"])


def feature_file(hdr: str | os.PathLike[str], feature: str) -> Path:
    """The file of ``feature`` (``alb``, ``nrm``) beside the colour file ``hdr``.

    >>> feature_file("d/v_0004spp.hdr.exr", "alb").as_posix()
    'd/v_0004spp.alb.exr'
    """
    p = Path(hdr)
    return p.with_name(p.name[: -len(".hdr.exr")] + f".{feature}.exr")


def oidn_files(hdr: str | os.PathLike[str]) -> list[Path]:
    """The colour file ``hdr`` and the feature files beside it that exist."""
    p = Path(hdr)
    return [p] + [f for f in (feature_file(p, k) for k in ("alb", "nrm")) if f.is_file()]


def is_oidn_tree(root: str | os.PathLike[str]) -> bool:
    """True when ``root`` holds (anywhere below it) an OIDN colour file ``*_<tag>.hdr.exr``."""
    return any(
        OIDN_NAME.match(p.name) and p.name.endswith(".hdr.exr")
        for p in Path(root).rglob("*.hdr.exr")
    )


def find_oidn_images(root: str | os.PathLike[str]) -> list[OidnImage]:
    """Every image of the OIDN data set under ``root`` (sorted by id), see the module doc.

    Raises:
        InputError: no OIDN colour file, one image with two files of one spp (``0004spp`` and
            ``4spp``) or two references, or an image with a single version (no reference and
            nothing to denoise).
    """
    base = Path(root)
    found: dict[str, dict[str, list[Path]]] = {}
    for p in sorted(base.rglob("*.hdr.exr")):
        parsed = parse_oidn_name(p.name)
        if parsed is None or p.name.startswith(TMP_PREFIX):
            continue
        name, tag, _ = parsed
        rel = p.parent.relative_to(base).as_posix()
        image_id = name if rel == "." else f"{rel}/{name}"
        found.setdefault(image_id, {}).setdefault(tag, []).append(p)
    if not found:
        raise InputError(
            f"{base}: no OIDN colour file (<name>_<spp>spp.hdr.exr, <name>_ref.hdr.exr)"
        )
    images = []
    for image_id, tags in sorted(found.items()):
        levels: dict[int, Path] = {}
        refs = [p for t in REFERENCE_TAGS for p in tags.get(t, [])]
        for tag, paths in tags.items():
            if tag in REFERENCE_TAGS:
                continue
            spp = int(tag.removesuffix("spp"))
            if spp in levels or len(paths) > 1:
                raise InputError(f"{base}: image {image_id!r} has two files of {spp} spp")
            levels[spp] = paths[0]
        if len(refs) > 1:
            names = ", ".join(p.name for p in refs)
            raise InputError(f"{base}: image {image_id!r} has two references ({names})")
        reference = refs[0] if refs else None
        if reference is None and levels:  # OIDN: the most samples is the reference
            reference = levels.pop(max(levels))
        if reference is None or not levels:
            raise InputError(
                f"{base}: image {image_id!r} has no noisy version and a reference: OIDN's "
                "layout needs at least two (<name>_0004spp.hdr.exr, <name>_ref.hdr.exr)"
            )
        images.append(OidnImage(image_id, dict(sorted(levels.items())), reference))
    return images


def _rgb(path: Path) -> torch.Tensor:
    """The three channels of an OIDN feature file as ``(3, H, W)`` float32: ``R,G,B`` when
    the file has them, else its only three channels in file order."""
    parts = probe_exr(path)
    names = parts[0].channel_names
    if all(c in names for c in ("R", "G", "B")):
        chosen = ["R", "G", "B"]
    elif len(names) == 3:
        chosen = list(names)
    else:
        raise InputError(
            f"{path}: an OIDN feature file holds three channels (R, G, B); it has "
            f"{', '.join(names)}"
        )
    px = read_exr(path, channels=chosen).pixels
    return torch.from_numpy(np.stack([px[c] for c in chosen]).astype(np.float32))


def read_oidn_level(hdr: str | os.PathLike[str], spp: int | None = None) -> FeatureBuffers:
    """The version whose colour file is ``hdr`` (``..._0004spp.hdr.exr``) with its ``alb``
    and ``nrm`` files where they exist, as ``FeatureBuffers`` (``color``, ``albedo``,
    ``normal``); ``spp`` from the name unless given (``None`` for a reference)."""
    p = Path(hdr)
    buffers = {"color": _rgb(p)}
    for feature in ("alb", "nrm"):
        f = feature_file(p, feature)
        if f.is_file():
            buffers[FEATURES[feature]] = _rgb(f)
    shapes = {tuple(t.shape) for t in buffers.values()}
    if len(shapes) > 1:
        raise InputError(f"{p}: its feature files differ in size ({sorted(shapes)})")
    if spp is None and (parsed := parse_oidn_name(p.name)) is not None:
        tag = parsed[1]
        spp = None if tag in REFERENCE_TAGS else int(tag.removesuffix("spp"))
    return FeatureBuffers(buffers, spp=spp)


def _write_features(stem: Path, buffers: FeatureBuffers) -> list[Path]:
    written = []
    for feature, buffer in (("hdr", "color"), *((k, v) for k, v in FEATURES.items() if k != "hdr")):
        if buffer not in buffers:
            continue
        arr = buffers[buffer].numpy()
        path = stem.with_name(f"{stem.name}.{feature}.exr")
        write_exr(path, {"R": arr[0], "G": arr[1], "B": arr[2]})
        written.append(path)
    return written


def write_oidn_layout(
    dataset_dir: str | os.PathLike[str], out_dir: str | os.PathLike[str]
) -> list[Path]:
    """Write the render folder ``dataset_dir`` (``mcdenoise render`` output) in OIDN's
    training layout into ``out_dir`` (created); return the files written, in order.

    Per image ``<id>`` and level ``n``: ``<id>_<n:04d>spp.hdr.exr`` (``alb``, ``nrm`` where
    the level has albedo / normal); the reference as ``<id>_ref.hdr.exr`` (and its albedo
    and normal when it has them). Each file is written atomically.

    Raises:
        InputError: no ``manifest.json`` or an unreadable one, a folder of sequences, a file
            of the manifest missing.
    """

    src, out = Path(dataset_dir), Path(out_dir)
    manifest_path = src / "manifest.json"
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(
            f"{src}: no manifest.json; write_oidn_layout takes a folder of `mcdenoise render`"
        ) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(f"{manifest_path}: cannot read it: {err}") from None
    if (manifest.get("settings") or {}).get("frames") is not None:
        raise InputError(
            f"{src}: holds sequences (--frames); OIDN's training layout is for still images"
        )
    written: list[Path] = []
    out.mkdir(parents=True, exist_ok=True)
    for rec in manifest.get("images") or []:
        image_id = str(rec.get("id"))
        files = rec.get("files") or {}
        noisy, ref = src / str(files.get("noisy", "")), src / str(files.get("reference", ""))
        for p in (noisy, ref):
            if not p.is_file():
                raise InputError(f"{src}: image {image_id!r}: file {p} is missing")
        for lv in rec.get("levels") or []:
            spp, part = int(lv["spp"]), str(lv["part"])
            level = load_buffers(noisy, part=part)
            written += _write_features(out / f"{image_id}_{spp:0{SPP_DIGITS}d}spp", level)
        written += _write_features(out / f"{image_id}_ref", load_buffers(ref))
    if not written:
        raise InputError(f"{src}: the manifest lists no image")
    return written
