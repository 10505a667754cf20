"""``mcdenoise train``."""

from __future__ import annotations

import click


@click.command()
@click.option(
    "--model",
    "model",
    default=None,
    metavar="NAME",
    help="Model to train: kpcn, kalantari-xbf or kalantari-nlm (default: the config file's, "
    "else kalantari-xbf).",
)
@click.option(
    "--data",
    type=click.Path(file_okay=False),
    default=None,
    help="Data set made by `mcdenoise render` (DIR/<id>.exr + DIR/ref/<id>.exr).",
)
@click.option(
    "--out",
    type=click.Path(file_okay=False),
    required=True,
    help="Run folder (config.json, checkpoints/, latest, metrics.jsonl, model.pt).",
)
@click.option(
    "--config",
    "config_file",
    type=click.Path(dir_okay=False),
    default=None,
    help="TOML config file (keys of the [train] table, see the README).",
)
@click.option(
    "-s",
    "--set",
    "overrides",
    multiple=True,
    metavar="KEY=VALUE",
    help="Override a config key (repeatable), e.g. -s steps=2000 -s hidden=32,16.",
)
@click.option("--steps", type=click.IntRange(min=1), default=None, help="Shortcut for -s steps=N.")
@click.option(
    "--resume", is_flag=True, help="Continue the run in --out from its latest checkpoint."
)
@click.option(
    "--finetune-encoder",
    "finetune_encoder",
    default=None,
    metavar="SOURCE",
    help="kpcn: train only a new encoder for SOURCE (full, basic, color) against the frozen "
    "trunk of --from (Vogels 2018).",
)
@click.option(
    "--from",
    "base",
    default=None,
    metavar="RUN",
    help="kpcn: run folder or model file to start from: --finetune-encoder keeps its trunk "
    "frozen; alone, the whole model trains further with this run's schedule.",
)
@click.option("--quiet", is_flag=True, help="No progress bar.")
def train(model, data, out, config_file, overrides, steps, resume, finetune_encoder, base, quiet):
    """Train a model on rendered data; the run folder can be resumed and used with --model."""
    from pathlib import Path

    from mcdenoise.registry import params_from_strings
    from mcdenoise.train.checkpoint import RunFolder
    from mcdenoise.train.config import load_config
    from mcdenoise.train.kalantari import train_kalantari
    from mcdenoise.train.kpcn import UNUSED_SCALE_WEIGHT, train_kpcn

    values = params_from_strings(overrides, option="--set")
    if model is not None:
        values["model"] = model
    if data is not None:
        values["data"] = data
    if steps is not None:
        values["steps"] = str(steps)
    if finetune_encoder is not None:
        values["finetune_encoder"] = finetune_encoder
        values.setdefault("model", "kpcn")
    if base is not None:
        values["base"] = base
    run = RunFolder(out)
    if resume and config_file is None and run.exists():
        # Resume from the folder alone: its resolved config, then the flags.
        config_file = str(run.config_path)
    cfg = load_config(config_file, values)
    trainer = train_kpcn if cfg.model == "kpcn" else train_kalantari
    result, report = trainer(cfg, out, resume=resume, progress=not quiet)
    if result.rank != 0:  # under torchrun only rank 0 reports
        return
    if report.skipped:
        click.echo(report.summary(), err=True)
    last = result.metrics[-1] if result.metrics else {}
    ratio = last.get("val_ratio")
    click.echo(
        f"trained {cfg.model} for {result.steps} steps in {result.seconds:.0f} s; "
        f"best validation relMSE {result.best_val_loss:.5g}"
        + (f" (learned/fixed geometric mean {ratio:.3f})" if ratio is not None else "")
    )
    click.echo(f"model: {Path(out) / 'model.pt'}")
    use = {
        int(k[len("val_scale") : -len("_weight")]): v
        for k, v in last.items()
        if k.startswith("val_scale") and k.endswith("_weight")
    }
    if use:
        click.echo(
            "scale use (mean compositor weight on the validation images): "
            + ", ".join(f"1/{2**s} {v:.3f}" for s, v in sorted(use.items()))
            + "".join(
                f"; the 1/{2**s} scale is unused (its gate closed in training)"
                for s, v in sorted(use.items())
                if v < UNUSED_SCALE_WEIGHT
            )
        )
    worse = {k: v for k, v in last.items() if k.endswith("_ratio_to_noisy") and v > 1}
    if worse:
        click.echo(
            "warning: on the validation images the model is worse than its noisy input ("
            + ", ".join(f"{k[4:-15]} {v:.2f}x" for k, v in sorted(worse.items()))
            + "): training may have collapsed; try a longer warmup or a lower lr",
            err=True,
        )
