"""Run folders: atomic checkpoints, the latest pointer, truncated files, metrics."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mcdenoise.train.checkpoint import CheckpointError, RunFolder, load_state


def test_latest_names_the_newest_complete_checkpoint_and_old_ones_are_pruned(
    tmp_path: Path,
) -> None:
    run = RunFolder(tmp_path / "run")
    assert run.latest() is None and run.load_latest() is None
    for step in (10, 20, 30, 40):
        run.save_checkpoint({"w": torch.full((2,), float(step)), "step": step}, step, keep=2)
    assert run.latest() == run.checkpoints / "step_000040.pt"
    assert [p.name for p in run.checkpoint_files()] == ["step_000030.pt", "step_000040.pt"]
    assert run.load_latest()["step"] == 40
    assert not list(run.path.rglob(".mcdenoise-tmp-*"))


def test_truncated_checkpoint_is_a_clear_error_and_the_previous_one_stays(tmp_path: Path) -> None:
    run = RunFolder(tmp_path / "run")
    run.save_checkpoint({"step": 1, "w": torch.ones(100)}, 1)
    run.save_checkpoint({"step": 2, "w": torch.ones(100)}, 2)
    latest = run.latest()
    latest.write_bytes(latest.read_bytes()[:100])
    with pytest.raises(CheckpointError) as err:
        run.load_latest()
    msg = str(err.value)
    assert "step_000002.pt" in msg and "truncated or corrupt" in msg and "step_000001.pt" in msg
    assert "\n" not in msg
    assert load_state(run.checkpoints / "step_000001.pt")["step"] == 1


class Evil:
    """Any class outside torch's weights-only allow-list."""


def test_pickled_code_is_never_loaded(tmp_path: Path) -> None:
    p = tmp_path / "evil.pt"
    torch.save({"x": Evil()}, p)
    with pytest.raises(CheckpointError, match=r"evil\.pt"):
        load_state(p)


def test_metrics_append_and_truncate(tmp_path: Path) -> None:
    run = RunFolder(tmp_path / "run")
    run.create()
    for step in (5, 10, 15):
        run.append_metrics({"step": step, "val_loss": 1.0 / step})
    run.truncate_metrics(10)
    assert [r["step"] for r in run.read_metrics()] == [5, 10]
