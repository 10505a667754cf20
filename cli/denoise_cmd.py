"""``mcdenoise denoise`` and ``mcdenoise methods``."""

from __future__ import annotations

import json
import sys

import click
from mcdenoise_cli.options import read_options, threads_option
from tqdm import tqdm


@click.command()
@click.argument("inputs", nargs=-1, required=True, type=click.Path())
@click.option(
    "-o",
    "--output",
    type=click.Path(),
    default=None,
    help="Output .exr (one input) or folder. Default: <input>_<method>.exr beside each input.",
)
@click.option(
    "-m",
    "--method",
    default="auto",
    show_default=True,
    help="Method (see `mcdenoise methods`, which lists the aliases too, e.g. xbf for "
    "cross-bilateral), a comma-separated list, 'all' (every available method; one that "
    "cannot run on an input is skipped there, with the reason), 'auto' (the best "
    "available method that accepts the input: --verbose says which and why), or an "
    "external command, 'cmd:PROGRAM ARGS {input} {output}' ({input}: one EXR with every "
    "buffer; {color}, {albedo}, {normal}: one file each, PFM or {color:exr}; {output}: the "
    "EXR whose R,G,B it writes; -p timeout=SECONDS, default 600; see docs/methods.md).",
)
@click.option(
    "-p",
    "--param",
    "params",
    multiple=True,
    metavar="KEY=VALUE",
    help="Override a method parameter (repeatable; see `mcdenoise methods`), e.g. "
    "--method nlm -p search_radius=7.",
)
@click.option(
    "--model",
    "model",
    default=None,
    metavar="PATH",
    help="Trained model (run folder or model file) for a learned method; same as -p model=PATH.",
)
@click.option(
    "--device",
    type=click.Choice(["auto", "cpu", "cuda"]),
    default="auto",
    show_default=True,
)
@read_options
@click.option(
    "--include-outputs",
    is_flag=True,
    help="Also denoise a folder's files that this tool wrote (those with a mcdenoise:method "
    "header); by default a folder's earlier outputs are skipped, so a re-run never denoises them again.",
)
@threads_option()
@click.option(
    "--half", is_flag=True, help="Write float16 (values beyond ±65504 are clamped and counted)."
)
@click.option(
    "--compression",
    default="zip",
    show_default=True,
    type=click.Choice(["none", "zip", "zips", "piz", "rle", "pxr24", "b44", "dwaa"]),
)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON record per output.")
@click.option(
    "--estimate-error",
    is_flag=True,
    help="Estimate each output's relMSE without a reference, from the input's two half "
    "buffers (mcdenoise render --halves): the method also runs on each half, judged against "
    "the other. Written as mcdenoise:relmse_estimated (and _se) in the header and "
    "relmse_estimated in --json; below its own noise as an upper bound "
    "(relmse_estimated_upper); a method that uses both halves itself (nfor) gets a note "
    "instead.",
)
@click.option(
    "-v",
    "--verbose",
    is_flag=True,
    help="Say on stderr which method each input got and, with the default (auto), which "
    "better-ranked methods were skipped for it and why.",
)
@click.option(
    "--progress/--no-progress",
    default=True,
    help="Progress on stderr with several outputs: a bar on a terminal, a few plain lines in "
    "a log.",
)
def denoise(
    inputs,
    output,
    method,
    params,
    model,
    device,
    profile,
    mapping,
    part,
    spp,
    include_outputs,
    half,
    compression,
    as_json,
    estimate_error,
    verbose,
    progress,
):
    """Denoise INPUTS (EXR files or folders of them) and write EXR outputs.

    Each output keeps the input's size and records the method, its parameters, the source file
    and the seconds the method took in its header (see `mcdenoise info OUT.exr`).

    A temporal method (`mcdenoise methods` says which) takes each folder as one sequence (the
    layout of `mcdenoise render --frames`: frame_0000.exr ..., ordered by frame number; the
    ref/ subfolder is not read) and the files given one by one as one more. The frames are
    checked first (consecutive numbers, one size, motion vectors in every frame: the profiles
    find them by name, --mapping names other channels); outputs are written frame by frame,
    and a re-run skips the frames already done (replaying the frames before the first missing
    one through the method, so its history is exact). A per-frame method takes a folder as
    separate images.

    Nothing is written when an output would replace one of the inputs (e.g. -o naming the
    input folder, which holds a.exr and a_nlm.exr): one line says which.
    """
    from mcdenoise.batch import OptionError, denoise_paths  # lazy: start-up of the CLI
    from mcdenoise.denoise_files import ReadOptions, WriteOptions  # lazy: start-up of the CLI
    from mcdenoise.method import params_from_strings  # lazy: start-up of the CLI

    read = ReadOptions(
        profile=profile, mapping=mapping, part=part, spp=spp, include_outputs=include_outputs
    )
    write = WriteOptions(half=half, compression=compression, estimate_error=estimate_error)
    try:
        outcomes = denoise_paths(
            inputs,
            output,
            method,
            params=params_from_strings(params),
            model=model,
            device=device,
            read=read,
            write=write,
            progress=progress,
        )
    except OptionError as err:
        raise click.UsageError(str(err)) from None
    for outcome in outcomes:  # results on stdout, "skipped ..." on stderr
        if verbose:
            for line in outcome.choice_lines():
                tqdm.write(line, file=sys.stderr)
        if outcome.result is None:
            tqdm.write(outcome.summary(), file=sys.stderr)
        elif as_json:
            tqdm.write(json.dumps(outcome.result.to_dict()), file=sys.stdout)
        else:
            tqdm.write(outcome.summary(), file=sys.stdout)


@click.command("methods")
def methods_cmd():
    """List the denoising methods, what they need, and whether they can run here."""
    from mcdenoise.registry import method_aliases, methods  # lazy: start-up of the CLI

    best = None
    aliases = method_aliases()
    for m in methods():
        reason = m.unavailable()
        if reason is None and best is None:
            best = m.name
        state = "available" if reason is None else f"unavailable: {reason}"
        click.echo(f"{m.name:<18} {m.summary}")
        if aliases.get(m.name):
            click.echo(f"{'':<18} alias: {', '.join(aliases[m.name])}")
        click.echo(
            f"{'':<18} needs: {', '.join(m.requires)}; uses if present: "
            f"{', '.join(m.uses) or '-'}; {state}"
        )
        if m.temporal:
            click.echo(f"{'':<18} temporal: a folder of frames is one sequence, in frame order")
        if m.defaults:
            ps = ", ".join(f"{k}={v}" for k, v in m.defaults.items())
            click.echo(f"{'':<18} parameters: {ps}")
    if best:
        click.echo(
            "\ndefault (no --method): the first available method above that accepts the "
            f"input ({best} for one with every buffer and its variance; "
            "`mcdenoise denoise --verbose` says which and why)"
        )
