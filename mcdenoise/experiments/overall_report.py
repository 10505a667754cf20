"""The experiment report's sections over all scenes: plots, error table, mean bias, equal
time, equal quality and statistics, for every scene and, when some scenes are flagged (noisy
curve not monotone: fireflies), also without them, with a switch between the two versions that
works offline and without a script (two radio inputs and CSS sibling selectors, see
``templates/experiment.html``)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from mcdenoise.experiments.analysis import ExperimentResult, OverallView
from mcdenoise.experiments.definitions import RENDER_TIME_UNKNOWN as UNKNOWN_TIME
from mcdenoise.experiments.headlines import BIAS_LIMIT, pct
from mcdenoise.experiments.htmlkit import LIM_MARK as _LIM_MARK
from mcdenoise.experiments.htmlkit import esc as _esc
from mcdenoise.experiments.htmlkit import g as _g
from mcdenoise.experiments.htmlkit import img as _img
from mcdenoise.experiments.htmlkit import sec as _sec
from mcdenoise.experiments.htmlkit import sub as _sub
from mcdenoise.experiments.htmlkit import table as _table
from mcdenoise.experiments.plots import plot_error_vs_spp, plot_error_vs_time, plot_speedup
from mcdenoise.experiments.record_values import number, relmse_of
from mcdenoise.experiments.spec_fields import NOISY
from mcdenoise.experiments.stats import BETTER, IS_BASELINE, WORSE
from mcdenoise.geomean import geometric_mean


def plot_series(
    result: ExperimentResult, records: Sequence[Mapping[str, Any]], x: str
) -> dict[str, tuple[list[float], list[float]]]:
    series: dict[str, tuple[list[float], list[float]]] = {}
    for label in result.labels:
        rs = sorted((r for r in records if r["method"] == label), key=lambda r: r["spp"])
        xs, ys = [], []
        for r in rs:
            e = relmse_of(r)
            xv = number(r.get(x)) if x != "spp" else float(r["spp"])
            if e is not None and xv is not None:
                xs.append(xv)
                ys.append(e)
        if xs:
            series[label] = (xs, ys)
    return series


def _overall_plots(
    result: ExperimentResult, view: OverallView, out: Path, tag: str = "overall"
) -> list[str]:

    rows = [o for o in view.rows if o.complete]
    fake = [
        {
            "method": o.method,
            "spp": o.spp,
            "total_seconds": o.seconds,
            "metrics": {"relmse": o.relmse},
        }
        for o in rows
    ]
    floors = [
        s.noise_floor for s in result.scenes if s.noise_floor is not None and s.id in view.scenes
    ]
    floor = geometric_mean(floors, invalid="none")
    noisy = [o for o in rows if o.method == NOISY and o.relmse]
    c = geometric_mean([o.relmse * o.spp for o in noisy]) if noisy else None
    names = [f"plot_{tag}_error_spp.png", f"plot_{tag}_error_time.png", f"plot_{tag}_speedup.png"]
    n = len(view.scenes)
    where = f"geometric mean over {n} scene{'s' if n != 1 else ''}"
    if n < len(result.scenes):
        where += " without flagged"
    plot_error_vs_spp(
        out / "images" / names[0],
        plot_series(result, fake, "spp"),
        one_over_n=c,
        floor=floor,
        title=f"Error vs samples per pixel ({where})",
    )
    if not result.render_time_known:  # no time axis: the error-vs-spp plot alone
        return names[:1]
    plot_error_vs_time(
        out / "images" / names[1],
        plot_series(result, fake, "total_seconds"),
        front=[(p.seconds, p.error, f"{p.method} {p.spp}") for p in view.pareto],
        floor=floor,
        title=f"Error vs total time ({where}; mean seconds)",
    )
    speed: dict[str, tuple[list[float], list[float]]] = {}
    for label in result.labels:
        if label == NOISY:
            continue
        pts = [(o.spp, o.speedup) for o in rows if o.method == label and o.speedup]
        if pts:
            speed[label] = ([p[0] for p in pts], [p[1] for p in pts])
    plot_speedup(out / "images" / names[2], speed, title=f"Equal-quality speed-up ({where})")
    return names


def overall_sections(result: ExperimentResult, out: Path, reason: str | None) -> list[str]:
    """The sections over all scenes; with flagged scenes, each in two versions (all scenes,
    without the flagged ones) and a switch between them that needs no script: two radio
    inputs before the sections and CSS sibling selectors (see templates/experiment.html)."""
    views = [("all", result.view)]
    if result.without_flagged is not None:
        views.append(("unflagged", result.without_flagged))
    plots = {
        tag: _overall_plots(result, view, out, "overall" if tag == "all" else tag)
        if reason is None
        else []
        for tag, view in views
    }

    def scoped(render: Callable[[str, OverallView], str]) -> str:
        if len(views) == 1:
            return render(*views[0])
        return "".join(f'<div class="v-{tag}">{render(tag, view)}</div>' for tag, view in views)

    def figures(names: Sequence[str]) -> str:
        inner = "".join(f"<figure>{_img(n, n)}</figure>" for n in names)
        return f'<div class="plots">{inner}</div>' if names else ""

    switch = ""
    parts = []
    if len(views) > 1:
        flagged = ", ".join(result.flagged)
        n, k = len(result.scenes), len(views[1][1].scenes)
        parts.append(
            '<input type="radio" name="scope" id="scope-all" class="scope" checked>'
            '<input type="radio" name="scope" id="scope-unflagged" class="scope">'
        )
        switch = (
            '<p class="switch">Scenes: <label for="scope-all" class="to-all">all '
            f'{n}</label> <label for="scope-unflagged" class="to-unflagged">{k} without '
            f"flagged {_esc(flagged)}</label></p>"
        )
    parts.append(f'<h2 id="overall">All scenes</h2>{switch}')
    if reason is not None:
        parts.append(f'<p class="notes">No plots: {_esc(reason)}</p>')
    parts.append(scoped(lambda tag, v: figures(plots[tag][:2]) + _overall_error_table(result, v)))
    if "bias" in result.metrics:
        parts.append(
            "<h3>Mean bias over scenes</h3>" + switch + scoped(lambda t, v: _bias_table(result, v))
        )
    parts.append(f'<h2 id="equal-time">Equal time: the best choice for a time budget</h2>{switch}')
    budgets = "as given by the spec" if result.spec.budgets else "log-spaced over the times"
    if not result.render_time_known:
        parts.append(f'<p class="notes">Not computed: {_esc(UNKNOWN_TIME)}</p>')
    else:
        parts.append(
            scoped(
                lambda t, v: (
                    f'<p class="small">Over {len(v.scenes)} scene(s) (mean total seconds, '
                    f"geometric mean relMSE). Budgets: {budgets}.</p>"
                    + equal_time_table(v.equal_time)
                )
            )
        )
    parts.append(
        f'<h2 id="equal-quality">Equal quality: what plain rendering would need</h2>{switch}'
    )
    parts.append(scoped(lambda tag, v: figures(plots[tag][2:]) + _overall_eq_table(result, v)))
    parts.append(f'<h2 id="statistics">Statistics over scenes</h2>{switch}')
    parts.append(scoped(lambda t, v: _stats_table(result, v)))
    return parts


def _bias_table(result: ExperimentResult, view: OverallView) -> str:

    by = {(o.method, o.spp): o for o in view.rows}
    rows = []
    for label in result.labels:
        cells = []
        for spp in result.spps:
            o = by.get((label, spp))
            if o is None or o.bias is None:
                cells.append("<td>\u2013</td>")
                continue
            worst = max(abs(o.bias_min or 0.0), abs(o.bias_max or 0.0))
            cls = "num lim" if worst > BIAS_LIMIT else "num"
            span = _sub(f"{pct(o.bias_min or 0.0)} to {pct(o.bias_max or 0.0)}")
            cells.append(f'<td class="{cls}">{pct(o.bias)}{span}</td>')
        cls = ' class="noisy"' if label == NOISY else ""
        rows.append(f"<tr{cls}><td>{_esc(label)}</td>{''.join(cells)}</tr>")
    return (
        '<p class="small">Each cell: mean bias (output mean ÷ reference mean − 1; negative = '
        f"darker, energy lost), the mean over {len(view.scenes)} scene(s), and below it the "
        f"range over the scenes. Amber: some scene beyond ±{BIAS_LIMIT:.0%}. The noisy row "
        "shows how far plain rendering's mean wanders by noise alone.</p>"
        + _table(["method", *(f"{s} spp" for s in result.spps)], rows)
    )


def _overall_error_table(result: ExperimentResult, view: OverallView) -> str:
    spps = result.spps
    known = result.render_time_known
    rows = []
    by = {(o.method, o.spp): o for o in view.rows}
    for label in result.labels:
        cells = []
        for spp in spps:
            o = by.get((label, spp))
            if o is None or not o.complete:
                n = o.scenes if o else 0
                cells.append(
                    '<td class="num fail" title="failed or missing in some scenes">'
                    f"{n}/{len(view.scenes)} scenes</td>"
                )
                continue
            front = any(p.method == label and p.spp == spp for p in view.pareto)
            lim = _LIM_MARK if o.limited else ""
            time = _sec(o.seconds) if known else f"denoise {_sec(o.denoise_seconds)}"
            cells.append(
                f'<td class="num{" front" if front else ""}">{_g(o.relmse)}{lim}'
                f'<span class="sub">{time}</span></td>'
            )
        cls = ' class="noisy"' if label == NOISY else ""
        rows.append(f"<tr{cls}><td>{_esc(label)}</td>{''.join(cells)}</tr>")
    head = ["method", *(f"{s} spp" for s in spps)]
    return (
        '<p class="small">Each cell: relMSE (geometric mean over scenes) and, below, the mean '
        + (
            "total seconds (render + denoise). Green cells are on the Pareto front.</p>"
            if known
            else "denoise seconds (render time unknown: no total, no Pareto front).</p>"
        )
        + _table(head, rows)
    )


def equal_time_table(rows: Sequence[Any]) -> str:
    out = []
    for r in rows:
        if r.best is None:
            out.append(
                f'<tr><td class="num">{_sec(r.budget)}</td><td colspan="4">nothing fits</td></tr>'
            )
            continue
        ru = r.runner_up
        nz = r.noisy
        out.append(
            f'<tr><td class="num">{_sec(r.budget)}</td>'
            f"<td><b>{_esc(r.best.method)}</b> at {r.best.spp} spp"
            f'<span class="sub">relMSE {_g(r.best.error)}, {_sec(r.best.seconds)}</span></td>'
            + (
                f"<td>{_esc(ru.method)} at {ru.spp} spp{_sub(f'relMSE {_g(ru.error)}')}</td>"
                if ru
                else "<td>\u2013</td>"
            )
            + (f"<td>{nz.spp} spp{_sub(f'relMSE {_g(nz.error)}')}</td>" if nz else "<td>none</td>")
            + f'<td class="num">{_g(r.gain)}{"×" if r.gain else ""}</td></tr>'
        )
    return _table(
        [
            "time budget",
            "best choice",
            "best other method",
            "plain rendering",
            "error of plain ÷ best",
        ],
        out,
    )


def _overall_eq_table(result: ExperimentResult, view: OverallView) -> str:
    spps = result.spps
    by = {(o.method, o.spp): o for o in view.rows}
    rows = []
    for label in result.labels:
        if label == NOISY:
            continue
        cells = []
        for spp in spps:
            o = by.get((label, spp))
            if o is None or not o.complete or (o.speedup is None and o.eq_spp is None):
                cells.append("<td>\u2013</td>")
                continue
            dag = ""
            if o.extrapolated:
                dag = f'<span title="1/N law used in {o.extrapolated} scene(s)">†</span>'
            if o.speedup is None:  # render time unknown: the spp alone
                cells.append(f'<td class="num">{_g(o.eq_spp)} spp{dag}</td>')
                continue
            eq_spp = _sub(f"{_g(o.eq_spp)} spp")
            cells.append(f'<td class="num">{_g(o.speedup)}×{dag}{eq_spp}</td>')
        rows.append(f"<tr><td>{_esc(label)}</td>{''.join(cells)}</tr>")
    if not rows:
        return '<p class="notes">No denoiser in this run.</p>'
    what = (
        "speed-up at equal quality (seconds plain rendering needs for the method's error ÷ "
        "the method's total seconds) and, below, the spp plain rendering needs"
        if result.render_time_known
        else "the spp plain rendering needs for the method's error (render time unknown: no "
        "seconds, no speed-up)"
    )
    return (
        f'<p class="small">Each cell: {what}; geometric means over scenes. † = extrapolated '
        "beyond the measured ladder (1/N law) in some scene.</p>"
        + _table(["method", *(f"from {s} spp" for s in spps)], rows)
    )


def _stats_table(result: ExperimentResult, view: OverallView) -> str:
    spps = result.spps
    labels = [lb for lb in result.labels if lb != result.baseline]
    by = {(s.method, s.spp): s for s in view.stats}
    rows = []
    for label in labels:
        cells = []
        for spp in spps:
            s = by.get((label, spp))
            if s is None or s.ratio is None:
                cells.append(f"<td>{_esc(s.verdict if s else '')}</td>")
                continue
            cls = {BETTER: "better", WORSE: "worse"}.get(s.verdict, "unclear")
            beats = f"wins {s.wins}/{s.scenes}, beats {_esc(result.baseline)} in {s.beats_baseline}"
            cells.append(
                f'<td class="num"><span class="{cls}">{_g(s.ratio)}</span>'
                + _sub(f"[{_g(s.ci_low)}, {_g(s.ci_high)}]")
                + _sub(_esc(s.verdict))
                + _sub(beats)
                + "</td>"
            )
        rows.append(f"<tr><td>{_esc(label)}</td>{''.join(cells)}</tr>")
    conf = f"{result.spec.confidence:.0%}"
    intro = (
        f'<p class="small">Each cell: relMSE ÷ relMSE of <b>{_esc(result.baseline)}</b> '
        f"(geometric mean over scenes; below 1 = lower error), its {conf} bootstrap interval "
        f"over scenes ({result.spec.bootstrap} resamples, seed {result.spec.stats_seed}), the "
        "verdict, in how many scenes the method has the lowest error of all methods (wins) and "
        f"in how many it beats the baseline. {len(view.scenes)} scene(s): with few scenes "
        "the intervals are wide, as they should be.</p>"
    )
    base_rows = [s for s in view.stats if s.verdict == IS_BASELINE]
    wins = ", ".join(f"{s.spp} spp: {s.wins}" for s in base_rows)
    tail = (
        f'<p class="small">Wins of the baseline {_esc(result.baseline)}: {_esc(wins)}.</p>'
        if wins
        else ""
    )
    return intro + _table(["method", *(f"{s} spp" for s in spps)], rows) + tail
