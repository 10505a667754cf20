"""String parsers of command-line options (``--spp 4,16,64``, ``--shard 2/5``, ``--res 320x240``).

Each turns the option's text into the value the library takes and leaves the validation to
the library's own checks (:func:`mcdenoise.render.config.check_spp_levels`,
:func:`mcdenoise.render.config.check_shard`), so a bad value gets the same message whether it
came from the command line or from Python; the message names the option.
"""

from __future__ import annotations

import re

from mcdenoise.render.config import RenderError, check_shard, check_spp_levels


def parse_spp(text: str) -> tuple[int, ...]:
    """``"4,16,64"`` -> ``(4, 16, 64)`` (validated).

    >>> parse_spp("4, 16,64")
    (4, 16, 64)
    """
    try:
        levels = tuple(int(t) for t in str(text).split(",") if t.strip())
    except ValueError:
        raise RenderError(f"--spp {text!r}: expected integers separated by commas") from None
    try:
        return check_spp_levels(levels)
    except RenderError as err:
        raise RenderError(f"--spp {text!r}: {err}") from None


def parse_shard(text: str) -> tuple[int, int]:
    """``"2/5"`` -> ``(2, 5)``: shard 2 of 5, numbered from 1.

    >>> parse_shard("2/5")
    (2, 5)
    """
    m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", str(text))
    if not m:
        raise RenderError(f"--shard {text!r}: expected i/n, e.g. 1/4 (shards are numbered from 1)")
    return check_shard((int(m.group(1)), int(m.group(2))))


def parse_res(text: str) -> tuple[int, int]:
    """``"256"`` -> ``(256, 256)``; ``"320x240"`` -> ``(320, 240)`` (width, height).

    >>> parse_res("320x240")
    (320, 240)
    """
    m = re.fullmatch(r"\s*(\d+)\s*(?:[xX]\s*(\d+)\s*)?", str(text))
    if not m or int(m.group(1)) < 1 or (m.group(2) is not None and int(m.group(2)) < 1):
        raise RenderError(f"--res {text!r}: expected N or WxH with positive integers")
    w = int(m.group(1))
    return w, int(m.group(2)) if m.group(2) is not None else w
