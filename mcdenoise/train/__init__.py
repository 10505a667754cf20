"""Training: configuration, patches from rendered data, run folders, the loop, baselines.

Modules: :mod:`~mcdenoise.train.config` (TrainConfig from TOML + flags),
:mod:`~mcdenoise.train.patches` (scan, split by image, load with a model's ``prepare`` hook,
importance-sampled crops with exact loss masks), :mod:`~mcdenoise.train.checkpoint` (run
folders: ``config.json``, ``checkpoints/``, ``latest``, ``metrics.jsonl``, ``model.pt``),
:mod:`~mcdenoise.train.loop` (the model-agnostic loop: AdamW, schedule, validation, exact
resume), :mod:`~mcdenoise.train.kalantari` (the Kalantari 2015 task),
:mod:`~mcdenoise.train.kpcn` (the kernel-predicting CNN), :mod:`~mcdenoise.train.trainers`
(the table of trainable models and :func:`~mcdenoise.train.trainers.train_model`, what
``mcdenoise train`` calls) and :mod:`~mcdenoise.train.grid` (grid search of the fixed filters,
the baseline of the learned ones).
"""

from mcdenoise.train.checkpoint import CheckpointError, RunFolder
from mcdenoise.train.config import TrainConfig, load_config
from mcdenoise.train.loop import TrainResult, train
from mcdenoise.train.patches import PatchSampler, load_items, scan_dataset, split_images

__all__ = [
    "CheckpointError",
    "PatchSampler",
    "RunFolder",
    "TrainConfig",
    "TrainResult",
    "load_config",
    "load_items",
    "scan_dataset",
    "split_images",
    "train",
]
