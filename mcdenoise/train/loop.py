"""The training loop shared by every trainable model: Adam, schedule, validation, resume.

A model plugs in as a :class:`Task` (its module, a loss on a batch, a validation pass, an
export of the model file). :func:`train` then owns everything else:

* the device (``cfg.device``: ``cpu``, ``cuda``, ``cuda:N``, ``auto``): the module and every
  batch tensor are moved there, and ``task.device`` says where, for the task's validation;
* AdamW with a linear warm-up and a cosine decay (``lr`` -> ``lr * lr_final``);
* steps whose loss or gradient is not finite are skipped and counted (never applied);
  gradients are clipped to norm 1;
* every ``epoch_steps`` steps: validation, one line in ``metrics.jsonl``, a checkpoint with
  the model, optimiser, scheduler, sampler and torch RNG states and the step, and -- when the
  validation loss is the best so far -- the exported model ``model.pt``;
* ``resume=True`` continues from the checkpoint ``latest`` names, exactly: with
  ``deterministic`` on CPU, N steps straight and N/2 + kill + resume give identical weights
  (when N/2 is a validation boundary: checkpoints are written there);
* several processes under ``torchrun`` (:mod:`mcdenoise.train.distributed`): data parallel
  with :class:`~torch.nn.parallel.DistributedDataParallel` (gradients averaged over the
  ranks), see :func:`train`;
* mixed precision on CUDA (``cfg.amp``): ``bf16`` or ``fp16`` autocast around the task's
  loss, fp16 with a gradient scaler. Ignored on the CPU (the run is then exactly the
  ``amp = "off"`` run).
"""

from __future__ import annotations

import contextlib
import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import torch
from torch import Tensor, nn
from torch.nn.parallel import DistributedDataParallel

from mcdenoise.errors import InputError
from mcdenoise.progress import progress_bar, write_line
from mcdenoise.train.checkpoint import CheckpointError, RunFolder
from mcdenoise.train.config import TrainConfig
from mcdenoise.train.distributed import (
    DistContext,
    all_gather_object,
    all_reduce_sum,
    barrier,
    broadcast_object,
    cleanup,
    init_from_env,
    read_env,
    resolve_device,
)
from mcdenoise.train.patches import LoadReport, PatchSampler

#: Config keys that may differ when resuming (they do not change the result).
RESUME_FREE = ("device", "threads", "data")
#: Distance between the seeds of two ranks' random streams.
RANK_SEED_STRIDE = 1_000_003
#: Autocast dtypes of the ``amp`` modes (on CUDA).
AMP_DTYPES = {"bf16": torch.bfloat16, "fp16": torch.float16}


class Task(Protocol):
    """What a model provides to :func:`train`.

    Conventions (every task follows them; :func:`train` sets the last two attributes before
    the first step, so a task only needs them to exist when used outside :func:`train`):

    * ``module``: the bare :class:`~torch.nn.Module` -- its ``state_dict`` is checkpointed,
      :meth:`validate` and :meth:`export` use it. It is moved to ``device`` by :func:`train`.
    * ``forward_module``: what :meth:`loss` calls for the training forward pass, e.g.
      ``self.forward_module(batch)`` (so ``module.forward`` must take the batch). It is
      ``module`` itself in a single process and a
      :class:`~torch.nn.parallel.DistributedDataParallel` wrapper of it under torchrun, which
      averages the gradients over the ranks in ``backward``. :meth:`validate` must **not** use
      it (only rank 0 validates; a DDP forward on one rank would wait for the others).
    * ``device``: the :class:`torch.device` training runs on. Batches reach :meth:`loss`
      already there; :meth:`validate` moves its own tensors there (``t.to(self.device)``).
    * ``find_unused_parameters`` (optional, default False): set True when a training forward
      may leave some trainable parameters without a gradient (e.g. one of several per-source
      encoders unused in a step); DDP then looks for them every step (slower). Without it such
      a step fails under torchrun ("Expected to have finished reduction ...").
    * randomness inside :meth:`loss` (dropout, ...) comes from the global torch CPU RNG,
      which is checkpointed per rank (CUDA generators are not); data randomness (crops,
      augmentation) belongs to the sampler's generator.
    """

    module: nn.Module
    forward_module: nn.Module
    device: torch.device

    def loss(self, batch: dict[str, Tensor]) -> Tensor:
        """Scalar training loss of a batch from :meth:`PatchSampler.batch` (on ``device``).

        Under ``amp`` it runs inside ``torch.autocast``; models keep their sensitive parts
        (softmax, kernel application, the loss) in float32 themselves.
        """
        ...

    def validate(self) -> dict[str, float]:
        """Validation metrics; ``val_loss`` selects the exported model (lower is better).

        Runs on rank 0 only, under ``torch.no_grad()``, with ``module`` in eval mode and
        without autocast.
        """
        ...

    def export(self, path: Path) -> None:
        """Write the model file (weights + model card) to ``path`` atomically."""
        ...


class CardTask:
    """The start of a :class:`Task` whose model is one carded module (auxnet, kalantari,
    nnao): the attributes the conventions ask for, set for a single process on the CPU, the
    training ``description`` and the last validation; :meth:`export` records both in the
    card's ``training`` field and writes the model file. A subclass adds ``loss`` and
    ``validate``."""

    def __init__(self, model: Any, description: dict[str, Any]) -> None:
        self.module = model
        self.forward_module: nn.Module = model
        self.device = torch.device("cpu")
        #: every weight is used in every step: DDP need not search for unused ones
        self.find_unused_parameters = False
        self.model = model
        self.description = description
        self.last_val: dict[str, float] = {}

    def export(self, path: Path) -> None:
        self.model.card.training = {**self.description, "validation": dict(self.last_val)}
        self.model.save(path)


@dataclass
class TrainResult:
    """Summary of a finished :func:`train` (``rank``/``world_size``: of the process)."""

    steps: int
    best_val_loss: float
    skipped_steps: int
    seconds: float
    metrics: list[dict[str, Any]]
    rank: int = 0
    world_size: int = 1


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


def sampler_seed(seed: int, rank: int) -> int:
    """Seed of rank ``rank``'s patch-sampler generator (rank 0: ``seed + 1``, as always)."""
    return seed + 1 + RANK_SEED_STRIDE * rank


def _check_resume_config(run: RunFolder, cfg: TrainConfig) -> None:
    old = run.read_config()
    new = cfg.to_dict()
    # a key missing from an older run's config did not exist then: its default applied
    diff = sorted(k for k in new if k not in RESUME_FREE and old.get(k, new[k]) != new[k])
    if diff:
        parts = ", ".join(f"{k}: {old.get(k)!r} -> {new[k]!r}" for k in diff)
        raise InputError(f"{run.path}: cannot resume with a different config ({parts})")


def _restore_rank_streams(
    state: dict[str, Any], ctx: DistContext, gen: torch.Generator, cfg: TrainConfig
) -> None:
    """Each rank's sampler generator and torch RNG as they were at the checkpoint.

    ``state["ranks"]`` (written by runs of several processes) holds one entry per rank; a
    single-process checkpoint holds only ``sampler_rng``/``torch_rng`` (rank 0's). Resuming
    with another number of processes continues, not bit-exactly: ranks without a saved stream
    start fresh ones seeded from the seed, the rank and the step.
    """
    saved = state.get("ranks") or [
        {"sampler_rng": state["sampler_rng"], "torch_rng": state["torch_rng"]}
    ]
    if len(saved) != ctx.world_size and ctx.is_main:
        warnings.warn(
            f"resuming a run of {len(saved)} process(es) with {ctx.world_size}: training "
            "continues, but not bit-exactly as the original run would have",
            stacklevel=3,
        )
    if ctx.rank < len(saved):
        gen.set_state(saved[ctx.rank]["sampler_rng"])
        torch.set_rng_state(saved[ctx.rank]["torch_rng"])
    else:
        step = int(state["step"])
        gen.manual_seed(sampler_seed(cfg.seed, ctx.rank) + step)
        torch.manual_seed(cfg.seed + RANK_SEED_STRIDE * ctx.rank + step)


def _agree_on_loss(ctx: DistContext, loss: Tensor) -> tuple[bool, float]:
    """(every rank's loss is finite, the mean loss over the ranks) -- one all-reduce."""
    value = loss.detach()
    if not ctx.enabled:
        ok = bool(torch.isfinite(value))
        return ok, float(value) if ok else math.nan
    finite = torch.isfinite(value)
    t = torch.stack(
        [(~finite).to(torch.float64), torch.where(finite, value.double(), 0.0)]
    ).reshape(2)
    all_reduce_sum(ctx, t)
    bad, total = t.tolist()
    return bad == 0, total / ctx.world_size if bad == 0 else math.nan


def train(
    cfg: TrainConfig,
    task: Task,
    sampler: PatchSampler,
    run: RunFolder,
    *,
    resume: bool = False,
    progress: bool = True,
    dist_ctx: DistContext | None = None,
) -> TrainResult:
    """Train ``task`` on batches from ``sampler``; write the run folder ``run``.

    Under torchrun (``WORLD_SIZE > 1``; see :mod:`mcdenoise.train.distributed`) every process
    runs this function on its own copy of the task and data:

    * the process group is joined here (gloo on CPU, nccl on CUDA with ``cuda:LOCAL_RANK``)
      unless ``dist_ctx`` is given (then the caller owns it), and left when training ends;
    * ``task.forward_module`` becomes a DDP wrapper of ``task.module``: gradients are
      averaged over the ranks, so all ranks hold the same weights after every step;
    * each rank draws its own batches of ``cfg.batch`` crops (generator seeded with
      :func:`sampler_seed` of the seed and the rank): the effective batch is
      ``cfg.batch * world_size``, and ``lr`` applies to that mean gradient;
    * a step is skipped on every rank when the loss is not finite on any rank; the logged
      training loss is the mean over the ranks;
    * only rank 0 validates, writes ``metrics.jsonl``, exports ``model.pt`` and writes the
      checkpoints; the others wait for it at each checkpoint (no rank runs ahead). The
      checkpoint has the single-process keys (rank 0's RNG states) plus ``ranks``: every
      rank's ``{"sampler_rng", "torch_rng"}``, so a resume with the same number of processes
      is exact on CPU.

    ``cfg.amp`` (``bf16``/``fp16``) applies on CUDA only: :meth:`Task.loss` runs inside
    ``torch.autocast("cuda", dtype)``; fp16 scales the loss with a
    :class:`torch.amp.GradScaler` (its state is checkpointed as ``grad_scaler``; steps whose
    scaled gradients overflow count as skipped). On the CPU ``amp`` is ignored.

    Raises:
        InputError: the run folder already holds a run and ``resume`` is False, the config
            differs from the one being resumed, or ``cfg.device`` / the torchrun environment
            is unusable.
        CheckpointError: the checkpoint to resume from is truncated/corrupt.
    """
    env = read_env() if dist_ctx is None else dist_ctx
    device = resolve_device(cfg.device, env)
    ctx = init_from_env(device) if dist_ctx is None else dist_ctx
    try:
        result = _train(cfg, task, sampler, run, ctx, device, resume=resume, progress=progress)
        if dist_ctx is None:
            # every rank is done before the group goes away: a rank that tears gloo down
            # while another still talks to it can abort ("terminate called without an
            # active exception"). Only on success: after an error a barrier could hang.
            barrier(ctx)
        return result
    finally:
        task.forward_module = task.module
        if dist_ctx is None:
            cleanup(ctx)


def _train(
    cfg: TrainConfig,
    task: Task,
    sampler: PatchSampler,
    run: RunFolder,
    ctx: DistContext,
    device: torch.device,
    *,
    resume: bool,
    progress: bool,
) -> TrainResult:
    module = task.module.to(device)
    task.device = device
    if ctx.enabled:
        task.forward_module = DistributedDataParallel(
            module,
            device_ids=[device.index] if device.type == "cuda" else None,
            find_unused_parameters=bool(getattr(task, "find_unused_parameters", False)),
        )
    else:
        task.forward_module = module
    params = [p for p in module.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: lr_factor(s, cfg))
    cuda = device.type == "cuda"
    amp_dtype = AMP_DTYPES.get(cfg.amp) if cuda else None
    scaler = torch.amp.GradScaler("cuda") if cuda and cfg.amp == "fp16" else None
    gen = torch.Generator().manual_seed(sampler_seed(cfg.seed, ctx.rank))
    start, best, skipped = 0, math.inf, 0

    # Every rank looks at the folder before rank 0 writes into it (the barrier below).
    state = run.load_latest() if run.exists() else None
    if run.exists() and not resume:
        raise InputError(f"{run.path}: already holds a run; pass --resume or choose another --out")
    resuming = resume and state is not None
    if resuming:
        _check_resume_config(run, cfg)
    barrier(ctx)
    if state is not None and resuming:
        module.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        if scaler is not None and "grad_scaler" in state:
            scaler.load_state_dict(state["grad_scaler"])
        _restore_rank_streams(state, ctx, gen, cfg)
        start, best, skipped = int(state["step"]), float(state["best"]), int(state["skipped"])
        if ctx.is_main:
            run.truncate_metrics(start)
    else:
        if ctx.rank > 0:  # rank 0 keeps the single-process stream; the others get their own
            torch.manual_seed(cfg.seed + RANK_SEED_STRIDE * ctx.rank)
        if ctx.is_main:
            run.write_config(cfg.to_json())
    barrier(ctx)
    if start >= cfg.steps:
        return TrainResult(start, best, skipped, 0.0, run.read_metrics(), ctx.rank, ctx.world_size)

    t0 = time.perf_counter()
    epoch_loss: list[float] = []
    bar = progress_bar(
        total=cfg.steps,
        initial=start,
        desc=f"train {cfg.model}",
        unit="step",
        progress=progress if ctx.is_main else False,
    )
    try:
        for step in range(start, cfg.steps):
            module.train()
            batch = {k: v.to(device) for k, v in sampler.batch(cfg.batch, gen).items()}
            autocast = (
                torch.autocast("cuda", dtype=amp_dtype)
                if amp_dtype is not None
                else contextlib.nullcontext()
            )
            with autocast:
                loss = task.loss(batch)
            loss = loss.float()
            opt.zero_grad(set_to_none=True)
            ok, mean_loss = _agree_on_loss(ctx, loss)
            if ok:
                (loss if scaler is None else scaler.scale(loss)).backward()
                if scaler is not None:
                    scaler.unscale_(opt)
                # gradients are identical on every rank after DDP's all-reduce: so is the norm
                norm = torch.nn.utils.clip_grad_norm_(params, 1.0)
                ok = bool(torch.isfinite(norm))
                if scaler is not None:
                    if ok:
                        scaler.step(opt)
                    scaler.update()  # lowers the scale after an overflow
                elif ok:
                    opt.step()
            if ok:
                epoch_loss.append(mean_loss)
            else:
                skipped += 1
            sched.step()
            bar.update(1)
            if ok:
                bar.set_postfix(loss=f"{mean_loss:.4g}", refresh=False)
            done = step + 1
            if done % cfg.epoch_steps == 0 or done == cfg.steps:
                streams = all_gather_object(
                    ctx, {"sampler_rng": gen.get_state(), "torch_rng": torch.get_rng_state()}
                )
                if ctx.is_main:
                    best = _validate_and_save(
                        cfg,
                        task,
                        run,
                        (opt, sched, scaler, gen),
                        ctx,
                        streams,
                        done=done,
                        best=best,
                        skipped=skipped,
                        epoch_loss=epoch_loss,
                        seconds=time.perf_counter() - t0,
                        progress=progress,
                    )
                # the other ranks wait here until rank 0 has written everything
                best = broadcast_object(ctx, best)
                epoch_loss = []
    finally:
        bar.close()
    return TrainResult(
        cfg.steps,
        best,
        skipped,
        time.perf_counter() - t0,
        run.read_metrics(),
        ctx.rank,
        ctx.world_size,
    )


def _validate_and_save(
    cfg: TrainConfig,
    task: Task,
    run: RunFolder,
    training_state: tuple[
        torch.optim.Optimizer,
        torch.optim.lr_scheduler.LRScheduler,
        torch.amp.GradScaler | None,
        torch.Generator,
    ],
    ctx: DistContext,
    streams: list[dict[str, Tensor]],
    *,
    done: int,
    best: float,
    skipped: int,
    epoch_loss: list[float],
    seconds: float,
    progress: bool,
) -> float:
    """Rank 0 at a validation boundary: validate, log, export if best, checkpoint.

    ``training_state``: the optimiser, scheduler, gradient scaler and sampler generator.
    Returns the best validation loss so far.
    """
    opt, sched, scaler, gen = training_state
    module = task.module
    module.eval()
    with torch.no_grad():
        val = task.validate()
    record = {
        "step": done,
        "epoch": math.ceil(done / cfg.epoch_steps),
        "train_loss": sum(epoch_loss) / len(epoch_loss) if epoch_loss else None,
        "lr": opt.param_groups[0]["lr"],
        "skipped_steps": skipped,
        "seconds": round(seconds, 3),
        **val,
    }
    vloss = float(val.get("val_loss", math.inf))
    if vloss < best or not run.model_path.is_file():
        best = min(best, vloss)
        task.export(run.model_path)
    record["best_val_loss"] = best
    run.append_metrics(record)
    if progress:
        write_line(  # a progress message: stderr, above the bar
            "step {step}: train {tl} val {vl:.5g} (best {b:.5g})".format(
                step=done,
                tl="n/a" if record["train_loss"] is None else f"{record['train_loss']:.5g}",
                vl=vloss,
                b=best,
            )
        )
    state: dict[str, Any] = {
        "model": module.state_dict(),
        "optimizer": opt.state_dict(),
        "scheduler": sched.state_dict(),
        "sampler_rng": gen.get_state(),
        "torch_rng": torch.get_rng_state(),
        "step": done,
        "best": best,
        "skipped": skipped,
    }
    if ctx.enabled:
        state["ranks"] = streams
    if scaler is not None:
        state["grad_scaler"] = scaler.state_dict()
    run.save_checkpoint(state, done, keep=cfg.checkpoints_kept)
    return best


def run_training(
    cfg: TrainConfig,
    build: Callable[..., tuple[Task, PatchSampler, LoadReport]],
    out: str | Path,
    *,
    resume: bool = False,
    progress: bool = True,
) -> tuple[TrainResult, LoadReport]:
    """Set torch up, ``build(cfg, progress=)`` the task and sampler, :func:`train` into the run
    folder ``out``; ``seconds`` of the result includes loading the data."""
    setup_torch(cfg)
    t0 = time.perf_counter()
    task, sampler, report = build(cfg, progress=progress)
    result = train(cfg, task, sampler, RunFolder(out), resume=resume, progress=progress)
    result.seconds = time.perf_counter() - t0
    return result, report


__all__ = [
    "AMP_DTYPES",
    "RANK_SEED_STRIDE",
    "RESUME_FREE",
    "CardTask",
    "CheckpointError",
    "Task",
    "TrainResult",
    "lr_factor",
    "run_training",
    "sampler_seed",
    "setup_torch",
    "train",
]
