"""``mcdenoise denoise`` and ``mcdenoise methods``."""

from __future__ import annotations

import json

import click
from mcdenoise_cli.options import read_options
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
    help="Method (see `mcdenoise methods`), a comma-separated list, 'all' (every available "
    "method), or 'auto' (the best available).",
)
@click.option(
    "-p",
    "--param",
    "params",
    multiple=True,
    metavar="KEY=VALUE",
    help="Override a method parameter (repeatable), e.g. -p radius=7.",
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
    "--half", is_flag=True, help="Write float16 (values beyond ±65504 are clamped and counted)."
)
@click.option(
    "--compression",
    default="zip",
    show_default=True,
    type=click.Choice(["none", "zip", "zips", "piz", "rle", "pxr24", "b44", "dwaa"]),
)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON record per output.")
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
    half,
    compression,
    as_json,
):
    """Denoise INPUTS (EXR files or folders of them) and write EXR outputs.

    Each output keeps the input's size and records the method, its parameters, the source file
    and the seconds the method took in its header (see `mcdenoise info OUT.exr`).
    """
    from pathlib import Path

    from mcdenoise import denoise as dn
    from mcdenoise.io import load_buffers
    from mcdenoise.io.buffers import MissingFeatureError
    from mcdenoise.registry import best_method

    files = dn.collect_inputs(inputs)
    if model is not None and method == "auto":
        from mcdenoise.models.weights import model_method

        method = model_method(model)  # the model file says which method
    chosen = dn.parse_methods(method)
    overrides = dn.params_from_strings(params)
    if model is not None:
        learned = [m.name for m in chosen if "model" in m.defaults]
        if len(chosen) != 1 or not learned:
            raise click.UsageError(
                "--model needs exactly one learned --method (e.g. --method kpcn)"
            )
        overrides["model"] = model
    if overrides and len(chosen) != 1:
        raise click.UsageError("--param needs exactly one --method")
    for m in chosen:
        m.resolve_params(overrides)  # fail on a bad --param before reading anything
    if len(chosen) > 1 and output is not None and Path(output).suffix.lower() == ".exr":
        raise click.UsageError("several methods write several files: give -o a folder")
    if overrides and method == "auto":
        raise click.UsageError(
            "--param needs an explicit --method (the default depends on the input)"
        )
    read = dn.ReadOptions(profile=profile, mapping=mapping, part=part, spp=spp)
    jobs: list = []
    if method == "auto":  # decided per input, when it is read: the best method it can feed
        dn.plan_outputs(files, output, "auto", part=part)  # refuses -o x.exr for several inputs
        jobs = [(src, None, None) for src in files]
    else:
        for m in chosen:
            outs = dn.plan_outputs(files, output, m.name, part=part)
            jobs += [(src, dst, m) for src, dst in zip(files, outs)]
    if output is not None and Path(output).suffix.lower() != ".exr":
        Path(output).mkdir(parents=True, exist_ok=True)
    write = dn.WriteOptions(half=half, compression=compression)
    skip_missing = method == "all"
    bar = tqdm(jobs, desc="denoise", unit="img", disable=len(jobs) < 2)
    for src, dst, m in bar:
        buffers = None
        if m is None:
            buffers = load_buffers(src, profile=profile, mapping=mapping, part=part, spp=spp)
            m = best_method(buffers)
            dst = dn.plan_outputs([src], output, m.name, part=part)[0]
        bar.set_postfix_str(f"{src.name} {m.name}")
        try:
            res = dn.denoise_file(
                src,
                dst,
                m,
                params=overrides,
                device=device,
                read=read,
                write=write,
                buffers=buffers,
            )
        except MissingFeatureError as err:
            if not skip_missing:
                raise
            tqdm.write(f"skipped {m.name} on {src.name}: {err}")
            continue
        if as_json:
            click.echo(json.dumps(res.to_dict()))
        else:
            extra = f", {res.clamped} values clamped to the half range" if res.clamped else ""
            fixed = sum(res.result.repaired.values())
            extra += f", {fixed} NaN/Inf/negative input values repaired" if fixed else ""
            tqdm.write(
                f"{dst}  [{res.result.method}, {res.result.seconds:.2f} s on "
                f"{res.result.device}{extra}]"
            )


@click.command("methods")
def methods_cmd():
    """List the denoising methods, what they need, and whether they can run here."""
    from mcdenoise import denoise as dn

    best = None
    for m in dn.methods():
        reason = m.unavailable()
        if reason is None and best is None:
            best = m.name
        state = "available" if reason is None else f"unavailable: {reason}"
        click.echo(f"{m.name:<18} {m.summary}")
        click.echo(
            f"{'':<18} needs: {', '.join(m.requires)}; uses if present: "
            f"{', '.join(m.uses) or '-'}; {state}"
        )
        if m.defaults:
            ps = ", ".join(f"{k}={v}" for k, v in m.defaults.items())
            click.echo(f"{'':<18} parameters: {ps}")
    if best:
        click.echo(f"\ndefault (no --method): {best}")
