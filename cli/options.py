"""Options shared by several commands (reading inputs, threads)."""

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


class _Threads(click.ParamType):
    name = "threads"

    def convert(self, value, param, ctx):
        if value is None or isinstance(value, int):
            return value
        text = str(value).strip().lower()
        if text == "auto":
            return None
        if text.isdigit() and int(text) >= 1:
            return int(text)
        self.fail(f"{value!r} is not a positive whole number or 'auto'", param, ctx)


def threads_option(*, render: bool = False, expose: bool = False):
    """``--threads N|auto``: the CPU threads the command computes with, chosen and applied
    (torch; with ``render`` also Mitsuba's Dr.Jit pool) as soon as the option is parsed.

    The default ``auto`` (see :func:`mcdenoise.threads.choose_threads`) respects
    ``OMP_NUM_THREADS``, else takes the physical cores not busy with other tasks at start, at
    least one. With ``expose`` the command receives ``threads``: the explicit ``N``, or
    ``None`` when none was given (so a spec or config file can keep its own value).
    """

    def apply(ctx: click.Context, param: click.Parameter, value: int | None) -> int | None:
        from mcdenoise.threads import apply_threads, choose_threads, set_render_threads

        choice = choose_threads(value)
        apply_threads(choice)
        if render:
            set_render_threads(choice.threads)
        ctx.meta["mcdenoise.threads"] = choice
        return value

    return click.option(
        "--threads",
        "threads",
        type=_Threads(),
        default=None,
        metavar="N|auto",
        expose_value=expose,
        callback=apply,
        help="CPU threads to compute with. Default auto: OMP_NUM_THREADS if set, else the "
        "physical cores not busy with other processes at start (at least 1); waiting OpenMP "
        "threads spin only briefly (GOMP_SPINCOUNT=10000 unless set).",
    )
