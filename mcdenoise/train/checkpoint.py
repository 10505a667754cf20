"""Run folders: resolved config, checkpoints, a ``latest`` pointer, metrics, the exported model.

Layout of ``runs/NAME/``::

    config.json              the resolved TrainConfig (written when the run starts)
    checkpoints/step_000100.pt ...   full training state (model, optimiser, scheduler, RNG, step)
    latest                   text: the file name of the newest *complete* checkpoint
    metrics.jsonl            one JSON object per validation ("epoch")
    model.pt                 the exported model (what ``--model runs/NAME`` loads)

Every file is written atomically (:func:`mcdenoise.io.atomic.atomic_path`), and ``latest`` is
rewritten only after the checkpoint it names is complete, so a run killed at any moment resumes
from a whole checkpoint. Checkpoints are read with :func:`mcdenoise.modelfile.load_state`
(``torch.load(weights_only=True)``: no pickled code runs); a truncated or corrupt one is a
:class:`~mcdenoise.modelfile.CheckpointError` naming the file and the previous checkpoint,
which is kept (``checkpoints_kept`` newest files).
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path
from typing import Any

from mcdenoise.io.atomic import write_text_atomic
from mcdenoise.modelfile import RUN_MODEL, CheckpointError, load_state, save_state

_STEP_FILE = re.compile(r"^step_(\d+)\.pt$")


class RunFolder:
    """A training run's folder (created on demand).

    Args:
        path: ``runs/NAME``.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.checkpoints = self.path / "checkpoints"
        self.config_path = self.path / "config.json"
        self.metrics_path = self.path / "metrics.jsonl"
        self.model_path = self.path / RUN_MODEL
        self.pointer = self.path / "latest"

    def create(self) -> None:
        self.checkpoints.mkdir(parents=True, exist_ok=True)

    def exists(self) -> bool:
        return self.config_path.is_file()

    def write_config(self, text: str) -> None:
        self.create()
        write_text_atomic(self.config_path, text)

    def read_config(self) -> dict[str, Any]:
        try:
            return json.loads(self.config_path.read_text())
        except (OSError, json.JSONDecodeError) as err:
            raise CheckpointError(
                f"{self.config_path}: cannot read the run's config ({err})"
            ) from None

    def checkpoint_files(self) -> list[Path]:
        """Complete-looking checkpoints, oldest first."""
        if not self.checkpoints.is_dir():
            return []
        found = [
            (int(m.group(1)), p)
            for p in self.checkpoints.iterdir()
            if (m := _STEP_FILE.match(p.name))
        ]
        return [p for _, p in sorted(found)]

    def latest(self) -> Path | None:
        """The checkpoint ``latest`` names, or ``None`` before the first one."""
        if not self.pointer.is_file():
            return None
        name = self.pointer.read_text().strip()
        if not _STEP_FILE.match(name):
            raise CheckpointError(f"{self.pointer}: does not name a checkpoint ({name!r})")
        return self.checkpoints / name

    def save_checkpoint(self, state: dict[str, Any], step: int, keep: int = 3) -> Path:
        """Write ``checkpoints/step_<step>.pt``, then point ``latest`` at it; prune old ones."""
        self.create()
        path = self.checkpoints / f"step_{step:06d}.pt"
        save_state(state, path)
        write_text_atomic(self.pointer, path.name + "\n")
        for old in self.checkpoint_files()[:-keep]:
            if old != path:
                old.unlink(missing_ok=True)
        return path

    def load_latest(self) -> dict[str, Any] | None:
        """The state ``latest`` names (``None`` when there is none yet).

        Raises:
            CheckpointError: the file is truncated/corrupt; the message names the previous
                checkpoint that is still there, to resume from by hand.
        """
        path = self.latest()
        if path is None:
            return None
        try:
            return load_state(path)
        except CheckpointError as err:
            older = [p for p in self.checkpoint_files() if p.name < path.name]
            hint = (
                f"; the previous checkpoint {older[-1]} is intact: point {self.pointer} at it"
                if older
                else ""
            )
            raise CheckpointError(f"{err}{hint}") from None

    def append_metrics(self, record: dict[str, Any]) -> None:
        """Append one JSON line to ``metrics.jsonl`` (rewritten atomically)."""
        old = self.metrics_path.read_text() if self.metrics_path.is_file() else ""
        write_text_atomic(self.metrics_path, old + _metrics_line(record))

    def read_metrics(self) -> list[dict[str, Any]]:
        if not self.metrics_path.is_file():
            return []
        return [
            json.loads(line) for line in self.metrics_path.read_text().splitlines() if line.strip()
        ]

    def truncate_metrics(self, step: int) -> None:
        """Drop metric lines after ``step`` (a resumed run recomputes them)."""
        kept = [r for r in self.read_metrics() if int(r.get("step", 0)) <= step]
        write_text_atomic(self.metrics_path, "".join(_metrics_line(r) for r in kept))


def _metrics_line(record: dict[str, Any]) -> str:
    """One line of ``metrics.jsonl``: valid JSON, a loss that is not finite (a diverged or
    empty validation, ``best_val_loss`` before the first one) written as ``null``."""
    finite = {
        k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in record.items()
    }
    return json.dumps(finite, sort_keys=True, allow_nan=False) + "\n"


__all__ = ["CheckpointError", "RunFolder", "load_state", "save_state"]
