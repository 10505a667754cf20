"""Multi-process training (torchrun, DDP over gloo on the CPU), devices and mixed precision."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
from datetime import timedelta
from pathlib import Path

import pytest
import torch
import torch.multiprocessing as mp
from tiny_settings import TINY_KALANTARI
from torch import Tensor, nn

from mcdenoise.errors import InputError
from mcdenoise.models.kalantari import KalantariModel
from mcdenoise.train.checkpoint import RunFolder, save_state
from mcdenoise.train.config import load_config
from mcdenoise.train.distributed import (
    DistContext,
    cleanup,
    init_from_env,
    read_env,
    resolve_device,
)
from mcdenoise.train.kalantari import train_kalantari
from mcdenoise.train.loop import sampler_seed, train

#: The tiny Kalantari settings shared with tests/train/test_loop.py.
TINY = TINY_KALANTARI
TORCHRUN_ENV = ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def torchrun_train(*args: str) -> subprocess.CompletedProcess[str]:
    """``torchrun --nproc_per_node 2 -m mcdenoise_cli.main train ARGS`` (gloo on the CPU)."""
    env = {k: v for k, v in os.environ.items() if k not in TORCHRUN_ENV}
    env.update(OMP_NUM_THREADS="1", MCDENOISE_DEBUG="1")
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--nproc_per_node",
        "2",
        "--master_addr",
        "127.0.0.1",
        "--master_port",
        str(free_port()),
        "-m",
        "mcdenoise_cli.main",
        "train",
        "--quiet",
        *args,
    ]
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)


def tiny_flags(data: Path) -> list[str]:
    flags = ["--data", str(data)]
    for k, v in TINY.items():
        flags += ["-s", f"{k}={v}"]
    return flags


@pytest.fixture(scope="module")
def ddp_run(tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 12-step Kalantari run by 2 gloo processes (checkpoints at steps 6 and 12)."""
    out = tmp_path_factory.mktemp("ddp") / "run"
    proc = torchrun_train("--out", str(out), *tiny_flags(tiny_dataset))
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def single_run(tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same run in one process."""
    out = tmp_path_factory.mktemp("single") / "run"
    cfg = load_config(None, {"data": str(tiny_dataset), **{k: str(v) for k, v in TINY.items()}})
    train_kalantari(cfg, out, progress=False)
    return out


def ckpt(run: Path, step: int) -> dict:
    return torch.load(run / "checkpoints" / f"step_{step:06d}.pt", weights_only=True)


def test_torchrun_trains_and_writes_the_single_process_format(
    ddp_run: Path, single_run: Path
) -> None:
    ddp, one = RunFolder(ddp_run), RunFolder(single_run)
    assert ddp.read_config() == one.read_config()
    assert ddp.latest().name == "step_000012.pt"
    a, b = ckpt(ddp_run, 12), ckpt(single_run, 12)
    assert set(a) == set(b) | {"ranks"}
    assert set(a["model"]) == set(b["model"])  # bare module keys, no DDP "module." prefix
    assert len(a["ranks"]) == 2
    assert torch.equal(a["ranks"][0]["sampler_rng"], a["sampler_rng"])
    assert not torch.equal(a["ranks"][0]["sampler_rng"], a["ranks"][1]["sampler_rng"])
    model = KalantariModel.load(ddp_run)
    assert model.card.training["val_images"]
    # one line per validation: rank 1 wrote none
    assert [r["step"] for r in ddp.read_metrics()] == [6, 12]
    assert not list(ddp_run.rglob(".mcdenoise-tmp-*"))


def test_ddp_training_differs_from_one_process_with_the_same_seed(
    ddp_run: Path, single_run: Path
) -> None:
    # rank 0 draws the single process's batches: the difference is rank 1's averaged gradient
    a, b = ckpt(ddp_run, 12), ckpt(single_run, 12)
    assert torch.equal(
        ckpt(ddp_run, 6)["ranks"][0]["sampler_rng"], ckpt(single_run, 6)["sampler_rng"]
    )
    assert any(not torch.allclose(a["model"][k], b["model"][k]) for k in a["model"])


def test_resume_under_torchrun_is_exact(ddp_run: Path, tmp_path: Path) -> None:
    # the folder a kill during step 8 leaves: checkpoint 6 is the latest, metrics up to 6
    half = tmp_path / "half"
    shutil.copytree(ddp_run, half)
    (half / "checkpoints" / "step_000012.pt").unlink()
    (half / "latest").write_text("step_000006.pt\n")
    proc = torchrun_train("--out", str(half), "--resume")
    assert proc.returncode == 0, proc.stderr[-3000:]
    a, b = ckpt(ddp_run, 12), ckpt(half, 12)
    assert a["step"] == b["step"] == 12
    for k, v in a["model"].items():
        assert torch.equal(v, b["model"][k]), k
    for r in range(2):
        for key in ("sampler_rng", "torch_rng"):
            assert torch.equal(a["ranks"][r][key], b["ranks"][r][key]), (r, key)
    keep = ("step", "train_loss", "val_loss", "lr")
    straight = [{k: m[k] for k in keep} for m in RunFolder(ddp_run).read_metrics()]
    assert [{k: m[k] for k in keep} for m in RunFolder(half).read_metrics()] == straight


def test_a_two_process_checkpoint_resumes_in_one_process(
    ddp_run: Path, tiny_dataset: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    shutil.copytree(ddp_run, run)
    (run / "latest").write_text("step_000006.pt\n")
    cfg = load_config(None, {"data": str(tiny_dataset), **{k: str(v) for k, v in TINY.items()}})
    with pytest.warns(UserWarning, match="2 process"):
        result, _ = train_kalantari(cfg, run, resume=True, progress=False)
    assert result.steps == 12 and [r["step"] for r in result.metrics] == [6, 12]
    assert "ranks" not in ckpt(run, 12)


# --- a toy task: DDP averages gradients, ranks agree on skipped steps --------------------------


class ToySampler:
    """Batches ``{"x": (B, 3), "y": (B, 1)}`` of a noisy linear function, from ``g``."""

    def batch(self, size: int, g: torch.Generator) -> dict[str, Tensor]:
        x = torch.randn(size, 3, generator=g)
        y = x @ torch.tensor([[1.0], [-2.0], [0.5]]) + 0.1 * torch.randn(size, 1, generator=g)
        return {"x": x, "y": y}


class UnionSampler(ToySampler):
    """One process drawing what ranks 0 and 1 of a seed-``seed`` run would draw together."""

    def __init__(self, seed: int) -> None:
        self.g1 = torch.Generator().manual_seed(sampler_seed(seed, 1))

    def batch(self, size: int, g: torch.Generator) -> dict[str, Tensor]:
        a, b = super().batch(size, g), super().batch(size, self.g1)
        return {k: torch.cat([a[k], b[k]]) for k in a}


class ToyNet(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.trunk = nn.Linear(3, 4)
        self.heads = nn.ModuleList([nn.Linear(4, 1), nn.Linear(4, 1)])

    def forward(self, x: Tensor, head: int) -> Tensor:
        return self.heads[head](torch.tanh(self.trunk(x)))


class ToyTask:
    """Alternates between two heads (one unused per step) and can fail at one step."""

    find_unused_parameters = True

    def __init__(self, nan_at: int | None = None) -> None:
        torch.manual_seed(0)
        self.module = ToyNet()
        self.forward_module: nn.Module = self.module
        self.device = torch.device("cpu")
        self.calls = 0
        self.nan_at = nan_at

    def loss(self, batch: dict[str, Tensor]) -> Tensor:
        self.calls += 1
        out = self.forward_module(batch["x"], self.calls % 2)
        loss = (out - batch["y"]).square().mean()
        return loss * float("nan") if self.calls == self.nan_at else loss

    def validate(self) -> dict[str, float]:
        x = torch.linspace(-1, 1, 12, device=self.device).reshape(4, 3)
        return {"val_loss": float(self.module(x, 0).square().mean())}

    def export(self, path: Path) -> None:
        save_state({"state": self.module.state_dict()}, path)


def toy_config(**kw: object):
    base = {"model": "toy", "steps": 8, "epoch_steps": 4, "batch": 4, "lr": 0.05, "warmup": 1}
    return load_config(None, {**base, **{k: str(v) for k, v in kw.items()}})


def _toy_worker(rank: int, folder: str, port: int) -> None:
    os.environ.update(
        RANK=str(rank),
        LOCAL_RANK=str(rank),
        WORLD_SIZE="2",
        MASTER_ADDR="127.0.0.1",
        MASTER_PORT=str(port),
    )
    torch.set_num_threads(1)
    ctx = init_from_env("cpu", timeout=timedelta(seconds=60))  # a hang fails in a minute
    try:
        task = ToyTask(nan_at=3 if rank == 1 else None)
        result = train(
            toy_config(), task, ToySampler(), RunFolder(Path(folder) / "run"), dist_ctx=ctx
        )
        assert isinstance(task.forward_module, ToyNet)  # the DDP wrapper is gone after training
        torch.save(
            {
                "state": task.module.state_dict(),
                "skipped": result.skipped_steps,
                "rank": result.rank,
            },
            Path(folder) / f"rank{rank}.pt",
        )
    finally:
        cleanup(ctx)
    # Leave without the interpreter's exit-time destructors: once in a clean-clone CI run a
    # rank aborted there ("terminate called without an active exception", gloo's threads)
    # after it had trained and saved. Failures above still raise before this line.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def test_ddp_averages_gradients_and_ranks_skip_together(tmp_path: Path) -> None:
    mp.spawn(_toy_worker, args=(str(tmp_path), free_port()), nprocs=2, join=True)
    r0, r1 = (torch.load(tmp_path / f"rank{r}.pt", weights_only=True) for r in (0, 1))
    assert (r0["rank"], r1["rank"]) == (0, 1)
    # rank 1's non-finite loss at step 3 made both ranks skip that step
    assert r0["skipped"] == r1["skipped"] == 1
    for k, v in r0["state"].items():
        assert torch.equal(v, r1["state"][k]), k
    # one process on both ranks' batches (mean loss = mean of the ranks' means) gets the same
    ref = ToyTask(nan_at=3)
    res = train(toy_config(), ref, UnionSampler(0), RunFolder(tmp_path / "ref"), progress=False)
    for k, v in ref.module.state_dict().items():
        assert torch.allclose(v, r0["state"][k], rtol=1e-5, atol=1e-6), k
    ddp_metrics = RunFolder(tmp_path / "run").read_metrics()
    assert [m["step"] for m in ddp_metrics] == [4, 8]
    for mine, theirs in zip(ddp_metrics, res.metrics, strict=True):
        assert mine["train_loss"] == pytest.approx(theirs["train_loss"], rel=1e-5)
    # one process on rank 0's batches alone ends elsewhere: rank 1's gradients counted
    alone = ToyTask(nan_at=3)
    train(toy_config(), alone, ToySampler(), RunFolder(tmp_path / "alone"), progress=False)
    assert not torch.allclose(alone.module.trunk.weight, ref.module.trunk.weight, atol=1e-4)


# --- devices and mixed precision -----------------------------------------------------------------


def test_amp_is_ignored_on_the_cpu(tmp_path: Path) -> None:
    states = {}
    for amp in ("off", "bf16", "fp16"):
        task = ToyTask()
        train(toy_config(amp=amp), task, ToySampler(), RunFolder(tmp_path / amp), progress=False)
        states[amp] = task.module.state_dict()
        assert "grad_scaler" not in torch.load(
            RunFolder(tmp_path / amp).latest(), weights_only=True
        )
    for amp in ("bf16", "fp16"):
        for k, v in states["off"].items():
            assert torch.equal(v, states[amp][k]), (amp, k)


def test_torchrun_environment_and_device_names() -> None:
    assert read_env({}) == DistContext()
    assert read_env({"WORLD_SIZE": "1", "LOCAL_RANK": "0"}).world_size == 1
    full = {
        "WORLD_SIZE": "4",
        "RANK": "3",
        "LOCAL_RANK": "1",
        "MASTER_ADDR": "h",
        "MASTER_PORT": "1",
    }
    ctx = read_env(full)
    assert (ctx.rank, ctx.world_size, ctx.local_rank, ctx.is_main) == (3, 4, 1, False)
    with pytest.raises(InputError, match="MASTER_PORT"):
        read_env({k: v for k, v in full.items() if k != "MASTER_PORT"})
    with pytest.raises(InputError, match="RANK=4"):
        read_env({**full, "RANK": "4"})
    with pytest.raises(InputError, match="'x'"):
        read_env({**full, "WORLD_SIZE": "x"})
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(InputError, match="'tpu'"):
        resolve_device("tpu")
    if not torch.cuda.is_available():
        with pytest.raises(InputError, match="CUDA is not available"):
            resolve_device("cuda:0")


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the error without a GPU")
def test_training_on_a_missing_gpu_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="device 'cuda'"):
        train(toy_config(device="cuda"), ToyTask(), ToySampler(), RunFolder(tmp_path / "r"))
    assert not (tmp_path / "r").exists()


@pytest.mark.gpu
@pytest.mark.parametrize("amp", ["bf16", "fp16"])
def test_mixed_precision_training_on_cuda_gives_finite_losses(
    tiny_dataset: Path, tmp_path: Path, amp: str
) -> None:
    values = {k: str(v) for k, v in TINY.items()}
    cfg = load_config(None, {**values, "data": str(tiny_dataset), "device": "cuda", "amp": amp})
    result, _ = train_kalantari(cfg, tmp_path / "run", progress=False)
    # fp16: the gradient scaler starts at 2**16 and halves after each overflow (skipped step)
    assert result.skipped_steps <= (6 if amp == "fp16" else 0)
    last = result.metrics[-1]["train_loss"]
    assert last is not None and torch.isfinite(torch.tensor(last))
    assert torch.isfinite(torch.tensor(result.best_val_loss))
    state = torch.load(RunFolder(tmp_path / "run").latest(), weights_only=True)
    assert ("grad_scaler" in state) == (amp == "fp16")
    model = KalantariModel.load(tmp_path / "run")
    assert all(torch.isfinite(p).all() for p in model.parameters())
