"""Training the temporal kpcn (``kpcn-temporal``, Vogels et al. 2018, section 5).

Data: one or more folders (``data = "DIR1,DIR2"``) of sequences made by
``mcdenoise render --frames N`` (``DIR/<id>/frame_XXXX.exr`` with its levels and motion,
``DIR/<id>/ref/frame_XXXX.exr``). The split is by sequence (``val_fraction``, ``seed``).
Every frame is prepared once for the ``full`` source
(:func:`~mcdenoise.prep.kpcn_temporal.prepare_frame`, the method's default prefilter),
scaled by its sequence's exposure factor (from frame 0, as the method does), and every
frame's window (``window``, ``temporal_mode``) is warped to it once
(:func:`~mcdenoise.prep.kpcn_temporal.warp_window`; frames outside the sequence: zeros
under a zero mask).

A training crop is a pair of consecutive frames ``(t − 1, t)`` at the same pixels (a
recurrent model: three, ``(t − 2, t − 1, t)``, unrolled: each output after the first gets the
previous one warped to its frame as input): the windows are cropped there and denoised, and
the loss (on the crop centre) is

    SMAPE(o_t, r_t) + temporal_weight · SMAPE(o_t − W(o_{t−1}), r_t − W(r_{t−1}))

(:func:`mcdenoise.losses.temporal_smape`; Isik et al. 2021 and Balint et al. 2023 use this
temporal term). With ``temporal_loss = "warped"`` (the default) ``W`` warps frame ``t − 1``
to frame ``t`` along the motion with the method's disocclusion test, and pixels where that
warp is invalid do not count: camera motion is not flicker. ``same-pixel`` (the first shipped
model's) takes ``W`` as the identity, the temporal relMSE this project reports
(``mcdenoise.eval.temporal_metrics``). A recurrent model's terms are averaged over its last two
outputs. The reference's warp ``W(r_{t−1})`` is made once per frame on the whole image; the
output's on the crop, masked by that warp's validity (out-of-crop reads are invalid).
Augmentation (``trunk = "train"`` only): flips, 90° rotations (the motion vectors turned with
the pixels) and RGB permutations. With the frozen trunk's features cached there is none: a
flipped crop would need the trunk run again on it (:class:`PairSampler`).

Training follows the paper: the model starts from a trained single-frame kpcn (``base`` =
``--from``: a kpcn run folder or model file, e.g. the shipped
``mcdenoise/models/weights/kpcn.pt``) with the temporal module at its zero start
(:func:`~mcdenoise.models.kpcn_temporal.from_single_frame`), and ``trunk = "frozen"`` (default)
trains only the temporal module (the trunk runs without autograd: much cheaper steps).
A second run from that ``kpcn-temporal`` run with ``trunk = "train"`` fine-tunes everything.

Validation runs every validation sequence through the model as the method does (all
frames, tiles, the window clipped at the ends) and reports the geometric means of the
per-frame relMSE and of the temporal relMSE, with the single-frame base's for scale;
``val_loss`` is the geometric mean of the two (lower is better).
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from mcdenoise.errors import InputError, McdenoiseError
from mcdenoise.filters.warp import warp
from mcdenoise.geomean import geometric_mean
from mcdenoise.io import load_buffers
from mcdenoise.losses import compute_loss, temporal_smape
from mcdenoise.modelfile import read_card
from mcdenoise.models.kpcn import KpcnModel
from mcdenoise.models.kpcn_temporal import FORMAT as TEMPORAL_FORMAT
from mcdenoise.models.kpcn_temporal import TemporalKpcn, from_single_frame, window_offsets
from mcdenoise.prep.kpcn import exposure_scale
from mcdenoise.prep.kpcn_temporal import PreparedFrame, prepare_frame, warp_image, warp_window
from mcdenoise.train.config import TrainConfig
from mcdenoise.train.loop import TrainResult, run_training
from mcdenoise.train.patches import LoadReport, augment, training_hardware

#: The input source the temporal module is trained on (every frame of a render has it).
SOURCE = "full"
#: The noisy level trained on when ``levels`` is empty (the issue's 4 spp).
DEFAULT_LEVEL = 4


@dataclass
class Sequence_:
    """One prepared sequence: per frame its window (warped tensors and masks) and reference."""

    name: str
    windows: list[tuple[list[dict[str, Tensor]], list[Tensor]]] = field(default_factory=list)
    #: per frame, per window frame, per scale: the frozen trunk's features (or empty)
    features: list[list[list[Tensor]]] = field(default_factory=list)
    refs: list[Tensor] = field(default_factory=list)
    frames: list[PreparedFrame] = field(default_factory=list)
    #: per frame: its motion to the previous frame ``(1, 2, H, W)`` (0 without), the previous
    #: reference warped to it and where that warp is valid (0 for the first frame)
    motion: list[Tensor] = field(default_factory=list)
    warped_refs: list[Tensor] = field(default_factory=list)
    warp_masks: list[Tensor] = field(default_factory=list)
    scale: float = 1.0

    @property
    def size(self) -> tuple[int, int]:
        h, w = self.refs[0].shape[-2:]
        return int(h), int(w)


def find_sequences(data: str) -> list[Path]:
    """Sequence folders (holding ``frame_*.exr`` and ``ref/``) of the comma-separated
    ``data`` folders, sorted by name within each folder."""
    out: list[Path] = []
    for part in [p.strip() for p in data.split(",") if p.strip()]:
        root = Path(part)
        if not root.is_dir():
            raise InputError(f"{root}: no such data folder")
        found = sorted(
            d
            for d in root.iterdir()
            if d.is_dir() and any(d.glob("frame_*.exr")) and (d / "ref").is_dir()
        )
        if not found:
            raise InputError(f"{root}: holds no sequence (<id>/frame_*.exr with <id>/ref/)")
        out += found
    return out


def load_sequence(
    folder: Path, level: int, offsets: Sequence[int], *, windows: bool = True
) -> Sequence_:
    """Read and prepare one sequence (see the module docstring)."""
    files = sorted(folder.glob("frame_*.exr"))
    seq = Sequence_(folder.name)
    for i, f in enumerate(files):
        b = load_buffers(f, part=f"spp{level}")
        frame = prepare_frame(b, SOURCE)
        ref = load_buffers(folder / "ref" / f.name).get("color")
        if ref is None:
            raise InputError(f"{folder / 'ref' / f.name}: no colour")
        if i == 0:
            seq.scale = exposure_scale(frame.tensors["color"])
        k = seq.scale
        if k != 1.0:
            frame.tensors["color"] = frame.tensors["color"] * k
            frame.tensors["color_var"] = frame.tensors["color_var"] * (k * k)
        seq.frames.append(frame)
        seq.refs.append(torch.nan_to_num(ref.float(), nan=0.0, posinf=0.0).clamp_min(0)[None] * k)
    motion_targets(seq)
    if windows:
        for t in range(len(seq.frames)):
            tens, masks, _ = warp_window(seq.frames, t, offsets, fill=True)
            seq.windows.append((tens, masks))
    return seq


def motion_targets(seq: Sequence_) -> None:
    """Fill ``seq``'s per-frame motion, previous reference warped to the frame and that warp's
    mask from its ``frames`` and ``refs`` (the warped temporal loss's targets)."""
    seq.motion, seq.warped_refs, seq.warp_masks = [], [], []
    for t, frame in enumerate(seq.frames):
        ref = seq.refs[t]
        motion = frame.motion if frame.motion is not None else torch.zeros_like(ref[:, :2])
        if t == 0:
            wref, wmask = torch.zeros_like(ref), torch.zeros_like(ref[:, :1])
        else:
            wref, wmask = warp_image(seq.frames, seq.refs[t - 1], t - 1, t)
        seq.motion.append(motion)
        seq.warped_refs.append(wref)
        seq.warp_masks.append(wmask)


@torch.no_grad()
def cache_features(model: TemporalKpcn, seqs: Sequence[Sequence_]) -> None:
    """The frozen trunk's features of every window frame, computed once (a frozen trunk
    gives the same features every step; this removes the trunk from the training steps)."""
    scales = model.base.card.scales
    model.eval()
    for s in seqs:
        for tens, _ in s.windows:
            stacked = {k: torch.cat([f[k] for f in tens], 0) for k in tens[0]}
            feats = model.base.features(stacked, SOURCE)[:scales]
            s.features.append([[f[i].contiguous() for f in feats] for i in range(len(tens))])
    model.train()


#: Batch key prefixes of frames ``t``, ``t − 1``, ``t − 2`` of a training crop.
PREFIXES = ("", "p:", "pp:")


class PairSampler:
    """Seeded batches of crops of consecutive frames (``(t − 1, t)``, or with ``frames=3``
    ``(t − 2, t − 1, t)``; see the module docstring); the duck type of
    :class:`~mcdenoise.train.patches.PatchSampler` that :func:`mcdenoise.train.loop.train`
    uses (``batch(size, generator)``)."""

    def __init__(
        self, seqs: Sequence[Sequence_], *, patch: int, margin: int, aug: bool, frames: int = 2
    ) -> None:
        self.frames = frames
        self.pairs = [(i, t) for i, s in enumerate(seqs) for t in range(frames - 1, len(s.windows))]
        if not self.pairs:
            raise InputError(f"no training sequence has {frames} frames")
        self.seqs = list(seqs)
        self.patch, self.margin, self.crop = patch, margin, patch + 2 * margin
        small = [s.name for s in seqs if min(s.size) < self.crop]
        if small:
            raise InputError(
                f"sequences smaller than the {self.crop}-px crop: {', '.join(small[:3])}"
            )
        self.aug = aug
        #: crops start on multiples of the coarsest feature scale (cached features crop exactly)
        self.align = 2 ** (len(seqs[0].features[0][0]) - 1) if seqs[0].features else 1
        if self.crop % self.align:
            raise InputError(f"patch + 2 margin must be a multiple of {self.align}")

    def _window(self, s: Sequence_, t: int, y: int, x: int, prefix: str) -> dict[str, Tensor]:
        c = self.crop
        tens, masks = s.windows[t]
        out = {}
        for i, (fr, m) in enumerate(zip(tens, masks)):
            for k, v in fr.items():
                out[f"{prefix}{k}@{i}"] = v[0, :, y : y + c, x : x + c]
            out[f"{prefix}mask@{i}"] = m[0, :, y : y + c, x : x + c]
            if s.features:
                for sc, f in enumerate(s.features[t][i]):
                    d = 2**sc
                    out[f"{prefix}feat{sc}@{i}"] = f[
                        :, y // d : (y + c) // d, x // d : (x + c) // d
                    ]
        out[f"{prefix}reference"] = s.refs[t][0, :, y : y + c, x : x + c]
        out[f"{prefix}motion"] = s.motion[t][0, :, y : y + c, x : x + c]
        out[f"{prefix}warped_reference"] = s.warped_refs[t][0, :, y : y + c, x : x + c]
        out[f"{prefix}warp_mask"] = s.warp_masks[t][0, :, y : y + c, x : x + c]
        return out

    def batch(self, size: int, g: torch.Generator) -> dict[str, Tensor]:
        items: list[dict[str, Tensor]] = []
        for _ in range(size):
            i, t = self.pairs[int(torch.randint(len(self.pairs), (), generator=g))]
            s = self.seqs[i]
            h, w = s.size
            a = self.align
            y = a * int(torch.randint((h - self.crop) // a + 1, (), generator=g))
            x = a * int(torch.randint((w - self.crop) // a + 1, (), generator=g))
            item: dict[str, Tensor] = {}
            for j, prefix in enumerate(PREFIXES[: self.frames]):
                item.update(self._window(s, t - j, y, x, prefix))
            items.append(item)
        batch = {k: torch.stack([it[k] for it in items]) for k in items[0]}
        m = torch.zeros(1, 1, self.crop, self.crop)
        m[..., self.margin : self.crop - self.margin, self.margin : self.crop - self.margin] = 1
        batch["mask"] = m.expand(size, -1, -1, -1).clone()
        batch["source"] = torch.zeros(size, dtype=torch.long)
        if self.aug and not self.seqs[0].features:
            # Not with cached trunk features: the features of a flipped image are not the
            # flipped features (the convolutions are not symmetric), and the kernels a head
            # predicts from flipped features would be applied mirrored. Training the first
            # shipped model that way made it worse than its untrained start (1.15x the
            # single-frame relMSE on validation sequences, the untrained start 1.01x).
            colour = [
                k
                for k in batch
                if k.split("@")[0].split(":")[-1]
                in ("color", "albedo", "reference", "warped_reference")
            ]
            motion = [k for k in batch if k.split(":")[-1] == "motion"]
            batch = augment(batch, g, colour, vector_keys=motion)
        return batch


def _split(batch: dict[str, Tensor], prefix: str) -> dict[str, Tensor]:
    n = len(prefix)
    return {
        k[n:]: v
        for k, v in batch.items()
        if (k.startswith(prefix) if prefix else ":" not in k) and k not in ("mask", "source")
    } | {"source": batch["source"]}


class TemporalTask:
    """The :class:`~mcdenoise.train.loop.Task` of the temporal kpcn."""

    find_unused_parameters = False

    def __init__(self, model: TemporalKpcn, cfg: TrainConfig, val: Sequence[Sequence_]) -> None:
        self.module = model
        self.forward_module = model
        self.device = torch.device("cpu")
        self.cfg = cfg
        self.val = list(val)
        self._base_scores: tuple[float, float] | None = None
        self._last = torch.zeros(0)

    @property
    def frames(self) -> int:
        """Frames per training crop: 3 for a recurrent model (unrolled), else 2."""
        return 3 if self.module.recurrence is not None else 2

    def loss(self, batch: dict[str, Tensor]) -> Tensor:
        parts = [_split(batch, p) for p in PREFIXES[: self.frames]][::-1]  # oldest first
        recurrent = self.module.recurrence is not None
        outs: list[Tensor] = []
        for part in parts:
            if recurrent and outs:  # the previous output, warped to this frame
                prev, prev_mask = warp(outs[-1], part["motion"], valid=part["warp_mask"])
                part = part | {"previous": prev, "previous_mask": prev_mask}
            outs.append(self.forward_module(part))
        mask = batch["mask"]
        scored = range(1, len(parts)) if recurrent else range(len(parts) - 1, len(parts))
        total = torch.zeros((), dtype=outs[-1].dtype, device=outs[-1].device)
        for j in scored:
            cur, out = parts[j], outs[j]
            total = total + compute_loss(
                self.cfg.loss,
                out,
                cur["reference"],
                mask,
                noisy=cur["color@" + str(self.module.centre)],
            )
            if self.cfg.temporal_weight > 0:
                total = total + self.cfg.temporal_weight * self._temporal(
                    out, outs[j - 1], cur, parts[j - 1], mask
                )
        return total / len(scored)

    def _temporal(
        self,
        out: Tensor,
        out_prev: Tensor,
        cur: dict[str, Tensor],
        prev: dict[str, Tensor],
        mask: Tensor,
    ) -> Tensor:
        if self.cfg.temporal_loss == "same-pixel":
            return temporal_smape(out, out_prev, cur["reference"], prev["reference"], mask)
        warped, valid = warp(out_prev, cur["motion"], valid=cur["warp_mask"])
        return temporal_smape(out, warped, cur["reference"], cur["warped_reference"], mask * valid)

    def _scores(self, model_run) -> tuple[float, float]:
        rel, trel = [], []
        for s in self.val:
            outs = [model_run(s, t) for t in range(len(s.windows))]
            refs = s.refs
            fr = [float(((o - r) ** 2 / (r**2 + 0.01)).mean()) for o, r in zip(outs, refs)]
            rel.append(sum(fr) / len(fr))
            d = [
                float(
                    (
                        ((outs[t] - outs[t - 1]) - (refs[t] - refs[t - 1])) ** 2
                        / (refs[t] ** 2 + 0.01)
                    ).mean()
                )
                for t in range(1, len(outs))
            ]
            trel.append(sum(d) / max(1, len(d)))
        return geometric_mean(rel), geometric_mean(trel)

    def _run(self, s: Sequence_, t: int) -> Tensor:
        """Frame ``t`` as the method denoises it (frames in order: a recurrent model reads
        its output of frame ``t − 1``, kept in ``self._last``)."""
        model = self.module
        offsets = model.card.offsets
        tens, masks = s.windows[t]
        keep = [i for i, o in enumerate(offsets) if 0 <= t + o < len(s.windows)]
        fr = [{k: v.to(self.device) for k, v in tens[i].items()} for i in keep]
        mk = [masks[i].to(self.device) for i in keep]
        prev = prev_mask = None
        if model.recurrence is not None and t > 0:
            prev, prev_mask = warp_image(s.frames, self._last, t - 1, t)
            prev, prev_mask = prev.to(self.device), prev_mask.to(self.device)
        out = model.denoise_window(
            fr,
            mk,
            keep.index(offsets.index(0)),
            SOURCE,
            previous=prev,
            previous_mask=prev_mask,
        ).cpu()
        self._last = out
        return out

    def _run_base(self, s: Sequence_, t: int) -> Tensor:
        tens, _ = s.windows[t]
        c = self.module.card.offsets.index(0)
        fr = {k: v.to(self.device) for k, v in tens[c].items()}
        return self.module.base.denoise_tensors(fr, SOURCE).cpu()

    def validate(self) -> dict[str, float]:
        if not self.val:
            return {"val_loss": math.nan}
        if self._base_scores is None:
            self._base_scores = self._scores(self._run_base)
        rel, trel = self._scores(self._run)
        brel, btrel = self._base_scores
        return {
            "val_loss": math.sqrt(rel * trel),
            "val_relmse": rel,
            "val_trelmse": trel,
            "val_relmse_ratio_to_base": rel / brel,
            "val_trelmse_ratio_to_base": trel / btrel,
        }

    def export(self, path: Path) -> None:
        self.module.save(path)


def _base_model(cfg: TrainConfig) -> TemporalKpcn:
    if not cfg.base:
        raise InputError(
            "kpcn-temporal starts from a trained model: pass --from RUN (a kpcn run folder or "
            "model file, e.g. mcdenoise/models/weights/kpcn.pt, or a kpcn-temporal run)"
        )
    card = read_card(cfg.base)
    if card.get("format") == TEMPORAL_FORMAT:
        model = TemporalKpcn.load(cfg.base)
        got = (model.card.window, model.card.mode, model.card.inputs, model.card.recurrent)
        want = (cfg.window, cfg.temporal_mode, cfg.temporal_inputs, cfg.recurrent)
        if got != want:
            raise InputError(
                f"{cfg.base}: a {got[0]}-frame {got[1]} model (inputs {got[2]}, recurrent "
                f"{got[3]}); this config asks for window {want[0]} ({want[1]}, inputs "
                f"{want[2]}, recurrent {want[3]})"
            )
        return model
    return from_single_frame(
        KpcnModel.load(cfg.base),
        window=cfg.window,
        mode=cfg.temporal_mode,
        inputs=cfg.temporal_inputs,
        recurrent=cfg.recurrent,
    )


def build(
    cfg: TrainConfig, *, progress: Any = False
) -> tuple[TemporalTask, PairSampler, LoadReport]:
    offsets = window_offsets(cfg.window, cfg.temporal_mode)
    if cfg.trunk not in ("frozen", "train"):
        raise InputError(f"trunk must be frozen or train, got {cfg.trunk!r}")
    model = _base_model(cfg)
    if SOURCE not in model.base.card.sources:
        raise InputError(f"{cfg.base}: the base model has no '{SOURCE}' source")
    folders = find_sequences(cfg.data)
    rng = random.Random(cfg.seed)
    order = list(folders)
    rng.shuffle(order)
    if cfg.max_images:
        order = order[: cfg.max_images]
    n_val = round(len(order) * cfg.val_fraction) if len(order) > 1 else 0
    val_set = {str(p) for p in order[:n_val]}
    level = cfg.levels[0] if cfg.levels else DEFAULT_LEVEL
    train, val, report = [], [], LoadReport()
    for p in sorted(order):
        try:
            s = load_sequence(p, level, offsets)
        except McdenoiseError as err:  # e.g. an AO render without albedo
            report.skipped.append((str(p), str(err)))
            continue
        (val if str(p) in val_set else train).append(s)
        report.used += len(s.windows)
    frozen = cfg.trunk == "frozen"
    for q in model.base.parameters():
        q.requires_grad_(not frozen)
    if frozen:
        cache_features(model, train)
    model.training_trunk = not frozen
    model.card.training = {
        "data": cfg.data,
        "level": level,
        "train_sequences": sorted(s.name for s in train),
        "val_sequences": sorted(s.name for s in val),
        "trunk": cfg.trunk,
        "loss": f"{cfg.loss} + {cfg.temporal_weight} * temporal smape ({cfg.temporal_loss})",
        "steps": cfg.steps,
        "base": str(cfg.base),
        "hardware": training_hardware(cfg.device),
        "config": cfg.to_dict(),
    }
    task = TemporalTask(model, cfg, val)
    sampler = PairSampler(
        train, patch=cfg.patch, margin=cfg.margin, aug=cfg.augment, frames=task.frames
    )
    return task, sampler, report


def train_kpcn_temporal(
    cfg: TrainConfig, out: str | Path, *, resume: bool = False, progress: Any = True
) -> tuple[TrainResult, LoadReport]:
    """Train a temporal kpcn into the run folder ``out`` (see the module docstring)."""
    return run_training(cfg, build, out, resume=resume, progress=progress)


__all__ = [
    "PREFIXES",
    "PairSampler",
    "TemporalTask",
    "build",
    "find_sequences",
    "load_sequence",
    "motion_targets",
    "train_kpcn_temporal",
]
