"""Options shared by several commands (reading inputs, threads)."""

from __future__ import annotations

import click

#: The forms ``--profile`` takes, for its help (:func:`profile_forms` of the library's
#: :data:`mcdenoise.io.profiles.PROFILE_NAMES`, written out so the CLI starts without loading
#: the library; a test checks they agree). Values are checked by the library's own resolver.
PROFILE_FORMS = "auto, mcdenoise, mitsuba, cycles, cycles:<Layer>, pbrt, tungsten"


class _Profile(click.ParamType):
    """A renderer profile name as :func:`mcdenoise.io.profiles.get_profile` accepts it
    (``cycles:<Layer>`` included), or ``auto``; the value is passed on as written."""

    name = "profile"

    def convert(self, value, param, ctx):
        text = str(value).strip()
        if text.lower() == "auto":
            return "auto"
        from mcdenoise.io.profiles import (
            PROFILE_NAMES,
            ProfileError,
            get_profile,
        )  # lazy: start-up of the CLI

        try:
            get_profile(text)
        except ProfileError as err:
            known = text.partition(":")[0].strip().lower() in PROFILE_NAMES
            why = str(err) if known else f"unknown profile {text!r}"
            self.fail(f"{why}; valid forms: {profile_forms(PROFILE_NAMES)}", param, ctx)
        return text


def profile_forms(names) -> str:
    """The forms ``--profile`` takes, given the library's profile names."""
    forms = ["auto"]
    for name in names:
        forms += [name, f"{name}:<Layer>"] if name == "cycles" else [name]
    return ", ".join(forms)


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
        type=_Profile(),
        default="auto",
        show_default=True,
        help="Renderer channel naming, auto-detected by default: one of "
        f"{PROFILE_FORMS} (a Blender view layer by name: cycles:<Layer>).",
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
        from mcdenoise.threads import (
            apply_threads,
            choose_threads,
            set_render_threads,
        )  # lazy: start-up of the CLI

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


def metrics_help() -> str:
    """The ``--metrics`` help, from the registered metrics (:data:`mcdenoise.eval.metrics.METRICS`)."""
    from mcdenoise.eval.metrics import METRICS, PARTS  # lazy: start-up of the CLI
    from mcdenoise.eval.temporal_metrics import TEMPORAL_METRICS  # lazy: start-up of the CLI

    names = ",".join(n for n, m in METRICS.items() if m.part_of is None)
    parts = "".join(f"; {k} also gives {','.join(v)}" for k, v in PARTS.items())
    optional = ",".join(n for n, m in METRICS.items() if m.optional)
    extra = f"; {optional} only when its package is installed" if optional else ""
    temporal = ",".join(TEMPORAL_METRICS)
    return (
        f"Comma-separated metrics (default: all: {names}{parts}{extra}; sequences also "
        f"{temporal}; with --experiment: the spec's)."
    )


class MetricsOption(click.Option):
    """``--metrics``, whose help lists the registered metrics: built when the help is shown,
    so the command starts without loading the metrics (and torch)."""

    def get_help_record(self, ctx: click.Context):
        self.help = metrics_help()
        return super().get_help_record(ctx)


#: ``--progress/--no-progress`` of the commands that run long loops (render, eval, experiment).
progress_option = click.option(
    "--progress/--no-progress",
    default=None,
    help="Progress on stderr (default: a bar on a terminal, a few plain lines in a log).",
)
