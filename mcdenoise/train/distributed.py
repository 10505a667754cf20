"""Multi-process training under ``torchrun``: the process context and a few collectives.

``torchrun --nproc_per_node N -m mcdenoise_cli.main train ...`` (or ``torchrun --no-python
mcdenoise train ...``) starts N copies of the command with the environment variables ``RANK``,
``WORLD_SIZE``, ``LOCAL_RANK``, ``MASTER_ADDR`` and ``MASTER_PORT`` set; multi-node runs add
``--nnodes`` / ``--node_rank`` (or a rendezvous endpoint) and every node must see the same run
folder and data set (a shared file system). :func:`init_from_env` reads those variables and,
when there is more than one process, joins the process group: ``gloo`` on CPU, ``nccl`` on CUDA
(one GPU per process, ``cuda:LOCAL_RANK``). Without the variables (a plain ``mcdenoise
train``) it returns a world of one and creates no process group, so single-process code pays
nothing.

Every helper below is a no-op (or the identity) in a world of one, so the training loop calls
them unconditionally.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from datetime import timedelta
from typing import Any

import torch
import torch.distributed as dist

from mcdenoise.errors import InputError

#: How long a collective (e.g. the other ranks waiting while rank 0 validates and writes a
#: checkpoint) may take before the process group gives up.
DEFAULT_TIMEOUT = timedelta(minutes=60)
#: Device names a config may use (``cuda:N`` too).
DEVICES = ("cpu", "cuda", "cuda:N", "auto")


@dataclass(frozen=True)
class DistContext:
    """Where this process stands in a (possibly one-process) training job.

    Attributes:
        rank: global rank, ``0 <= rank < world_size``.
        world_size: number of processes (1: no process group).
        local_rank: rank on this node (the GPU index under torchrun on CUDA).
        backend: ``"gloo"`` or ``"nccl"`` when a process group is in use, ``""`` otherwise.
        owns_group: this context created the process group (:func:`cleanup` destroys it).
    """

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    backend: str = ""
    owns_group: bool = field(default=False, compare=False)

    @property
    def is_main(self) -> bool:
        """Rank 0: the process that validates and writes the run folder."""
        return self.rank == 0

    @property
    def enabled(self) -> bool:
        """More than one process (collectives do something)."""
        return self.world_size > 1


def _int_var(environ: Mapping[str, str], name: str, default: int | None) -> int:
    raw = environ.get(name)
    if raw is None or raw == "":
        if default is None:
            raise InputError(f"environment variable {name} is not set (start with torchrun)")
        return default
    try:
        return int(raw)
    except ValueError:
        raise InputError(f"environment variable {name}={raw!r} is not an integer") from None


def read_env(environ: Mapping[str, str] | None = None) -> DistContext:
    """The context the torchrun variables describe, without joining any process group.

    ``WORLD_SIZE`` absent or 1: a world of one (rank 0). Otherwise ``RANK``, ``MASTER_ADDR``
    and ``MASTER_PORT`` must be set; ``LOCAL_RANK`` defaults to ``RANK``.

    Raises:
        InputError: a variable is missing or not an integer, or the rank is out of range.
    """
    env = os.environ if environ is None else environ
    world = _int_var(env, "WORLD_SIZE", 1)
    if world < 1:
        raise InputError(f"environment variable WORLD_SIZE={world} must be >= 1")
    if world == 1:
        return DistContext(local_rank=_int_var(env, "LOCAL_RANK", 0))
    rank = _int_var(env, "RANK", None)
    local = _int_var(env, "LOCAL_RANK", rank)
    if not 0 <= rank < world:
        raise InputError(f"environment variable RANK={rank} is not in [0, WORLD_SIZE={world})")
    if local < 0:
        raise InputError(f"environment variable LOCAL_RANK={local} must be >= 0")
    for name in ("MASTER_ADDR", "MASTER_PORT"):
        if not env.get(name):
            raise InputError(f"environment variable {name} is not set (start with torchrun)")
    return DistContext(rank=rank, world_size=world, local_rank=local)


def resolve_device(name: str, ctx: DistContext | None = None) -> torch.device:
    """The torch device a config's ``device`` names, for this process.

    ``cpu``; ``cuda`` / ``cuda:N``; ``auto`` = ``cuda`` when a GPU is visible, else ``cpu``.
    In a world of more than one process every CUDA choice becomes ``cuda:LOCAL_RANK`` (one
    GPU per process, as torchrun assigns them; an explicit ``N`` is then ignored -- restrict
    the GPUs with ``CUDA_VISIBLE_DEVICES`` instead).

    Raises:
        InputError: an unknown name, CUDA asked for but not available, or a GPU index beyond
            the visible ones.
    """
    ctx = ctx or DistContext()
    text = name.strip().lower()
    if text == "auto":
        text = "cuda" if torch.cuda.is_available() else "cpu"
    if text == "cpu":
        return torch.device("cpu")
    index: int | None = None
    if text.startswith("cuda:") and text[5:].isdigit():
        index = int(text[5:])
    elif text != "cuda":
        raise InputError(f"device {name!r}: expected one of {', '.join(DEVICES)}")
    if not torch.cuda.is_available():
        raise InputError(
            f"device {name!r}: CUDA is not available (torch {torch.__version__}); use cpu"
        )
    if ctx.enabled:
        index = ctx.local_rank
    index = torch.cuda.current_device() if index is None else index
    count = torch.cuda.device_count()
    if index >= count:
        raise InputError(f"device {name!r}: cuda:{index} does not exist ({count} GPU(s) visible)")
    return torch.device("cuda", index)


def init_from_env(
    device: torch.device | str, *, timeout: timedelta = DEFAULT_TIMEOUT
) -> DistContext:
    """Join the torchrun process group (if any) for a process that computes on ``device``.

    A world of one creates nothing. With more processes: ``nccl`` when ``device`` is CUDA
    (after ``torch.cuda.set_device(device)``), ``gloo`` otherwise, rendezvous through
    ``MASTER_ADDR:MASTER_PORT``. An already initialised default group (the caller made it) is
    used as it is and left to the caller (``owns_group`` False).

    Raises:
        InputError: see :func:`read_env`.
    """
    if dist.is_available() and dist.is_initialized():
        env = read_env()
        return DistContext(
            rank=dist.get_rank(),
            world_size=dist.get_world_size(),
            local_rank=env.local_rank,
            backend=str(dist.get_backend()),
        )
    ctx = read_env()
    if not ctx.enabled:
        return ctx
    if not dist.is_available():
        raise InputError("WORLD_SIZE > 1 but this torch build has no torch.distributed")
    dev = torch.device(device)
    backend = "nccl" if dev.type == "cuda" else "gloo"
    if dev.type == "cuda":
        torch.cuda.set_device(dev)
    dist.init_process_group(
        backend,
        init_method="env://",
        rank=ctx.rank,
        world_size=ctx.world_size,
        timeout=timeout,
    )
    return replace(ctx, backend=backend, owns_group=True)


def barrier(ctx: DistContext) -> None:
    """Wait until every process got here (nothing in a world of one)."""
    if not ctx.enabled:
        return
    if ctx.backend == "nccl":
        dist.barrier(device_ids=[torch.cuda.current_device()])
    else:
        dist.barrier()


def all_gather_object(ctx: DistContext, obj: Any) -> list[Any]:
    """``[obj of rank 0, obj of rank 1, ...]`` on every rank (``[obj]`` in a world of one).

    ``obj`` must be picklable; tensors in it keep their device (send CPU tensors, e.g. RNG
    states).
    """
    if not ctx.enabled:
        return [obj]
    out: list[Any] = [None] * ctx.world_size
    dist.all_gather_object(out, obj)
    return out


def broadcast_object(ctx: DistContext, obj: Any, src: int = 0) -> Any:
    """Rank ``src``'s ``obj`` on every rank; the other ranks block until ``src`` sends it."""
    if not ctx.enabled:
        return obj
    box = [obj if ctx.rank == src else None]
    dist.broadcast_object_list(box, src=src)
    return box[0]


def all_reduce_sum(ctx: DistContext, tensor: torch.Tensor) -> torch.Tensor:
    """Sum ``tensor`` over the ranks in place (it must be on the process group's device)."""
    if ctx.enabled:
        dist.all_reduce(tensor, op=dist.ReduceOp.SUM)
    return tensor


def cleanup(ctx: DistContext) -> None:
    """Destroy the process group if ``ctx`` created it (idempotent)."""
    if ctx.owns_group and dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


__all__ = [
    "DEFAULT_TIMEOUT",
    "DEVICES",
    "DistContext",
    "all_gather_object",
    "all_reduce_sum",
    "barrier",
    "broadcast_object",
    "cleanup",
    "init_from_env",
    "read_env",
    "resolve_device",
]
