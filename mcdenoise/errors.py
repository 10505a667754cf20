"""Errors meant for the user.

Library code raises :class:`McdenoiseError` (or a subclass) when the *input* is wrong: a
missing file, a corrupt EXR, a buffer a method needs, an invalid parameter. Its message is one
line that names the offending file or value; the CLI prints exactly that line and exits with a
non-zero code, with no traceback. Anything else escaping the library is a bug.
"""

from __future__ import annotations


class McdenoiseError(Exception):
    """Base class for errors caused by bad input; ``str(err)`` is a one-line message."""


class InputError(McdenoiseError, ValueError):
    """An argument or parameter value is invalid (even kernel size, sigma <= 0, ...)."""


class ExrError(McdenoiseError, OSError):
    """An EXR file cannot be read or written (missing, truncated, corrupt, too large, ...)."""


class WriteError(McdenoiseError, OSError):
    """A file cannot be written (full disk, I/O error, no permission); the message names the
    file, and the file is as it was before the write."""
