"""``mcdenoise eval``: compare outputs with references, or run an experiment (``--experiment``)."""

from __future__ import annotations

import sys

import click


@click.command("eval")
@click.argument("outputs", nargs=-1, type=click.Path())
@click.option(
    "--ref",
    "reference",
    default=None,
    type=click.Path(),
    help="Reference EXR, or a folder of references matched to outputs by file-name prefix "
    "(required without --experiment).",
)
@click.option(
    "-i",
    "--input",
    "inputs",
    multiple=True,
    type=click.Path(),
    help="Noisy input(s) to show as the 'noisy' row (default: each output's recorded source).",
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
@click.option(
    "--metrics",
    default=None,
    metavar="LIST",
    help="Comma-separated metrics (default: all available: relmse,smape,mse,psnr,ssim,flip; "
    "with --experiment: the spec's).",
)
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
    help="Progress bars with --experiment (default: when on a terminal).",
)
def eval_cmd(outputs, reference, inputs, out_dir, metrics, experiment, progress):
    """Compare denoised OUTPUTS (files or folders) with a reference; write a report.

    \b
    With --experiment SPEC (no OUTPUTS, no --ref): run the experiment and write
    report.html, results.json and results.csv into -o DIR.
    """
    from pathlib import Path

    names = [m.strip() for m in metrics.split(",") if m.strip()] if metrics else None
    if experiment is not None:
        if outputs or reference is not None or inputs:
            raise click.UsageError("--experiment takes no OUTPUTS, --ref or --input")
        _experiment(experiment, out_dir, names, progress)
        return
    if reference is None:
        raise click.UsageError("Missing option '--ref' (or give --experiment SPEC).")
    if not outputs:
        raise click.UsageError("Missing argument 'OUTPUTS...' (or give --experiment SPEC).")

    from mcdenoise.eval import evaluate, write_report

    result = evaluate(reference, list(outputs), inputs=list(inputs) or None, metrics=names)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    paths = write_report(result, out_dir)
    click.echo(result.format_table() if hasattr(result, "format_table") else "")
    for kind in ("html", "json", "csv"):
        if kind in paths:
            click.echo(f"{kind}: {paths[kind]}")


def _experiment(spec_path, out_dir, metrics, progress):
    from mcdenoise.experiments import load_experiment, run_experiment

    show = sys.stderr.isatty() if progress is None else progress
    summary = run_experiment(load_experiment(spec_path), out_dir, progress=show, metrics=metrics)
    for line in summary.messages():
        click.echo(line)
