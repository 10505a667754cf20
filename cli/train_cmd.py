"""``mcdenoise train``."""

from __future__ import annotations

import click
from mcdenoise_cli.options import threads_option


@click.command()
@threads_option(expose=True)
@click.option(
    "--model",
    "model",
    default=None,
    metavar="NAME",
    help="Model to train: kpcn, kpcn-temporal, kalantari-xbf or kalantari-nlm (default: the "
    "config file's, "
    "else kalantari-xbf).",
)
@click.option(
    "--data",
    type=click.Path(),
    callback=lambda ctx, param, value: _check_data(value),
    default=None,
    help="Data set made by `mcdenoise render` (DIR/<id>.exr + DIR/ref/<id>.exr), or kpcn: a "
    "pack made by --pack (FILE.npz; read with numpy and torch only).",
)
@click.option(
    "--out",
    type=click.Path(file_okay=False),
    default=None,
    help="Run folder (config.json, checkpoints/, latest, metrics.jsonl, model.pt). Required "
    "unless --pack.",
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
    help="kpcn, kpcn-temporal: run folder or model file to start from (kpcn-temporal: a kpcn "
    "model, or a kpcn-temporal run to continue): --finetune-encoder keeps its trunk "
    "frozen; alone, the whole model trains further with this run's schedule.",
)
@click.option(
    "--pack",
    "pack",
    type=click.Path(dir_okay=False),
    default=None,
    metavar="FILE.npz",
    help="kpcn: prepare --data DIR as training would (same split, channels, config) and write "
    "it to FILE.npz instead of training; train from it with --data FILE.npz.",
)
@click.option(
    "--pack-dtype",
    "pack_dtype",
    type=click.Choice(["float16", "float32"]),
    default="float16",
    show_default=True,
    help="Storage of --pack: float16 (an array beyond its range stays float32) or float32 "
    "(the folder's values bit for bit).",
)
@click.option(
    "--pack-shard-mib",
    "pack_shard_mib",
    type=click.FloatRange(min=0),
    default=0,
    help="Split --pack into files of about this many MiB (FILE.npz, FILE.part1.npz, ...: "
    "parts that travel separately; the reader needs them all beside FILE.npz). 0: one file.",
)
@click.option(
    "--quiet",
    is_flag=True,
    help="No progress (default: a bar on a terminal, a few plain lines in a log).",
)
def train(
    threads,
    model,
    data,
    out,
    config_file,
    overrides,
    steps,
    resume,
    finetune_encoder,
    base,
    pack,
    pack_dtype,
    pack_shard_mib,
    quiet,
):
    """Train a model on rendered data; the run folder can be resumed and used with --model."""
    from mcdenoise.denoise_files import check_output_folder  # lazy: start-up of the CLI
    from mcdenoise.method import params_from_strings  # lazy: start-up of the CLI
    from mcdenoise.train.trainers import train_model  # lazy: start-up of the CLI

    if pack is not None:
        from mcdenoise.train.trainers import pack_data  # lazy: start-up of the CLI

        summary = pack_data(
            pack,
            model=model,
            data=data,
            config_file=config_file,
            overrides=_with_threads(params_from_strings(overrides, option="--set"), threads),
            dtype=pack_dtype,
            shard_bytes=int(pack_shard_mib * 2**20),
            progress=not quiet,
        )
        click.echo(summary.line())
        return
    if out is None:
        ctx = click.get_current_context()
        raise click.MissingParameter(
            ctx=ctx, param=next(p for p in ctx.command.params if p.name == "out")
        )
    check_output_folder(out, "--out")

    outcome = train_model(
        out,
        model=model,
        data=data,
        config_file=config_file,
        overrides=_with_threads(params_from_strings(overrides, option="--set"), threads),
        steps=steps,
        resume=resume,
        finetune_encoder=finetune_encoder,
        base=base,
        progress=not quiet,
    )
    if outcome.result.rank != 0:  # under torchrun only rank 0 reports
        return
    for line, to_stderr in outcome.messages():
        click.echo(line, err=to_stderr)


def _check_data(value):
    """``--data``: a folder, or a pack (``*.npz``); another existing file is refused, as a
    folder-only option refuses it."""
    from pathlib import Path  # lazy: start-up of the CLI

    if value is not None and Path(value).is_file() and not value.lower().endswith(".npz"):
        raise click.BadParameter(f"Directory {value!r} is a file.", param_hint="'--data'")
    return value


def _with_threads(values, threads):
    """An explicit ``--threads N`` is ``-s threads=N`` (an explicit ``-s threads`` wins)."""
    if threads is not None:
        values.setdefault("threads", str(threads))
    return values
