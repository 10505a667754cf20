"""The trainers: which models ``mcdenoise train`` trains, and the one call behind the command.

Each :class:`Trainer` names a model (the ``model`` config key, ``--model``), the function that
trains it into a run folder and the config keys only its family reads. :func:`train_model`
is ``mcdenoise train``: flags and file into a :class:`~mcdenoise.train.config.TrainConfig`,
the trainer of its model, and the lines the command prints (:class:`TrainOutcome`).

Adding a model: a ``train_<name>(cfg, out, *, resume, progress)`` function (see
:func:`mcdenoise.train.loop.run_training`) and a :class:`Trainer` in :data:`TRAINERS`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcdenoise.errors import InputError
from mcdenoise.train import auxnet, kalantari, kpcn, kpcn_temporal, nnao
from mcdenoise.train.checkpoint import RunFolder
from mcdenoise.train.config import TrainConfig, load_config
from mcdenoise.train.loop import TrainResult
from mcdenoise.train.pack import PackSummary, is_pack
from mcdenoise.train.patches import LoadReport

#: ``train(cfg, out, *, resume, progress) -> (TrainResult, LoadReport)``.
TrainFn = Callable[..., tuple[TrainResult, LoadReport]]


@dataclass(frozen=True)
class Trainer:
    """A trainable model.

    Attributes:
        name: the model name (``--model``, the ``model`` config key).
        summary: one line on what is trained.
        train: ``train(cfg, out, *, resume, progress)`` trains into the run folder ``out``.
        accepts: the config keys only this family of models reads (the others are shared).
    """

    name: str
    summary: str
    train: TrainFn
    accepts: frozenset[str] = frozenset()


# The functions are looked up when called, so a test may replace them in their module.
def _train_kalantari(cfg: TrainConfig, out: str | Path, **kwargs: Any):
    return kalantari.train_kalantari(cfg, out, **kwargs)


def _train_kpcn(cfg: TrainConfig, out: str | Path, **kwargs: Any):
    return kpcn.train_kpcn(cfg, out, **kwargs)


def _train_kpcn_temporal(cfg: TrainConfig, out: str | Path, **kwargs: Any):
    return kpcn_temporal.train_kpcn_temporal(cfg, out, **kwargs)


def _train_nnao(cfg: TrainConfig, out: str | Path, **kwargs: Any):
    return nnao.train_nnao(cfg, out, **kwargs)


def _train_auxnet(cfg: TrainConfig, out: str | Path, **kwargs: Any):
    return auxnet.train_auxnet(cfg, out, **kwargs)


_KALANTARI_KEYS = frozenset({"hidden", "passes", "regional", "guides"})
_KPCN_KEYS = frozenset(
    {
        "channels",
        "scales",
        "encoder",
        "albedo_kernels",
        "sources",
        "augment",
        "asym_slope",
        "finetune_encoder",
        "finetune_keep",
        "base",
        "exposure",
        "normalize_exposure",
        "prefilter",
    }
)

#: Every trainable model, in the order ``--model``'s help lists them.
TRAINERS: tuple[Trainer, ...] = (
    Trainer(
        "kalantari-xbf",
        "MLP predicting per-pixel cross-bilateral bandwidths (Kalantari 2015)",
        _train_kalantari,
        _KALANTARI_KEYS,
    ),
    Trainer(
        "kalantari-nlm",
        "MLP predicting per-pixel NLM parameters (Kalantari 2015)",
        _train_kalantari,
        _KALANTARI_KEYS,
    ),
    Trainer(
        "kpcn",
        "kernel-predicting CNN with source-aware encoders, 3 kernel scales (Bako 2017, "
        "Vogels 2018)",
        _train_kpcn,
        _KPCN_KEYS,
    ),
    Trainer(
        "kpcn-temporal",
        "temporal kernel predictor over motion-warped windows around a trained kpcn "
        "(Vogels 2018); --from a kpcn model",
        _train_kpcn_temporal,
        frozenset({"window", "temporal_mode", "temporal_weight", "trunk", "base", "augment"}),
    ),
    Trainer(
        "nnao",
        "per-pixel MLP predicting AO from a G-buffer neighbourhood (Holden 2016)",
        _train_nnao,
        frozenset({"hidden"}),
    ),
    Trainer(
        "auxnet",
        "kernel-predicting U-Net prefiltering noisy albedo and normal (kpcn -p "
        "prefilter=learned); -s channels=24,32,48",
        _train_auxnet,
        frozenset({"channels", "augment"}),
    ),
)


def get_trainer(name: str) -> Trainer:
    """The trainer of model ``name``; ``InputError`` naming the trainable ones."""
    for t in TRAINERS:
        if t.name == name:
            return t
    raise InputError(f"unknown model {name!r}; trainable: {', '.join(t.name for t in TRAINERS)}")


def implied_model(values: Mapping[str, Any]) -> str | None:
    """The model that ``values`` (config keys given without ``model``) can only mean: the one
    family accepting ``finetune_encoder`` when it is given (only kpcn has per-source encoders),
    else ``None`` (the config's default)."""
    if "finetune_encoder" not in values:
        return None
    names = [t.name for t in TRAINERS if "finetune_encoder" in t.accepts]
    return names[0] if len(names) == 1 else None


@dataclass
class TrainOutcome:
    """What :func:`train_model` did: the resolved config, the result and the data report."""

    config: TrainConfig
    out: Path
    result: TrainResult
    report: LoadReport

    def messages(self) -> list[tuple[str, bool]]:
        """The lines ``mcdenoise train`` prints, each with ``True`` for stderr: skipped data,
        the summary, the model path, the use of the kernel scales, a collapse warning."""
        cfg, result, report = self.config, self.result, self.report
        lines: list[tuple[str, bool]] = []
        if report.skipped:
            lines.append((report.summary(), True))
        last = result.metrics[-1] if result.metrics else {}
        ratio = last.get("val_ratio")
        lines.append(
            (
                f"trained {cfg.model} for {result.steps} steps in {result.seconds:.0f} s; "
                f"best validation relMSE {result.best_val_loss:.5g}"
                + (f" (learned/fixed geometric mean {ratio:.3f})" if ratio is not None else ""),
                False,
            )
        )
        lines.append((f"model: {self.out / 'model.pt'}", False))
        use = {
            int(k[len("val_scale") : -len("_weight")]): v
            for k, v in last.items()
            if k.startswith("val_scale") and k.endswith("_weight")
        }
        if use:
            lines.append(
                (
                    "scale use (mean compositor weight on the validation images): "
                    + ", ".join(f"1/{2**s} {v:.3f}" for s, v in sorted(use.items()))
                    + "".join(
                        f"; the 1/{2**s} scale is unused (its gate closed in training)"
                        for s, v in sorted(use.items())
                        if v < kpcn.UNUSED_SCALE_WEIGHT
                    ),
                    False,
                )
            )
        worse = {k: v for k, v in last.items() if k.endswith("_ratio_to_noisy") and v > 1}
        if worse:
            lines.append(
                (
                    "warning: on the validation images the model is worse than its noisy "
                    "input ("
                    + ", ".join(f"{k[4:-15]} {v:.2f}x" for k, v in sorted(worse.items()))
                    + "): training may have collapsed; try a longer warmup or a lower lr",
                    True,
                )
            )
        return lines


def _flag_values(
    overrides: Mapping[str, Any] | None, model: str | None, data: str | None
) -> dict[str, Any]:
    """The config values of the command line: ``-s key=value``, then ``--model`` and ``--data``."""
    values: dict[str, Any] = dict(overrides or {})
    if model is not None:
        values["model"] = model
    if data is not None:
        values["data"] = data
    return values


def train_model(
    out: str | os.PathLike[str],
    *,
    model: str | None = None,
    data: str | None = None,
    config_file: str | os.PathLike[str] | None = None,
    overrides: Mapping[str, Any] | None = None,
    steps: int | None = None,
    resume: bool = False,
    finetune_encoder: str | None = None,
    base: str | None = None,
    progress: bool = True,
) -> TrainOutcome:
    """``mcdenoise train``: resolve the config and train its model into the run folder ``out``.

    The config is the model's defaults, then ``config_file`` (TOML/JSON; with ``resume`` and
    no file, the run folder's resolved ``config.json``), then ``overrides`` (``-s key=value``),
    then the other arguments (``steps``, ``data``, ...), which win.

    Raises:
        InputError: bad config, unknown model, unusable data (see the trainers).
    """
    values = _flag_values(overrides, model, data)
    if steps is not None:
        values["steps"] = str(steps)
    if finetune_encoder is not None:
        values["finetune_encoder"] = finetune_encoder
        implied = implied_model(values)
        if implied is not None:
            values.setdefault("model", implied)
    if base is not None:
        values["base"] = base
    run = RunFolder(out)
    if resume and config_file is None and run.exists():
        # Resume from the folder alone: its resolved config, then the flags.
        config_file = run.config_path
    cfg = load_config(config_file, values)
    trainer = get_trainer(cfg.model)
    if is_pack(cfg.data) and cfg.model != "kpcn":
        raise InputError(f"{cfg.data}: a pack (.npz) is kpcn training data: pass --model kpcn")
    result, report = trainer.train(cfg, out, resume=resume, progress=progress)
    return TrainOutcome(cfg, Path(out), result, report)


def pack_data(
    path: str | os.PathLike[str],
    *,
    model: str | None = None,
    data: str | None = None,
    config_file: str | os.PathLike[str] | None = None,
    overrides: Mapping[str, Any] | None = None,
    dtype: str = "float16",
    shard_bytes: int = 0,
    progress: bool = True,
) -> PackSummary:
    """``mcdenoise train --pack PATH``: resolve the config as :func:`train_model` does and
    write its data, prepared for the model, to the pack ``PATH`` (kpcn only;
    :mod:`mcdenoise.train.pack`).

    Raises:
        InputError: another model, no data folder, bad config, no usable training image.
    """
    values = _flag_values(overrides, model, data)
    cfg = load_config(config_file, values)
    if cfg.model != "kpcn":
        raise InputError(f"--pack prepares kpcn training data only, not {cfg.model}")
    return kpcn.pack_kpcn(cfg, path, dtype=dtype, shard_bytes=shard_bytes, progress=progress)


__all__ = [
    "TRAINERS",
    "TrainOutcome",
    "Trainer",
    "get_trainer",
    "implied_model",
    "pack_data",
    "train_model",
]
