"""``mcdenoise experiment``: run an experiment spec and write its accuracy-vs-time report.

``mcdenoise eval --experiment SPEC`` is an alias kept for scripts (and ``make demo`` before
this verb): both call :func:`run_experiment_command`.
"""

from __future__ import annotations

import dataclasses

import click
from mcdenoise_cli.options import MetricsOption, progress_option, threads_option

#: The options that only an experiment takes (``eval`` accepts them with ``--experiment``).
EXPERIMENT_OPTIONS = {"shard": "--shard", "merge": "--merge", "allow_commands": "--allow-commands"}


@click.command("experiment")
@threads_option(expose=True)
@click.argument("spec", type=click.Path(dir_okay=False))
@click.option(
    "-o",
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    required=True,
    help="Folder for report.html, results.json and results.csv, the rendered data, the "
    "denoised outputs and the resumable work records.",
)
@click.option("--metrics", cls=MetricsOption, default=None, metavar="LIST")
@progress_option
@click.option(
    "--shard",
    default=None,
    metavar="I/N",
    help="Run only share I of N of the (scene, spp, method) units (a cluster job array "
    "spreads one experiment over N machines sharing -o); no report.",
)
@click.option(
    "--merge",
    is_flag=True,
    help="Run nothing; build the report from every shard's finished units (an error names "
    "the shards that have not finished).",
)
@click.option(
    "--allow-commands",
    is_flag=True,
    help="Let the spec run the external programs it names ([[external]], 'cmd:...' methods); "
    "a spec that names any is refused without it, listing them.",
)
def experiment_cmd(threads, spec, out_dir, metrics, progress, shard, merge, allow_commands):
    """Run the experiment SPEC (TOML, e.g. data/experiments/demo.toml): render what is
    missing, run every method on every spp level, time render and denoise, and write an
    accuracy-vs-time report (report.html, results.json, results.csv) into -o DIR.
    Re-running resumes.

    \b
    --shard I/N runs share I of N (e.g. I = $SLURM_ARRAY_TASK_ID); --merge then writes the
    one report. A spec that names external programs ([[external]], 'cmd:...') runs them only
    with --allow-commands. `eval --experiment SPEC` is an alias of this command.
    """
    run_experiment_command(
        spec,
        out_dir,
        metrics=metrics,
        progress=progress,
        threads=threads,
        shard=shard,
        merge=merge,
        allow_commands=allow_commands,
    )


def run_experiment_command(
    spec_path,
    out_dir,
    *,
    metrics=None,
    progress=None,
    threads=None,
    shard=None,
    merge=False,
    allow_commands=False,
):
    """What ``mcdenoise experiment`` (and its alias ``eval --experiment``) does, from the
    option values as click gives them."""
    from mcdenoise_cli.parsing import parse_shard  # lazy: imports mcdenoise.render

    from mcdenoise.denoise_files import check_output_folder  # lazy: start-up of the CLI
    from mcdenoise.experiments import load_experiment, run_experiment  # lazy: start-up of the CLI

    if shard is not None and merge:
        raise click.UsageError("--shard runs one share, --merge builds the report: not both")
    check_output_folder(out_dir, "-o")
    spec = load_experiment(spec_path, allow_commands=allow_commands)
    if threads is not None:  # an explicit --threads N overrides the spec's threads
        spec = dataclasses.replace(spec, threads=threads)
    summary = run_experiment(
        spec,
        out_dir,
        progress="auto" if progress is None else ("bar" if progress else "off"),
        metrics=[m.strip() for m in metrics.split(",") if m.strip()] if metrics else None,
        shard=None if shard is None else parse_shard(shard),
        merge=merge,
    )
    for line, to_stderr in summary.messages():  # results on stdout, notes on stderr
        click.echo(line, err=to_stderr)
