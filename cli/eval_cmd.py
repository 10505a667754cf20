"""``mcdenoise eval``: compare outputs with references, or run an experiment (``--experiment``)."""

from __future__ import annotations

import sys

import click
from mcdenoise_cli.options import threads_option


def metrics_help() -> str:
    """The ``--metrics`` help, from the registered metrics (:data:`mcdenoise.eval.metrics.METRICS`)."""
    from mcdenoise.eval.metrics import METRICS, PARTS
    from mcdenoise.eval.temporal_metrics import TEMPORAL_METRICS

    names = ",".join(n for n, m in METRICS.items() if m.part_of is None)
    parts = "".join(f"; {k} also gives {','.join(v)}" for k, v in PARTS.items())
    optional = ",".join(n for n, m in METRICS.items() if m.optional)
    extra = f"; {optional} only when its package is installed" if optional else ""
    temporal = ",".join(TEMPORAL_METRICS)
    return (
        f"Comma-separated metrics (default: all: {names}{parts}{extra}; sequences also "
        f"{temporal}; with --experiment: the spec's)."
    )


class _MetricsOption(click.Option):
    """``--metrics``, whose help lists the registered metrics: built when the help is shown,
    so the command starts without loading the metrics (and torch)."""

    def get_help_record(self, ctx: click.Context):
        self.help = metrics_help()
        return super().get_help_record(ctx)


@click.command("eval")
@threads_option(expose=True)
@click.argument("outputs", nargs=-1, type=click.Path())
@click.option(
    "--ref",
    "reference",
    default=None,
    type=click.Path(),
    help="Reference EXR, a folder of references matched to outputs by file-name prefix, or "
    "a folder of frames frame_0000.exr ... (a sequence). Without --ref: each output's relMSE "
    "ESTIMATED from its input's half buffers (outputs of `denoise --estimate-error`; "
    "docs/results/estimate.md).",
)
@click.option(
    "-i",
    "--input",
    "inputs",
    multiple=True,
    type=click.Path(),
    help="Noisy input(s) to show as the 'noisy' row (default: each output's recorded source); "
    "for sequences, a folder of noisy frames.",
)
@click.option(
    "-o",
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    default="report",
    show_default=True,
    help="Folder for report.html, results.json and results.csv (with --experiment: also the "
    "rendered data, denoised outputs and the resumable work records).",
)
@click.option("--metrics", cls=_MetricsOption, default=None, metavar="LIST")
@click.option(
    "--experiment",
    "experiment",
    default=None,
    type=click.Path(dir_okay=False),
    metavar="SPEC",
    help="Run the experiment SPEC (TOML, e.g. data/experiments/demo.toml): render what is "
    "missing, run every method on every spp level, time render and denoise, and write an "
    "accuracy-vs-time report into -o. Re-running resumes.",
)
@click.option(
    "--progress/--no-progress",
    default=None,
    help="Progress on stderr (default: a bar on a terminal, a few plain lines in a log).",
)
@click.option(
    "--warmup",
    type=click.IntRange(min=0),
    default=None,
    metavar="N",
    help="Sequences: the first N frames (history warm-up) are reported apart from the means "
    "(default: 2; 16 is Noisebase's setting, 0 averages every frame).",
)
@click.option(
    "--shard",
    default=None,
    metavar="I/N",
    help="With --experiment: run only share I of N of the (scene, spp, method) units (a "
    "cluster job array spreads one experiment over N machines sharing -o); no report.",
)
@click.option(
    "--merge",
    is_flag=True,
    help="With --experiment: run nothing; build the report from every shard's finished "
    "units (an error names the shards that have not finished).",
)
@click.option(
    "--allow-commands",
    is_flag=True,
    help="With --experiment: let the spec run the external programs it names ([[external]], "
    "'cmd:...' methods); a spec that names any is refused without it, listing them.",
)
@click.option(
    "--force",
    is_flag=True,
    help="Evaluate outputs whose recorded source shows another scene than the reference "
    "(a warning instead of an error).",
)
@click.option(
    "--keep-going",
    is_flag=True,
    help="With --ref: exit with 0 even when images FAILED (NaN/Inf pixels in an output or its "
    "reference: no metrics). Without it the report is still written, and eval exits with 1.",
)
def eval_cmd(
    threads,
    outputs,
    reference,
    inputs,
    out_dir,
    metrics,
    experiment,
    progress,
    warmup,
    shard,
    merge,
    allow_commands,
    force,
    keep_going,
):
    """Compare denoised OUTPUTS (files or folders) with a reference; write a report.

    An output made by `mcdenoise denoise` records its source; when the source's
    mcdenoise:scene header names another scene than the reference's, eval refuses it unless
    --force. Files without scene headers (your own noisy.exr, ref.exr) are evaluated as given.
    An output made from one Blender view layer (--profile cycles:<Layer>) is compared with
    that layer of the reference.

    \b
    Sequences: when --ref is a folder of frames (frame_0000.exr, ...; DIR/<id>/ref of
    `mcdenoise render --frames`), each OUTPUT is a folder of denoised frames
    (`mcdenoise denoise DIR/<id> -o OUT`), matched by frame name. Per sequence: per-frame
    metrics, temporal relMSE, tPSNR and tRMAE (Noisebase's), with the first --warmup frames
    reported apart; a per-frame table; frames.csv in -o.

    \b
    With --experiment SPEC (no OUTPUTS, no --ref): run the experiment and write
    report.html, results.json and results.csv into -o DIR. --shard I/N runs share I of N
    (e.g. I = $SLURM_ARRAY_TASK_ID), --merge then writes the one report. A spec that names
    external programs ([[external]], 'cmd:...') runs them only with --allow-commands.
    """
    from mcdenoise.denoise_files import check_output_folder

    check_output_folder(out_dir, "-o")
    mode = "auto" if progress is None else ("bar" if progress else "off")
    names = [m.strip() for m in metrics.split(",") if m.strip()] if metrics else None
    if experiment is None and (shard is not None or merge):
        raise click.UsageError("--shard and --merge apply to --experiment SPEC")
    if experiment is None and allow_commands:
        raise click.UsageError("--allow-commands applies to --experiment SPEC")
    if experiment is not None:
        if shard is not None and merge:
            raise click.UsageError("--shard runs one share, --merge builds the report: not both")
        if outputs or reference is not None or inputs:
            raise click.UsageError("--experiment takes no OUTPUTS, --ref or --input")
        if force:
            raise click.UsageError("--force applies to --ref, not to --experiment")
        if keep_going:
            raise click.UsageError("--keep-going applies to --ref, not to --experiment")
        if warmup is not None:
            raise click.UsageError("--warmup applies to --ref sequences, not to --experiment")
        _experiment(
            experiment,
            out_dir,
            names,
            mode,
            threads,
            shard=shard,
            merge=merge,
            allow_commands=allow_commands,
        )
        return
    if not outputs:
        raise click.UsageError("Missing argument 'OUTPUTS...' (or give --experiment SPEC).")
    if reference is None:
        _estimated(outputs, out_dir)
        return

    from mcdenoise.eval import evaluate, write_report
    from mcdenoise.eval.temporal_metrics import WARMUP_FRAMES

    result = evaluate(
        reference,
        list(outputs),
        inputs=list(inputs) or None,
        metrics=names,
        # seconds of work: a bar on a terminal, no lines in a log
        progress=(sys.stderr.isatty() if mode == "auto" else mode),
        force=force,
        warn=lambda message: click.echo(f"mcdenoise: warning: {message}", err=True),
        warmup=WARMUP_FRAMES if warmup is None else warmup,
    )
    paths = write_report(result, out_dir)
    click.echo(result.format_table())
    if result.has_sequences:
        click.echo("")
        click.echo(result.format_frames())
    for kind in ("html", "json", "csv", "frames"):
        if kind in paths:
            click.echo(f"{kind}: {paths[kind]}")
    _fail_on_failed_rows(result, keep_going)


def _fail_on_failed_rows(result, keep_going):
    """Exit with 1 (one line on stderr) when a row FAILED, unless --keep-going: a script must
    not take a report whose rows have no metrics for a successful evaluation."""
    from mcdenoise.errors import McdenoiseError

    failed = [r for r in result.records if r.failed]
    if failed and not keep_going:
        raise McdenoiseError(
            f"{len(failed)} of {len(result.records)} evaluated image(s) FAILED (NaN/Inf "
            f"pixels, no metrics), e.g. {failed[0].file}: {failed[0].reason}; the report is "
            "written (--keep-going: exit with 0 anyway)"
        )


def _estimated(outputs, out_dir):
    """No reference: every output's relMSE estimated from its input's half buffers
    (mcdenoise.eval.estimate): with several outputs of one input, all normalised by the median
    of those outputs (each method runs again on the halves); one output alone keeps what
    `denoise --estimate-error` recorded. Printed and written as a report in -o."""
    from mcdenoise.denoise import denoise
    from mcdenoise.eval.estimate import estimate_files, format_estimates, write_estimate_report

    rows = estimate_files(
        list(outputs),
        rerun=lambda half, method, params: denoise(half, method, params=params).image,
        log=lambda line: click.echo(f"mcdenoise: {line}", err=True),
    )
    if not any(r["relmse_estimated"] is not None for r in rows if r["method"] != "noisy"):
        raise click.UsageError(
            "Missing option '--ref': no output here carries an estimated error (denoise an "
            "input with half buffers with --estimate-error to evaluate without a reference)."
        )
    click.echo(format_estimates(rows))
    if out_dir is not None:
        for kind, path in write_estimate_report(rows, out_dir).items():
            click.echo(f"{kind}: {path}")


def _experiment(
    spec_path,
    out_dir,
    metrics,
    progress,
    threads=None,
    *,
    shard=None,
    merge=False,
    allow_commands=False,
):
    from mcdenoise_cli.parsing import parse_shard

    from mcdenoise.experiments import load_experiment, run_experiment

    summary = run_experiment(
        _with_threads(load_experiment(spec_path, allow_commands=allow_commands), threads),
        out_dir,
        progress=progress,
        metrics=metrics,
        shard=None if shard is None else parse_shard(shard),
        merge=merge,
    )
    for line, to_stderr in summary.messages():  # results on stdout, notes on stderr
        click.echo(line, err=to_stderr)


def _with_threads(spec, threads):
    """An explicit ``--threads N`` overrides the spec's ``threads``."""
    import dataclasses

    return spec if threads is None else dataclasses.replace(spec, threads=threads)
