"""Reflow of the distribution's text template into reStructuredText paragraphs and lists
(:func:`mcdenoise.render.random_scenes.distribution.describe_distribution`).
"""

from __future__ import annotations

import re
import textwrap


def _reflow(text: str, width: int = 95) -> str:
    """Refill the paragraphs of ``text`` (a definition's body indented by four spaces),
    never breaking inside an inline literal."""

    def fill(body: str, indent: str) -> str:
        body = re.sub(r"``[^`]*``", lambda m: m.group().replace(" ", "\x00"), body)
        out = textwrap.fill(
            body,
            width,
            initial_indent=indent,
            subsequent_indent=indent,
            break_long_words=False,
            break_on_hyphens=False,
        )
        return out.replace("\x00", " ")

    blocks = []
    for block in text.strip("\n").split("\n\n"):
        lines = block.split("\n")
        if len(lines) > 1 and set(lines[1]) == {"="}:  # a title
            blocks.append(block)
        elif len(lines) > 1 and lines[1].startswith("    ") and not lines[0].startswith(" "):
            body = " ".join(line.strip() for line in lines[1:])
            blocks.append(lines[0] + "\n" + fill(body, "    "))
        else:
            blocks.append(fill(" ".join(line.strip() for line in lines), ""))
    return "\n\n".join(blocks) + "\n"
