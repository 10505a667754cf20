"""The experiment report's headlines: short sentences that never claim more than the
statistics over scenes allow.

A headline that names a "lowest" or "most accurate" method also says which other methods it
cannot be told apart from: the ratio of the two methods' relMSE over the scenes, with its
bootstrap interval (:func:`~mcdenoise.experiments.stats.bootstrap_geomean_ci`); an interval
that contains 1 is *no clear difference* — tied within the interval — never a win. Ratios to the
statistics baseline are quoted from the statistics table, so the page agrees with itself.

Also: scenes flagged for a rising noisy curve (fireflies) and the same headline without them,
and every method whose mean bias (output mean / reference mean − 1) exceeds
:data:`BIAS_LIMIT` in magnitude, with the noisy input's bias at the same place for scale.
"""

from __future__ import annotations

import html
import math
import zlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from mcdenoise.experiments.analysis import ExperimentResult, OverallRow, OverallView, errors_by_key
from mcdenoise.experiments.quality import FLOOR_FACTOR
from mcdenoise.experiments.record_values import bias_of
from mcdenoise.experiments.spec_fields import NOISY
from mcdenoise.experiments.stats import BETTER, bootstrap_geomean_ci

#: A method whose mean bias exceeds this magnitude (2 %) in some result is named.
BIAS_LIMIT = 0.02


def _esc(text: Any) -> str:
    return html.escape(str(text), quote=True)


def _g(v: float | None) -> str:
    if v is None:
        return "\u2013"
    if v != 0 and (abs(v) < 1e-3 or abs(v) >= 1e5):
        return f"{v:.2e}"
    return f"{v:.3g}"


def pct(v: float) -> str:
    """A signed fraction as a percentage with a true minus sign: ``-0.039`` -> ``−3.9 %``."""
    return f"{100.0 * v:+.2g} %".replace("-", "\u2212")


def paired_ratio(
    errors: Mapping[tuple[str, int, str], float],
    scenes: Sequence[str],
    a: tuple[str, int],
    b: tuple[str, int],
    *,
    resamples: int,
    confidence: float,
    seed: int,
) -> tuple[float, float, float, int] | None:
    """Geometric-mean ratio over ``scenes`` of relMSE(``a``) / relMSE(``b``) for two
    (method, spp), its bootstrap interval and the number of scenes; ``None`` without a common
    scene. Seeded by (seed, a, b)."""
    ratios = []
    for s in scenes:
        ea, eb = errors.get((s, a[1], a[0])), errors.get((s, b[1], b[0]))
        if ea is not None and eb is not None and ea > 0 and eb > 0:
            ratios.append(ea / eb)
    if not ratios:
        return None
    key = [seed, zlib.crc32(f"{a[0]}@{a[1]}".encode()), zlib.crc32(f"{b[0]}@{b[1]}".encode())]
    point, lo, hi = bootstrap_geomean_ci(
        ratios, resamples=resamples, confidence=confidence, rng=np.random.default_rng(key)
    )
    return point, lo, hi, len(ratios)


def _where(result: ExperimentResult, view: OverallView) -> str:
    n = len(view.scenes)
    if n == len(result.scenes):
        return f"over the {n} scene{'s' if n != 1 else ''}"
    left = [s for s in result.scenes if s.id not in view.scenes]
    return f"over the {n} scene{'s' if n != 1 else ''} without {', '.join(s.id for s in left)}"


def _ratio_text(a: str, b: str, r: float, lo: float, hi: float, conf: str) -> str:
    return f"{_esc(a)} \u00f7 {_esc(b)} {_g(r)}, {conf} interval {_g(lo)}\u2013{_g(hi)}"


def _versus(
    result: ExperimentResult, view: OverallView, best: tuple[str, int], other: tuple[str, int]
) -> tuple[str, bool] | None:
    """(text of the ratio of ``best`` to ``other``, whether the interval contains 1). Against
    the baseline at the same spp the statistics table's row is quoted."""
    spec = result.spec
    conf = f"{spec.confidence:.0%}"
    if best[1] == other[1] and result.baseline in (best[0], other[0]):
        method = other[0] if best[0] == result.baseline else best[0]
        row = next((s for s in view.stats if s.method == method and s.spp == best[1]), None)
        if row is None or row.ratio is None or row.ci_low is None or row.ci_high is None:
            return None
        tied = row.ci_low <= 1.0 <= row.ci_high
        text = _ratio_text(method, result.baseline, row.ratio, row.ci_low, row.ci_high, conf)
        return text + ", as in the statistics table", tied
    got = paired_ratio(
        errors_by_key(result.records),
        view.scenes,
        best,
        other,
        resamples=spec.bootstrap,
        confidence=spec.confidence,
        seed=spec.stats_seed,
    )
    if got is None:
        return None
    r, lo, hi, _ = got
    names = (f"{best[0]} {best[1]} spp", f"{other[0]} {other[1]} spp")
    if best[1] == other[1]:
        names = (best[0], other[0])
    return _ratio_text(*names, r, lo, hi, conf), lo <= 1.0 <= hi


def lowest_at(result: ExperimentResult, view: OverallView, spp: int) -> str | None:
    """Which method has the lowest error at ``spp`` over the view's scenes, and which ones
    it is tied with (interval containing 1)."""
    rows = [o for o in view.rows if o.spp == spp and o.complete and o.relmse]
    if not rows:
        return None
    best: OverallRow = min(rows, key=lambda o: o.relmse or math.inf)
    noisy = next((o for o in rows if o.method == NOISY), None)
    gain = (
        f", {noisy.relmse / best.relmse:.3g}× lower than plain rendering"
        if noisy and noisy.relmse and best.relmse and best.method != NOISY
        else ""
    )
    where = _where(result, view)
    head = f"relMSE {_g(best.relmse)} {where}{gain}"
    if len(view.scenes) == 1:
        return (
            f"At {spp} spp the lowest error is <b>{_esc(best.method)}</b> ({head}); one scene "
            "gives no interval, so this may not hold on other scenes."
        )
    ties: list[tuple[float, str, str]] = []  # (|log ratio|, method, ratio text)
    clear = 0
    for o in rows:
        if o is best:
            continue
        got = _versus(result, view, (best.method, spp), (o.method, spp))
        if got is None:
            continue
        text, tied = got
        if tied:
            closeness = abs(math.log((o.relmse or math.inf) / (best.relmse or math.inf)))
            ties.append((closeness, o.method, text))
        else:
            clear += 1
    if not ties:
        return (
            f"At {spp} spp the lowest error is <b>{_esc(best.method)}</b> ({head}), clearly "
            f"below each of the {clear} other methods (every ratio's "
            f"{result.spec.confidence:.0%} interval below 1)."
        )
    ties.sort()
    _, name, text = ties[0]
    more = f" and {len(ties) - 1} more" if len(ties) > 1 else ""
    return (
        f"At {spp} spp <b>{_esc(best.method)}</b> has the lowest mean error ({head}), but it is "
        f"<b>tied within the interval</b> (no clear difference) with {_esc(name)} ({text})"
        f"{more}: no single method is lowest at {spp} spp on these scenes."
    )


def _budget(result: ExperimentResult, view: OverallView) -> str | None:
    if not view.equal_time:
        return None
    last = view.equal_time[-1]
    if last.best is None:
        return None
    b = last.best
    text = (
        f"With the largest budget ({last.budget:.3g} s), the most accurate choice is "
        f"<b>{_esc(b.method)}</b> at {b.spp} spp"
    )
    ru = last.runner_up
    if ru is None or len(view.scenes) < 2:
        return text + "."
    got = _versus(result, view, (b.method, b.spp), (ru.method, ru.spp))
    if got is None:
        return text + "."
    ratio, tied = got
    if tied:
        return (
            text + f", tied within the interval with {_esc(ru.method)} at {ru.spp} spp "
            f"({ratio}): no clear difference."
        )
    return text + f", clearly ahead of the best other method ({ratio})."


def _speedup(view: OverallView) -> str | None:
    speed = [(o.speedup, o) for o in view.rows if o.complete and o.speedup and o.method != NOISY]
    if not speed:
        return None
    s, o = max(speed, key=lambda t: t[0])
    flag = " (extrapolated beyond the ladder in some scenes)" if o.extrapolated else ""
    return (
        f"Largest equal-quality speed-up (geometric mean over scenes): <b>{_esc(o.method)}</b> "
        f"from {o.spp} spp: plain rendering would need {_g(o.eq_spp)} spp for the same error, "
        f"{_g(s)}× the time{flag}."
    )


def _worst(result: ExperimentResult, over: Sequence[tuple[float, Mapping[str, Any]]]) -> str:
    """The largest |bias| of ``over`` as text, with the noisy input's bias at the same place."""
    b, r = max(over, key=lambda t: abs(t[0]))
    noisy = result.record(r["scene"], r["spp"], NOISY)
    nb = bias_of(noisy) if noisy else None
    ref = f"; the noisy input there {pct(nb)}" if nb is not None else ""
    return f"{pct(b)} ({_esc(r['scene'])}, {r['spp']} spp{ref})"


#: At most this many headline bullets: the detail lives in the tables below them.
MAX_HEADLINES = 5


def bias_lines(result: ExperimentResult) -> list[str]:
    """One line: the methods whose |mean bias| exceeds :data:`BIAS_LIMIT` somewhere (the
    one with the largest named, with its worst case and the noisy input's bias there, the
    rest counted), or one saying none does; ``[]`` without the bias metric."""
    if "bias" not in result.metrics:
        return []
    found: list[tuple[float, str]] = []
    for label in result.labels:
        if label == NOISY:
            continue
        over = [
            (b, r)
            for r in result.records
            if r["method"] == label and (b := bias_of(r)) is not None and abs(b) > BIAS_LIMIT
        ]
        if over:
            worst = max(abs(b) for b, _ in over)
            found.append((worst, f"<b>{_esc(label)}</b> (worst {_worst(result, over)})"))
    limit = f"{BIAS_LIMIT:.0%}"
    if not found:
        return [
            f"Every method keeps the image's energy: mean bias (output mean ÷ reference mean − "
            f"1) within ±{limit} in every scene and at every spp."
        ]
    found.sort(key=lambda t: -t[0])
    others = f" and {len(found) - 1} more method(s)" if len(found) > 1 else ""
    return [
        f'<span class="lim">Mean bias beyond ±{limit}</span> (output mean ÷ reference mean − '
        f"1) in {found[0][1]}{others}: see the mean-bias table."
    ]


def _cautions(result: ExperimentResult) -> str | None:
    """Where the numbers need care, in one item: results at the reference's noise floor,
    scenes flagged for a rising noisy curve, methods that lose or add energy."""
    parts = []
    limited = [r for r in result.records if r.get("limited_by_reference")]
    if limited:
        parts.append(
            f'<span class="lim">{len(limited)} result(s) within {FLOOR_FACTOR:g}× of the '
            "reference's noise floor</span> (≈: the reference limits what can be measured)"
        )
    flagged = [s for s in result.scenes if s.flagged]
    if flagged:
        parts.append(
            '<span class="lim">Flagged: the noisy error rises with more samples</span> in '
            + ", ".join(f"<b>{_esc(s.id)}</b>" for s in flagged)
            + " (fireflies; the means include "
            + ("it" if len(flagged) == 1 else "them")
            + (
                ", the switch above the overall section leaves them out)"
                if result.without_flagged is not None
                else ")"
            )
        )
    bias = bias_lines(result)
    if bias and "beyond" in bias[0]:
        parts.append(bias[0].rstrip("."))
    return "; ".join(parts) + "." if parts else None


def headlines(result: ExperimentResult) -> list[str]:
    """The headline items (HTML) of the report, in order, at most :data:`MAX_HEADLINES`, each
    one sentence with its number (and interval where there is one)."""
    items: list[str] = []
    view = result.view
    strip = result.strip_spp
    for text in (lowest_at(result, view, strip), _speedup(view), _budget(result, view)):
        if text:
            items.append(text)
    better = [s for s in result.stats if s.verdict == BETTER and s.spp == strip]
    if better and result.baseline != NOISY:
        best = min(better, key=lambda s: s.ratio or math.inf)
        conf = f"{result.spec.confidence:.0%}"
        items.append(
            f"Clearly better than {_esc(result.baseline)} at {strip} spp (whole {conf} interval "
            f"below 1): {_esc(', '.join(s.method for s in better))}; the lowest ratio "
            + _ratio_text(
                best.method,
                result.baseline,
                best.ratio or math.nan,
                best.ci_low or math.nan,
                best.ci_high or math.nan,
                conf,
            )
            + "."
        )
    caution = _cautions(result)
    if caution:
        items.append(caution)
    else:
        items += bias_lines(result)
    return items[:MAX_HEADLINES]
