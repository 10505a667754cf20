"""Small HTML helpers shared by the experiment report's modules (:mod:`.report`,
:mod:`.overall_report`): escaping, number formatting, table and image tags."""

from __future__ import annotations

import html
import math
import re
from collections.abc import Iterable, Sequence
from typing import Any

from mcdenoise.experiments.record_values import number

#: The mark of a result within 2× of the reference's noise floor.
LIM_MARK = ' <span class="lim" title="within 2x of the reference noise floor">≈</span>'


def esc(text: Any) -> str:
    return html.escape(str(text), quote=True)


def g(value: Any, digits: int = 3) -> str:
    v = number(value) if not isinstance(value, float | int) else float(value)
    if v is None:
        return "\u2013"
    if math.isnan(v):
        return "NaN"
    if math.isinf(v):
        return "\u221e" if v > 0 else "\u2212\u221e"
    if v != 0 and (abs(v) < 1e-3 or abs(v) >= 1e5):
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}g}"


def sec(value: Any) -> str:
    v = number(value) if not isinstance(value, float | int) else float(value)
    if v is None:
        return "\u2013"
    return f"{v:.3g} s"


def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._") or "x"


def sub(text: str) -> str:
    """A second line in a table cell (already escaped ``text``)."""
    return f'<span class="sub">{text}</span>'


def img(name: str, alt: str, extra: str = "") -> str:
    return f'<img src="images/{esc(name)}" alt="{esc(alt)}"{extra}>'


def table(head: Sequence[str], rows: Iterable[str], cls: str = "t") -> str:
    th = "".join(f"<th>{h}</th>" for h in head)
    return (
        f'<table class="{cls}"><thead><tr>{th}</tr></thead><tbody>{"".join(rows)}</tbody></table>'
    )
