"""The ``mcdenoise`` command: click wiring only.

Each command parses its options and calls one library function. Errors caused by the input
(:class:`mcdenoise.errors.McdenoiseError`, missing or unreadable files) are printed as one line
``mcdenoise: error: ...`` on stderr with exit code 1; usage errors exit with 2 (click's
convention); Ctrl-C exits with 130. Set ``MCDENOISE_DEBUG=1`` to see tracebacks.

Importing this module sets ``GOMP_SPINCOUNT=10000`` (unless the user set ``OMP_WAIT_POLICY`` or
``GOMP_SPINCOUNT``) before anything imports torch, so a waiting OpenMP thread spins briefly, then
sleeps, instead of spinning long against another busy process (:mod:`mcdenoise.threads`,
``docs/results/threads.md``).
Warnings of the library (logger ``mcdenoise``) are printed as ``mcdenoise: warning: ...``.
"""

from __future__ import annotations

import os
import sys

from mcdenoise.threads import set_wait_policy

set_wait_policy()  # before torch (libgomp) starts: it reads the variable once, at start

import logging  # noqa: E402

import click  # noqa: E402

from mcdenoise import __version__  # noqa: E402

EXIT_ERROR = 1
EXIT_INTERRUPTED = 130


class _Group(click.Group):
    """A click group that turns library errors into one-line messages."""

    def invoke(self, ctx: click.Context):  # type: ignore[override]
        from mcdenoise.errors import McdenoiseError  # lazy: start-up of the CLI

        debug = os.environ.get("MCDENOISE_DEBUG", "") not in ("", "0")
        try:
            return super().invoke(ctx)
        except (click.exceptions.ClickException, click.exceptions.Exit, click.Abort):
            raise
        except KeyboardInterrupt:
            if debug:
                raise
            click.echo("\nmcdenoise: interrupted; outputs already written are complete", err=True)
            ctx.exit(EXIT_INTERRUPTED)
        except (McdenoiseError, OSError) as err:
            if debug:
                raise
            click.echo(f"mcdenoise: error: {_one_line(err)}", err=True)
            ctx.exit(EXIT_ERROR)
        except Exception as err:  # a bug: still one line, with the way to get the traceback
            if debug:
                raise
            click.echo(
                f"mcdenoise: internal error: {type(err).__name__}: {_one_line(err)} "
                "(set MCDENOISE_DEBUG=1 for the traceback, and please report it)",
                err=True,
            )
            ctx.exit(EXIT_ERROR)


class _EchoHandler(logging.Handler):
    """Writes each record as one line ``mcdenoise: warning: ...`` on click's stderr."""

    def emit(self, record: logging.LogRecord) -> None:
        click.echo(f"mcdenoise: {record.levelname.lower()}: {record.getMessage()}", err=True)


def _log_to_stderr() -> None:
    """Library log records of level WARNING and above -> one line each on stderr."""
    logger = logging.getLogger("mcdenoise")
    if not any(isinstance(h, _EchoHandler) for h in logger.handlers):
        logger.addHandler(_EchoHandler(logging.WARNING))


def _one_line(err: BaseException) -> str:
    from mcdenoise.errors import McdenoiseError  # lazy: start-up of the CLI

    if isinstance(err, OSError) and not isinstance(err, McdenoiseError) and err.strerror:
        # "[Errno 2] No such file or directory: 'x'" -> "No such file or directory: x"
        where = ", ".join(str(f) for f in (err.filename, err.filename2) if f is not None)
        return f"{err.strerror}: {where}" if where else err.strerror
    return " ".join(str(err).split()) or type(err).__name__


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="mcdenoise")
def main() -> None:
    """Monte Carlo denoising experiments: denoise EXR renders, compare methods, report.

    \b
    Typical use:
      mcdenoise info noisy.exr                    what the file holds
      mcdenoise denoise noisy.exr -o out.exr      best available method
      mcdenoise eval --ref ref.exr out.exr -o report/
    """
    _log_to_stderr()


def _register() -> None:
    from mcdenoise_cli import (  # lazy: start-up of the CLI
        denoise_cmd,
        eval_cmd,
        experiment_cmd,
        info_cmd,
        render_cmd,
        train_cmd,
    )

    main.add_command(denoise_cmd.denoise)
    main.add_command(denoise_cmd.methods_cmd)
    main.add_command(info_cmd.info)
    main.add_command(eval_cmd.eval_cmd)
    main.add_command(experiment_cmd.experiment_cmd)
    main.add_command(render_cmd.render)
    main.add_command(train_cmd.train)


_register()

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
