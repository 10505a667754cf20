"""``mcdenoise eval``."""

from __future__ import annotations

import click


@click.command("eval")
@click.argument("outputs", nargs=-1, required=True, type=click.Path())
@click.option(
    "--ref",
    "reference",
    required=True,
    type=click.Path(),
    help="Reference EXR, or a folder of references matched to outputs by file-name prefix.",
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
    help="Folder for report.html, results.json and results.csv.",
)
@click.option(
    "--metrics",
    default=None,
    metavar="LIST",
    help="Comma-separated metrics (default: all available: relmse,smape,mse,psnr,ssim,flip).",
)
def eval_cmd(outputs, reference, inputs, out_dir, metrics):
    """Compare denoised OUTPUTS (files or folders) with a reference; write a report."""
    from pathlib import Path

    from mcdenoise.eval import evaluate, write_report

    names = [m.strip() for m in metrics.split(",") if m.strip()] if metrics else None
    result = evaluate(reference, list(outputs), inputs=list(inputs) or None, metrics=names)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    paths = write_report(result, out_dir)
    click.echo(result.format_table() if hasattr(result, "format_table") else "")
    for kind in ("html", "json", "csv"):
        if kind in paths:
            click.echo(f"{kind}: {paths[kind]}")
