"""The experiment's plots (matplotlib, Agg canvas, PNG files written atomically).

* :func:`plot_error_vs_spp`: relMSE against spp on log-log axes, one line per method, the
  ``c/N`` Monte Carlo line fitted to the noisy curve (slope -1), and the reference's noise
  floor as a horizontal line (the band below 2× the floor shaded: errors there are limited by
  the reference, not by the method);
* :func:`plot_error_vs_time`: relMSE against total seconds (render + denoise), one line per
  method through its spp levels, the Pareto front as a grey step line, its points labelled
  with their spp;
* :func:`plot_speedup`: the equal-quality speed-up against spp (1 = no gain over plain
  rendering).

Figures are drawn on a :class:`matplotlib.figure.Figure` with an Agg canvas, never through
``pyplot``, so nothing global (the backend, open figures) is touched. Every method keeps its
colour and marker in every plot (:func:`styles`). The legend sits to the right of the axes,
never over the data. Log axes (:func:`log_ticks`) have a labelled tick at every decade (every
power of 2 for spp) and minor ticks in between, labelled too (2 and 5) when the axis spans
fewer than :data:`LABEL_MINOR_BELOW` decades, so a short range still reads as numbers.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from typing import Any

from mcdenoise.io.atomic import atomic_path

#: Size of every plot's axes area plus margins in inches (at :data:`DPI`); the legend to the
#: right of it widens the PNG (``bbox_inches="tight"``).
FIGSIZE = (6.4, 4.4)
#: Below this many decades a log axis also labels its minor ticks 2 and 5 (3 too below 1).
LABEL_MINOR_BELOW = 3.0
DPI = 100
_MARKERS = "osD^v<>pXh*"


def plots_unavailable() -> str | None:
    """``None`` when matplotlib can draw here, else the reason."""
    try:
        import matplotlib  # noqa: F401  # lazy: optional, see except
    except ImportError:
        return "matplotlib is not installed (pip install 'mcdenoise[plots]')"
    return None


def styles(labels: Sequence[str]) -> dict[str, dict[str, Any]]:
    """label -> matplotlib line style; ``noisy`` is black and dashed, the rest cycle through
    the tab10/tab20 colours and a set of markers."""
    from matplotlib import colormaps  # lazy: matplotlib is optional and slow to import

    others = [lb for lb in labels if lb != "noisy"]
    cmap = colormaps["tab10" if len(others) <= 10 else "tab20"]
    out: dict[str, dict[str, Any]] = {}
    for i, label in enumerate(others):
        out[label] = {
            "color": cmap(i % cmap.N),
            "marker": _MARKERS[i % len(_MARKERS)],
            "linestyle": "-",
        }
    out["noisy"] = {"color": "black", "marker": "o", "linestyle": "--"}
    return out


def _figure() -> tuple[Any, Any]:
    from matplotlib.backends.backend_agg import (  # lazy: matplotlib is optional and slow to import
        FigureCanvasAgg,
    )
    from matplotlib.figure import Figure  # lazy: matplotlib is optional and slow to import

    fig = Figure(figsize=FIGSIZE, dpi=DPI)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ax.grid(True, which="both", alpha=0.25)
    return fig, ax


def _save(fig: Any, path: str | os.PathLike[str]) -> None:
    # fixed margins for the axes; the tight bounding box adds the legend on the right
    fig.subplots_adjust(left=0.12, right=0.97, bottom=0.12, top=0.92)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI, bbox_inches="tight", pad_inches=0.08)


def tick_text(value: float) -> str:
    """A log-axis tick label: ``0.05``, ``2``, ``100``, ``1e-05``.

    >>> [tick_text(v) for v in (0.05, 2.0, 100.0, 1e-5)]
    ['0.05', '2', '100', '1e-05']
    """
    return f"{value:g}"


def log_ticks(axis: Any, lo: float, hi: float, *, base: int = 10) -> None:
    """Ticks of a log ``axis`` (``ax.xaxis``/``ax.yaxis``) showing ``[lo, hi]``.

    ``base=10``: a labelled major tick at every decade and minor ticks at 2–9 times each,
    the minor ones labelled (2 and 5; also 3 below one decade) when the axis spans fewer than
    :data:`LABEL_MINOR_BELOW` decades. ``base=2`` (spp): a labelled tick at every power of 2,
    written as plain numbers (1, 2, 4, ...).
    """
    from matplotlib.ticker import (  # lazy: matplotlib is optional and slow to import
        FuncFormatter,
        LogLocator,
        NullFormatter,
        NullLocator,
    )

    axis.set_major_formatter(FuncFormatter(lambda v, _: tick_text(v)))
    if base == 2:
        axis.set_major_locator(LogLocator(base=2, numticks=64))
        axis.set_minor_locator(NullLocator())
        axis.set_minor_formatter(NullFormatter())
        return
    axis.set_major_locator(LogLocator(base=10, numticks=64))
    axis.set_minor_locator(LogLocator(base=10, subs=tuple(range(2, 10)), numticks=64))
    span = math.log10(hi / lo) if lo > 0 and hi > lo else 0.0
    if span >= LABEL_MINOR_BELOW:
        axis.set_minor_formatter(NullFormatter())
        return
    shown = (2, 3, 5) if span < 1 else (2, 5)

    def minor(v: float, _: Any) -> str:
        mantissa = round(v / 10.0 ** math.floor(math.log10(v) + 1e-9))
        return tick_text(v) if mantissa in shown else ""

    axis.set_minor_formatter(FuncFormatter(minor))
    axis.set_tick_params(which="minor", labelsize=7)


def _floor(ax: Any, floor: float | None, ys: Sequence[float]) -> None:
    if floor is None or not math.isfinite(floor) or floor <= 0:
        return
    ax.axhline(floor, color="0.35", linestyle=":", linewidth=1.5, label="reference noise floor")
    lo = min([*ys, floor]) / 3.0
    ax.axhspan(
        lo, 2.0 * floor, color="0.5", alpha=0.08, linewidth=0, label="within 2× of the floor"
    )


def _legend(ax: Any, n: int) -> None:
    """The legend outside the axes, to their right (never over a curve)."""
    ax.legend(
        fontsize=8,
        loc="upper left",
        bbox_to_anchor=(1.02, 1.0),
        borderaxespad=0.0,
        ncol=2 if n > 16 else 1,
        frameon=False,
    )


def _axes(ax: Any, *, x_base: int) -> None:
    """Ticks of both log axes for their final limits (:func:`log_ticks`)."""
    log_ticks(ax.xaxis, *ax.get_xlim(), base=x_base)
    log_ticks(ax.yaxis, *ax.get_ylim())


def _ylim(ax: Any, ys: Sequence[float], floor: float | None) -> None:
    vals = [y for y in ys if math.isfinite(y) and y > 0]
    if floor is not None and math.isfinite(floor) and floor > 0:
        vals.append(floor)
    if vals:
        ax.set_ylim(min(vals) / 1.6, max(vals) * 1.6)


def _plot_series(
    ax: Any,
    series: Mapping[str, tuple[Sequence[float], Sequence[float]]],
    st: Mapping[str, Mapping[str, Any]],
    *,
    linewidth: float,
) -> tuple[list[float], list[float]]:
    """One line per label through its points with ``x > 0`` and finite ``y > 0`` (log axes);
    returns every plotted x and y."""
    all_x: list[float] = []
    ys: list[float] = []
    for label, (x, y) in series.items():
        pts = [
            (a, b)
            for a, b in zip(x, y)
            if a is not None and b is not None and a > 0 and math.isfinite(b) and b > 0
        ]
        if not pts:
            continue
        xs, vs = zip(*pts)
        all_x.extend(xs)
        ys.extend(vs)
        ax.plot(xs, vs, label=label, markersize=4, linewidth=linewidth, **st[label])
    return all_x, ys


def plot_error_vs_spp(
    path: str | os.PathLike[str],
    series: Mapping[str, tuple[Sequence[float], Sequence[float]]],
    *,
    one_over_n: float | None = None,
    floor: float | None = None,
    title: str = "",
    ylabel: str = "relMSE",
) -> None:
    """relMSE vs spp, log-log, one line per label.

    Args:
        path: PNG file to write.
        series: label -> (spp levels, errors), in plotting order.
        one_over_n: ``c`` of the noisy ``c / N`` fit, drawn as a thin dotted line over the
            spp range (``None``: not drawn).
        floor: the reference's noise floor (``None``: not drawn).
        title, ylabel: texts.
    """
    fig, ax = _figure()
    st = styles(list(series))
    all_x, ys = _plot_series(ax, series, st, linewidth=1.3)
    if one_over_n is not None and all_x:
        lo, hi = min(all_x), max(all_x)
        ax.plot(
            [lo, hi],
            [one_over_n / lo, one_over_n / hi],
            color="0.45",
            linewidth=1,
            linestyle=(0, (1, 2)),
            label="1/N law, fit to noisy",
        )
    _floor(ax, floor, ys)
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    _ylim(ax, ys, floor)
    _axes(ax, x_base=2)
    ax.set_xlabel("samples per pixel (spp)")
    ax.set_ylabel(f"{ylabel} (log)")
    ax.set_title(title, fontsize=10)
    _legend(ax, len(series) + 2)
    _save(fig, path)


def plot_error_vs_time(
    path: str | os.PathLike[str],
    series: Mapping[str, tuple[Sequence[float], Sequence[float]]],
    *,
    front: Sequence[tuple[float, float, str]] = (),
    floor: float | None = None,
    title: str = "",
    ylabel: str = "relMSE",
    xlabel: str = "total seconds: render + denoise (log)",
) -> None:
    """relMSE vs total seconds, log-log, one line per label through its spp levels.

    Args:
        path: PNG file to write.
        series: label -> (total seconds, errors) in spp order.
        front: the Pareto front as (seconds, error, text) fastest first; drawn as a grey step
            line, each point annotated with ``text`` (e.g. ``"nlm 4"``).
        floor: the reference's noise floor (``None``: not drawn).
    """
    fig, ax = _figure()
    st = styles(list(series))
    _, ys = _plot_series(ax, series, st, linewidth=1.2)
    if front:
        fx = [p[0] for p in front]
        fy = [p[1] for p in front]
        ax.step(
            fx,
            fy,
            where="post",
            color="0.3",
            linewidth=2.5,
            alpha=0.35,
            label="Pareto front",
            zorder=0,
        )
        for sx, sy, text in front:
            ax.annotate(text, (sx, sy), textcoords="offset points", xytext=(3, 3), fontsize=6)
    _floor(ax, floor, ys)
    ax.set_xscale("log")
    ax.set_yscale("log")
    _ylim(ax, ys, floor)
    _axes(ax, x_base=10)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(f"{ylabel} (log)")
    ax.set_title(title, fontsize=10)
    _legend(ax, len(series) + 2)
    _save(fig, path)


def plot_speedup(
    path: str | os.PathLike[str],
    series: Mapping[str, tuple[Sequence[float], Sequence[float]]],
    *,
    title: str = "",
) -> None:
    """Equal-quality speed-up vs spp (log-log), one line per label, with a line at 1.

    Args:
        path: PNG file to write.
        series: label -> (spp levels, speed-ups).
    """
    fig, ax = _figure()
    st = styles(["noisy", *series])
    _, ys = _plot_series(ax, series, st, linewidth=1.3)
    ax.axhline(1.0, color="black", linewidth=1, linestyle="--", label="plain rendering")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    _ylim(ax, [*ys, 1.0], None)
    _axes(ax, x_base=2)
    ax.set_xlabel("samples per pixel (spp) the method started from")
    ax.set_ylabel("speed-up at equal quality (log)")
    ax.set_title(title, fontsize=10)
    _legend(ax, len(series) + 1)
    _save(fig, path)
