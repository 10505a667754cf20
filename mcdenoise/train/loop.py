"""The training loop shared by every trainable model: Adam, schedule, validation, resume.

A model plugs in as a :class:`Task` (its module, a loss on a batch, a validation pass, an
export of the model file). :func:`train` then owns everything else:

* AdamW with a linear warm-up and a cosine decay (``lr`` -> ``lr * lr_final``);
* steps whose loss or gradient is not finite are skipped and counted (never applied);
  gradients are clipped to norm 1;
* every ``epoch_steps`` steps: validation, one line in ``metrics.jsonl``, a checkpoint with
  the model, optimiser, scheduler, sampler and torch RNG states and the step, and -- when the
  validation loss is the best so far -- the exported model ``model.pt``;
* ``resume=True`` continues from the checkpoint ``latest`` names, exactly: with
  ``deterministic`` on CPU, N steps straight and N/2 + kill + resume give identical weights
  (when N/2 is a validation boundary: checkpoints are written there).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import torch
from torch import Tensor, nn
from tqdm import tqdm

from mcdenoise.errors import InputError
from mcdenoise.train.checkpoint import CheckpointError, RunFolder
from mcdenoise.train.config import TrainConfig
from mcdenoise.train.dataset import PatchSampler

#: Config keys that may differ when resuming (they do not change the result).
RESUME_FREE = ("device", "threads", "data")


class Task(Protocol):
    """What a model provides to :func:`train`."""

    module: nn.Module

    def loss(self, batch: dict[str, Tensor]) -> Tensor:
        """Scalar training loss of a batch from :meth:`PatchSampler.batch`."""
        ...

    def validate(self) -> dict[str, float]:
        """Validation metrics; ``val_loss`` selects the exported model (lower is better)."""
        ...

    def export(self, path: Path) -> None:
        """Write the model file (weights + model card) to ``path`` atomically."""
        ...


@dataclass
class TrainResult:
    """Summary of a finished :func:`train`."""

    steps: int
    best_val_loss: float
    skipped_steps: int
    seconds: float
    metrics: list[dict[str, Any]]


def lr_factor(step: int, cfg: TrainConfig) -> float:
    """Multiplier of ``cfg.lr`` at ``step``: linear warm-up, then cosine to ``lr_final``."""
    if step < cfg.warmup:
        return (step + 1) / cfg.warmup
    span = max(1, cfg.steps - cfg.warmup)
    t = min(1.0, (step - cfg.warmup) / span)
    return cfg.lr_final + (1 - cfg.lr_final) * 0.5 * (1 + math.cos(math.pi * t))


def setup_torch(cfg: TrainConfig) -> None:
    """Threads and determinism as the config says (global torch settings)."""
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    torch.use_deterministic_algorithms(cfg.deterministic, warn_only=True)


def _check_resume_config(run: RunFolder, cfg: TrainConfig) -> None:
    old = run.read_config()
    new = cfg.to_dict()
    # a key missing from an older run's config did not exist then: its default applied
    diff = sorted(k for k in new if k not in RESUME_FREE and old.get(k, new[k]) != new[k])
    if diff:
        parts = ", ".join(f"{k}: {old.get(k)!r} -> {new[k]!r}" for k in diff)
        raise InputError(f"{run.path}: cannot resume with a different config ({parts})")


def train(
    cfg: TrainConfig,
    task: Task,
    sampler: PatchSampler,
    run: RunFolder,
    *,
    resume: bool = False,
    progress: bool = True,
) -> TrainResult:
    """Train ``task`` on batches from ``sampler``; write the run folder ``run``.

    Raises:
        InputError: the run folder already holds a run and ``resume`` is False, or the config
            differs from the one being resumed.
        CheckpointError: the checkpoint to resume from is truncated/corrupt.
    """
    module = task.module
    params = [p for p in module.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: lr_factor(s, cfg))
    gen = torch.Generator().manual_seed(cfg.seed + 1)
    start, best, skipped = 0, math.inf, 0

    state = run.load_latest() if run.exists() else None
    if run.exists() and not resume:
        raise InputError(f"{run.path}: already holds a run; pass --resume or choose another --out")
    if resume and state is not None:
        _check_resume_config(run, cfg)
        module.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        gen.set_state(state["sampler_rng"])
        torch.set_rng_state(state["torch_rng"])
        start, best, skipped = int(state["step"]), float(state["best"]), int(state["skipped"])
        run.truncate_metrics(start)
    else:
        run.write_config(cfg.to_json())
    if start >= cfg.steps:
        return TrainResult(start, best, skipped, 0.0, run.read_metrics())

    t0 = time.perf_counter()
    epoch_loss: list[float] = []
    bar = tqdm(
        total=cfg.steps, initial=start, desc=f"train {cfg.model}", unit="step", disable=not progress
    )
    try:
        for step in range(start, cfg.steps):
            module.train()
            batch = sampler.batch(cfg.batch, gen)
            loss = task.loss(batch)
            opt.zero_grad(set_to_none=True)
            ok = bool(torch.isfinite(loss))
            if ok:
                loss.backward()
                norm = torch.nn.utils.clip_grad_norm_(params, 1.0)
                ok = bool(torch.isfinite(norm))
            if ok:
                opt.step()
                epoch_loss.append(float(loss.detach()))
            else:
                skipped += 1
            sched.step()
            bar.update(1)
            if ok:
                bar.set_postfix(loss=f"{float(loss.detach()):.4g}", refresh=False)
            done = step + 1
            if done % cfg.epoch_steps == 0 or done == cfg.steps:
                module.eval()
                with torch.no_grad():
                    val = task.validate()
                record = {
                    "step": done,
                    "epoch": math.ceil(done / cfg.epoch_steps),
                    "train_loss": sum(epoch_loss) / len(epoch_loss) if epoch_loss else None,
                    "lr": opt.param_groups[0]["lr"],
                    "skipped_steps": skipped,
                    "seconds": round(time.perf_counter() - t0, 3),
                    **val,
                }
                epoch_loss = []
                vloss = float(val.get("val_loss", math.inf))
                if vloss < best or not run.model_path.is_file():
                    best = min(best, vloss)
                    task.export(run.model_path)
                record["best_val_loss"] = best
                run.append_metrics(record)
                if progress:
                    bar.write(
                        "step {step}: train {tl} val {vl:.5g} (best {b:.5g})".format(
                            step=done,
                            tl="n/a"
                            if record["train_loss"] is None
                            else f"{record['train_loss']:.5g}",
                            vl=vloss,
                            b=best,
                        )
                    )
                run.save_checkpoint(
                    {
                        "model": module.state_dict(),
                        "optimizer": opt.state_dict(),
                        "scheduler": sched.state_dict(),
                        "sampler_rng": gen.get_state(),
                        "torch_rng": torch.get_rng_state(),
                        "step": done,
                        "best": best,
                        "skipped": skipped,
                    },
                    done,
                    keep=cfg.checkpoints_kept,
                )
    finally:
        bar.close()
    return TrainResult(cfg.steps, best, skipped, time.perf_counter() - t0, run.read_metrics())


__all__ = [
    "RESUME_FREE",
    "CheckpointError",
    "Task",
    "TrainResult",
    "lr_factor",
    "setup_torch",
    "train",
]
