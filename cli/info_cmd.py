"""``mcdenoise info``."""

from __future__ import annotations

import json

import click
from mcdenoise_cli.options import read_options


@click.command()
@click.argument("files", nargs=-1, required=True, type=click.Path())
@read_options
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of text.")
def info(files, profile, mapping, part, spp, as_json):
    """Describe EXR FILES: detected profile, buffers found and missing, NaN/Inf counts."""
    from mcdenoise.io import describe  # lazy: start-up of the CLI

    records = []
    for i, path in enumerate(files):
        fi = describe(path, profile=profile, mapping=mapping, part=part, spp=spp)
        if as_json:
            records.append(fi.to_dict())
        else:
            if i:
                click.echo("")
            click.echo(fi.format_text())
    if as_json:
        click.echo(json.dumps(records if len(records) > 1 else records[0], indent=2))
