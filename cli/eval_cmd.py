"""``mcdenoise eval``: compare outputs with references (or, without one, estimate their error).

``eval --experiment SPEC`` is an alias of ``mcdenoise experiment SPEC``
(:mod:`mcdenoise_cli.experiment_cmd`), kept because scripts call it.
"""

from __future__ import annotations

import dataclasses
import sys

import click
from mcdenoise_cli.experiment_cmd import run_experiment_command
from mcdenoise_cli.options import MetricsOption, progress_option, threads_option


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
@click.option("--metrics", cls=MetricsOption, default=None, metavar="LIST")
@click.option(
    "--experiment",
    "experiment",
    default=None,
    type=click.Path(dir_okay=False),
    metavar="SPEC",
    help="Alias of `mcdenoise experiment SPEC`: run the experiment SPEC (TOML) and write its "
    "accuracy-vs-time report into -o (with --shard, --merge, --allow-commands as there).",
)
@progress_option
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
    help="With --experiment: see `mcdenoise experiment --help`.",
)
@click.option(
    "--merge",
    is_flag=True,
    help="With --experiment: see `mcdenoise experiment --help`.",
)
@click.option(
    "--allow-commands",
    is_flag=True,
    help="With --experiment: see `mcdenoise experiment --help`.",
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
    --experiment SPEC is an alias of `mcdenoise experiment SPEC` (no OUTPUTS, no --ref).
    """
    experiment_only = {"--shard": shard is not None, "--merge": merge}
    experiment_only["--allow-commands"] = allow_commands
    eval_only = {"OUTPUTS": bool(outputs), "--ref": reference is not None, "--input": bool(inputs)}
    eval_only |= {"--force": force, "--keep-going": keep_going, "--warmup": warmup is not None}
    wrong = [k for k, v in (eval_only if experiment else experiment_only).items() if v]
    if wrong:
        raise click.UsageError(
            f"--experiment (`mcdenoise experiment SPEC`) takes none of {', '.join(wrong)}"
            if experiment
            else f"{' and '.join(wrong)} appl{'ies' if len(wrong) == 1 else 'y'} to "
            "--experiment SPEC (`mcdenoise experiment`)"
        )
    if experiment is not None:
        run_experiment_command(
            experiment,
            out_dir,
            metrics=metrics,
            progress=progress,
            threads=threads,
            shard=shard,
            merge=merge,
            allow_commands=allow_commands,
        )
        return
    from mcdenoise.denoise_files import check_output_folder  # lazy: start-up of the CLI

    check_output_folder(out_dir, "-o")
    mode = "auto" if progress is None else ("bar" if progress else "off")
    names = [m.strip() for m in metrics.split(",") if m.strip()] if metrics else None
    if not outputs:
        raise click.UsageError("Missing argument 'OUTPUTS...' (or give --experiment SPEC).")
    if reference is None:
        _estimated(outputs, out_dir)
        return

    from mcdenoise.eval import EvalOptions, evaluate, write_report  # lazy: start-up of the CLI

    options = EvalOptions(
        inputs=list(inputs),
        metrics=names,
        # seconds of work: a bar on a terminal, no lines in a log
        progress=(sys.stderr.isatty() if mode == "auto" else mode),
        force=force,
        warn=lambda message: click.echo(f"mcdenoise: warning: {message}", err=True),
    )
    if warmup is not None:
        options = dataclasses.replace(options, warmup=warmup)
    result = evaluate(reference, list(outputs), options)
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
    from mcdenoise.errors import McdenoiseError  # lazy: start-up of the CLI

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
    from mcdenoise.denoise import denoise  # lazy: start-up of the CLI
    from mcdenoise.eval.estimate import (  # lazy: start-up of the CLI
        format_estimates,
        write_estimate_report,
    )
    from mcdenoise.eval.estimate_files import estimate_files  # lazy: start-up of the CLI

    rows = estimate_files(
        list(outputs),
        rerun=lambda half, method, params: denoise(half, method, params=params).image,
        log=lambda line: click.echo(f"mcdenoise: {line}", err=True),
    )
    if not any(
        r["relmse_estimated"] is not None or r.get("relmse_estimated_upper") is not None
        for r in rows
        if r["method"] != "noisy"
    ):
        raise click.UsageError(
            "Missing option '--ref': no output here carries an estimated error (denoise an "
            "input with half buffers with --estimate-error to evaluate without a reference)."
        )
    click.echo(format_estimates(rows))
    if out_dir is not None:
        for kind, path in write_estimate_report(rows, out_dir).items():
            click.echo(f"{kind}: {path}")
