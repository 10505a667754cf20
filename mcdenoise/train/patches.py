"""Training patches from a data set rendered by ``mcdenoise render``.

Layout read (see :mod:`mcdenoise.render.generate`): ``DIR/<id>.exr`` with one part per spp level
(``spp4``, ``spp16``, ...) and the reference ``DIR/ref/<id>.exr``; sequences
``DIR/<seq>/frame_NNNN.exr`` with ``DIR/<seq>/ref/frame_NNNN.exr``. Any EXR not under a ``ref``
folder whose ``ref/<same name>`` exists is an input; single-part files are one level.

Pipeline:

1. :func:`scan_dataset` lists the (input, part, reference) triples; :func:`split_images`
   splits them into training and validation **by image** (all levels and frames of an image
   go to the same side), seeded.
2. :func:`load_items` reads each level and its reference once and hands them to a model's
   ``prepare(buffers, reference) -> {name: (C, H, W) tensor}`` hook (e.g. the filter input
   preparation and per-pixel features, computed on the whole image so that a patch sees
   exactly what the model sees at inference). Images that cannot be used are *reported* with
   their file and reason, never silently dropped: NaN/Inf in the reference, a constant
   reference, a missing buffer the model needs, an image smaller than a patch.
3. :class:`PatchSampler` draws batches of ``patch + 2 margin`` crops. A share ``importance``
   of the crops is drawn with probability proportional to the noisy input's mean relMSE over
   the patch (noisy, high-error regions: edges, caustics, dark noisy corners), the rest
   uniformly. Each crop comes with a loss ``mask``: the pixels whose filter footprint
   (``margin`` pixels on each side) is the same in the crop as in the whole image -- the
   crop's centre, plus the strips along the image's own borders. A filter of radius
   ``<= margin`` gives the masked pixels exactly their whole-image values.
"""

from __future__ import annotations

import os
import platform
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from mcdenoise.errors import InputError, McdenoiseError
from mcdenoise.io import load_buffers
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.io.exr import probe_exr
from mcdenoise.io.oidn_layout import (
    find_oidn_images,
    is_oidn_tree,
    parse_oidn_name,
    read_oidn_level,
)
from mcdenoise.losses import relmse, relmse_map
from mcdenoise.progress import Mode, progress_bar

#: Key of the reference colour in a prepared item.
REFERENCE = "reference"

Prepare = Callable[[FeatureBuffers, Tensor], dict[str, Tensor]]


@dataclass(frozen=True)
class Entry:
    """One noisy level of one image and its reference.

    Attributes:
        image: image id (relative path of the input without ``.exr``; the sequence folder
            for frames, so frames split together).
        path: the input EXR.
        part: the part holding the level (``None`` for single-part files).
        reference: the reference EXR.
        spp: samples per pixel of the level, when known from the part name.
    """

    image: str
    path: Path
    part: str | None
    reference: Path
    spp: int | None

    @property
    def name(self) -> str:
        return f"{self.path.name}" + (f"[{self.part}]" if self.part else "")


def _spp_of(part: str | None) -> int | None:
    if part and part.startswith("spp") and part[3:].isdigit():
        return int(part[3:])
    return None


def _read(path: Path, part: str | None) -> FeatureBuffers:
    """A level or reference: an OIDN-layout file (``*_0004spp.hdr.exr`` with its ``.alb`` /
    ``.nrm``) through :func:`mcdenoise.io.oidn_layout.read_oidn_level`, else the EXR."""

    return read_oidn_level(path) if parse_oidn_name(path.name) else load_buffers(path, part=part)


def scan_dataset(root: str | os.PathLike[str], levels: Sequence[int] = ()) -> list[Entry]:
    """Every (input level, reference) pair under ``root``, sorted by path then spp.

    Args:
        root: folder written by ``mcdenoise render``.
        levels: keep only these spp levels (empty: all).

    Raises:
        InputError: ``root`` is not a folder, or holds no input with a reference.
    """
    base = Path(root)
    if not base.is_dir():
        raise InputError(f"{base}: not a folder (expected a data set made by mcdenoise render)")
    entries: list[Entry] = []
    for path in sorted(base.rglob("*.exr")):
        rel = path.relative_to(base)
        if "ref" in rel.parts[:-1] or path.name.startswith("."):
            continue
        ref = path.parent / "ref" / path.name
        if not ref.is_file():
            continue
        image = str(rel.parent) if rel.parent != Path(".") else rel.stem
        parts = [p.name for p in probe_exr(path)]
        named = [p for p in parts if _spp_of(p) is not None]
        for part in named or [None]:  # type: ignore[list-item]
            spp = _spp_of(part)
            if levels and spp not in levels:
                continue
            entries.append(Entry(image, path, part, ref, spp))
    if not entries:
        if is_oidn_tree(base):  # OIDN's training layout: <name>_0004spp.hdr.exr + _ref.hdr.exr
            for im in find_oidn_images(base):
                for spp, hdr in im.levels.items():
                    if im.reference is not None and (not levels or spp in levels):
                        entries.append(Entry(im.id, hdr, None, im.reference, spp))
    if not entries:
        wanted = f" at spp {list(levels)}" if levels else ""
        raise InputError(f"{base}: no input EXR with a ref/<name>.exr reference{wanted}")
    return sorted(entries, key=lambda e: (str(e.path), e.spp or 0))


def split_images(
    entries: Sequence[Entry], val_fraction: float, seed: int, max_images: int = 0
) -> tuple[list[Entry], list[Entry]]:
    """(train, validation) entries, split by image id with a seeded permutation.

    With at least two images and ``val_fraction > 0`` the validation side gets at least one.
    ``max_images`` (> 0) keeps only that many images (the first of the permutation).
    """
    images = sorted({e.image for e in entries})
    g = torch.Generator().manual_seed(seed)
    order = [images[i] for i in torch.randperm(len(images), generator=g).tolist()]
    if max_images > 0:
        order = order[:max_images]
    n_val = round(len(order) * val_fraction)
    if val_fraction > 0 and len(order) >= 2:
        n_val = min(max(1, n_val), len(order) - 1)
    val = set(order[:n_val])
    train = set(order[n_val:])
    return [e for e in entries if e.image in train], [e for e in entries if e.image in val]


@dataclass
class Item:
    """A prepared level: the model's tensors ``(C, H, W)`` (with :data:`REFERENCE`)."""

    entry: Entry
    tensors: dict[str, Tensor]

    @property
    def size(self) -> tuple[int, int]:
        h, w = self.tensors[REFERENCE].shape[-2:]
        return int(h), int(w)


@dataclass
class LoadReport:
    """What :func:`load_items` used and what it skipped (file and reason per skipped level)."""

    used: int = 0
    skipped: list[tuple[str, str]] = field(default_factory=list)

    def summary(self) -> str:
        lines = [f"{self.used} level(s) used, {len(self.skipped)} skipped"]
        lines += [f"  skipped {name}: {why}" for name, why in self.skipped]
        return "\n".join(lines)


def check_reference(ref: Tensor) -> str | None:
    """Why a reference colour ``(3, H, W)`` cannot be trained on, or ``None``."""
    bad = int((~torch.isfinite(ref)).sum())
    if bad:
        return f"reference has {bad} NaN/Inf values"
    if float(ref.max() - ref.min()) == 0.0:
        return "reference is constant"
    return None


def load_items(
    entries: Sequence[Entry],
    prepare: Prepare,
    *,
    min_size: int = 1,
    progress: Mode = False,
) -> tuple[list[Item], LoadReport]:
    """Read and prepare every entry; unusable ones are reported, not raised.

    Args:
        entries: from :func:`scan_dataset`.
        prepare: model hook ``(buffers, reference (3, H, W)) -> {name: (C, H, W)}``; it may raise
            :class:`~mcdenoise.errors.McdenoiseError` (e.g. a missing buffer) to skip a level.
            A hook with the attribute ``reference_buffers = True`` gets the reference's
            :class:`~mcdenoise.io.buffers.FeatureBuffers` (its features too) instead.
        min_size: smallest acceptable image edge (patch + margins).
        progress: report the loading on stderr (:func:`mcdenoise.progress.progress_bar`:
            a bar on a terminal, a line per stage in a log).
    """
    report = LoadReport()
    items: list[Item] = []
    refs: dict[Path, FeatureBuffers] = {}
    whole_reference = bool(getattr(prepare, "reference_buffers", False))
    keys: tuple[str, ...] | None = None
    bar = progress_bar(entries, desc="loading", unit="level", progress=progress, leave=False)
    for e in bar:
        try:
            if e.reference not in refs:
                refs = {e.reference: _read(e.reference, None)}
            ref_buffers = refs[e.reference]
            ref = ref_buffers["color"]
            why = check_reference(ref)
            if why is None:
                buffers = _read(e.path, e.part)
                if tuple(buffers["color"].shape) != tuple(ref.shape):
                    why = f"size {tuple(buffers['color'].shape[1:])} != reference {tuple(ref.shape[1:])}"
                elif min(ref.shape[1:]) < min_size:
                    why = f"smaller than a training crop ({min_size} px)"
            if why is not None:
                report.skipped.append((e.name, why))
                continue
            tensors = prepare(buffers, ref_buffers if whole_reference else ref)
        except McdenoiseError as err:
            report.skipped.append((e.name, str(err)))
            continue
        bad = [k for k, v in tensors.items() if not bool(torch.isfinite(v).all())]
        if bad:
            report.skipped.append((e.name, f"non-finite values after preparation in {bad}"))
            continue
        if keys is None:
            keys = tuple(sorted(tensors))
        elif tuple(sorted(tensors)) != keys:
            report.skipped.append((e.name, f"buffers {sorted(tensors)} differ from {list(keys)}"))
            continue
        items.append(Item(e, {k: v.float().contiguous() for k, v in tensors.items()}))
    report.used = len(items)
    return items, report


def load_split(
    cfg: Any, prepare: Prepare, *, crop: int, progress: Mode = False
) -> tuple[list[Item], list[Item], LoadReport]:
    """Scan ``cfg.data``, split by image (``cfg.val_fraction``, ``cfg.seed``, ``cfg.max_images``)
    and prepare both parts: ``(train items, validation items, report of both)``. Training images
    must hold a ``crop``-px crop.

    Raises:
        InputError: no usable training image (the report is in the message).
    """
    entries = scan_dataset(cfg.data, cfg.levels)
    train_e, val_e = split_images(entries, cfg.val_fraction, cfg.seed, cfg.max_images)
    train_items, report = load_items(train_e, prepare, min_size=crop, progress=progress)
    val_items, val_report = load_items(val_e, prepare, min_size=1, progress=progress)
    report.skipped += val_report.skipped
    if not train_items:
        raise InputError(f"{cfg.data}: no usable training image\n{report.summary()}")
    return train_items, val_items, report


def training_hardware(device: str) -> dict[str, Any]:
    """The machine a model is trained on, for its card: the device, the CPU model and cores,
    torch's intra-op threads and version, the GPU's name on CUDA."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            names = [ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")]
        cpu = names[0] if names else cpu
    except OSError:
        pass
    out: dict[str, Any] = {
        "device": device,
        "cpu": cpu,
        "cpu_cores": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
    }
    if device.startswith("cuda") and torch.cuda.is_available():
        out["gpu"] = torch.cuda.get_device_name(torch.device(device))
    return out


def describe_training(
    cfg: Any, train_items: Sequence[Item], val_items: Sequence[Item]
) -> dict[str, Any]:
    """What a model card records about its training data, config and hardware (JSON-able)."""
    return {
        "hardware": training_hardware(str(getattr(cfg, "device", "cpu"))),
        "data": str(cfg.data),
        "train_images": sorted({it.entry.image for it in train_items}),
        "val_images": sorted({it.entry.image for it in val_items}),
        "levels": sorted({it.entry.spp for it in train_items if it.entry.spp}),
        "config": cfg.to_dict(),
    }


def error_map(noisy: Tensor, reference: Tensor) -> Tensor:
    """Per-pixel relMSE ``(H, W)`` of a noisy colour ``(3, H, W)`` against the reference."""
    x = torch.nan_to_num(noisy, nan=0.0, posinf=0.0, neginf=0.0)
    return relmse_map(x, reference).mean(0)


class PatchSampler:
    """Seeded batches of crops from prepared items, with loss masks.

    Args:
        items: prepared levels (same tensor names, any sizes >= ``patch + 2 margin``).
        patch: edge of the crop's centre (the loss region away from image borders).
        margin: context on each side (>= the model's filter radius).
        importance: share of crops drawn ∝ the noisy error of the patch (key ``noisy_key``).
        noisy_key: tensor holding the noisy colour used for the importance map.
        transform: optional ``(batch, generator) -> batch`` applied to every batch (e.g. the
            augmentation of :func:`augment`); it must draw its randomness from the generator,
            so a resumed run repeats it exactly.
    """

    def __init__(
        self,
        items: Sequence[Item],
        *,
        patch: int,
        margin: int,
        importance: float = 0.5,
        noisy_key: str = "color",
        transform: Callable[[dict[str, Tensor], torch.Generator], dict[str, Tensor]] | None = None,
    ) -> None:
        self.transform = transform
        if not items:
            raise InputError("no usable training images (see the loading report)")
        self.items = list(items)
        self.patch, self.margin = patch, margin
        self.crop = patch + 2 * margin
        self.importance = importance
        small = [it.entry.name for it in self.items if min(it.size) < self.crop]
        if small:
            raise InputError(f"images smaller than the {self.crop}-px crop: {', '.join(small[:3])}")
        # Importance: mean error of every crop position (a box filter of the error map).
        self._cdf_image: Tensor
        weights, self._cdf_pos = [], []
        for it in self.items:
            err = error_map(it.tensors[noisy_key], it.tensors[REFERENCE])[None, None]
            pooled = F.avg_pool2d(err, self.crop, stride=1)[0, 0]  # (H-c+1, W-c+1)
            pooled = torch.nan_to_num(pooled, nan=0.0).clamp_min(0).double()
            total = float(pooled.sum())
            weights.append(total / pooled.numel())
            self._cdf_pos.append(pooled.flatten().cumsum(0) / max(total, 1e-300))
        w = torch.tensor(weights, dtype=torch.float64)
        self._cdf_image = (w / w.sum()).cumsum(0) if float(w.sum()) > 0 else None  # type: ignore[assignment]

    def _position(self, i: int, g: torch.Generator, weighted: bool) -> tuple[int, int]:
        h, w = self.items[i].size
        span_x = w - self.crop + 1
        if weighted:
            u = torch.rand((), generator=g, dtype=torch.float64)
            k = int(torch.searchsorted(self._cdf_pos[i], u).clamp_max(self._cdf_pos[i].numel() - 1))
            return divmod(k, span_x)
        y = int(torch.randint(h - self.crop + 1, (), generator=g))
        x = int(torch.randint(span_x, (), generator=g))
        return y, x

    def mask(self, y: int, x: int, size: tuple[int, int]) -> Tensor:
        """Loss mask ``(1, crop, crop)`` of the crop at ``(y, x)`` in an image of ``size``."""
        h, w = size
        c, m = self.crop, self.margin
        rows = torch.zeros(c, dtype=torch.bool)
        cols = torch.zeros(c, dtype=torch.bool)
        rows[0 if y == 0 else m : c if y + c == h else c - m] = True
        cols[0 if x == 0 else m : c if x + c == w else c - m] = True
        return (rows[:, None] & cols[None, :]).float()[None]

    def batch(self, size: int, g: torch.Generator) -> dict[str, Tensor]:
        """``size`` crops: every tensor ``(B, C, crop, crop)``, plus ``mask`` ``(B, 1, ...)``."""
        out: dict[str, list[Tensor]] = {}
        for _ in range(size):
            weighted = self._cdf_image is not None and bool(
                torch.rand((), generator=g) < self.importance
            )
            if weighted:
                u = torch.rand((), generator=g, dtype=torch.float64)
                i = int(torch.searchsorted(self._cdf_image, u).clamp_max(len(self.items) - 1))
            else:
                i = int(torch.randint(len(self.items), (), generator=g))
            y, x = self._position(i, g, weighted)
            it = self.items[i]
            for k, v in it.tensors.items():
                out.setdefault(k, []).append(v[:, y : y + self.crop, x : x + self.crop])
            out.setdefault("mask", []).append(self.mask(y, x, it.size))
        batch = {k: torch.stack(v) for k, v in out.items()}
        return self.transform(batch, g) if self.transform is not None else batch


def augment(
    batch: dict[str, Tensor],
    g: torch.Generator,
    color_keys: Sequence[str] = (),
    *,
    vector_keys: Sequence[str] = (),
) -> dict[str, Tensor]:
    """Random flips, 90° rotations and (for ``color_keys``) RGB permutations, per crop.

    Every tensor ``(B, C, H, W)`` of the batch (square crops) gets the same geometric transform
    per crop; the tensors named in ``color_keys`` (3 channels: colour, albedo, reference) get
    the same channel permutation. The tensors named in ``vector_keys`` are 2-D pixel
    displacements ``(x right, y down)`` (motion vectors): their components turn with the
    image (a flip negates one, a rotation swaps them), so a warp along them commutes with the
    transform. Randomness comes from ``g`` only.
    """
    n = next(iter(batch.values())).shape[0]
    flips = torch.randint(2, (n, 2), generator=g)
    rots = torch.randint(4, (n,), generator=g)
    perms = torch.stack([torch.randperm(3, generator=g) for _ in range(n)])
    out = {}
    for key, v in batch.items():
        if v.ndim != 4:
            out[key] = v
            continue
        items = []
        for i in range(n):
            x = v[i]
            vec = key in vector_keys
            if flips[i, 0]:
                x = x.flip(-1)
                x = torch.stack([-x[0], x[1]]) if vec else x
            if flips[i, 1]:
                x = x.flip(-2)
                x = torch.stack([x[0], -x[1]]) if vec else x
            for _ in range(int(rots[i])):  # each quarter turn: (x, y) -> (y, -x)
                x = torch.rot90(x, 1, dims=(-2, -1))
                x = torch.stack([x[1], -x[0]]) if vec else x
            if key in color_keys and x.shape[0] == 3:
                x = x[perms[i]]
            items.append(x)
        out[key] = torch.stack(items).contiguous()
    return out


def image_relmse(output: Tensor, reference: Tensor) -> float:
    """relMSE (:func:`mcdenoise.losses.relmse`, in float64) of one image ``(3, H, W)`` (or a
    batch) as a Python float: the validation error of the trainers."""
    return float(relmse(output.double(), reference.double()))
