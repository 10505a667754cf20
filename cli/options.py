"""Options shared by several commands (reading inputs)."""

from __future__ import annotations

import click

PROFILES = ("auto", "mcdenoise", "mitsuba", "cycles", "pbrt", "tungsten")


def read_options(f):
    """``--profile``, ``--mapping``, ``--part`` and ``--spp``: how input EXRs are read."""
    f = click.option(
        "--spp",
        type=click.IntRange(min=1),
        default=None,
        help="Samples per pixel of the input, when the file does not record it "
        "(needed to turn second moments into variances).",
    )(f)
    f = click.option(
        "--part",
        default=None,
        metavar="NAME",
        help="Part (multi-part EXR) or layer to read; default: the first with colour.",
    )(f)
    f = click.option(
        "--mapping",
        type=click.Path(dir_okay=False),
        default=None,
        metavar="FILE",
        help="TOML/JSON file mapping buffer names to channel names, for other renderers.",
    )(f)
    f = click.option(
        "--profile",
        type=click.Choice(PROFILES),
        default="auto",
        show_default=True,
        help="Renderer channel naming; auto-detected by default.",
    )(f)
    return f
