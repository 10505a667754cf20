"""Write an experiment: ``results.json``, ``results.csv``, ``report.html`` and its PNGs.

The page is for a reader new to the field. It opens with how to read it and the headline
findings, then the answers over all scenes — error against spp (with the ``1/N`` line and
the reference's noise floor), error against total time with the Pareto front, the
equal-time table, the equal-quality speed-ups and the statistics over scenes — then one
section per scene (its curves, tables and an image strip: noisy input, every method and the
reference through the same crop and tonemap, each with its per-pixel relMSE map), and ends
with the definitions and the provenance (versions, git commit, machine, data hash, seeds).

Like :mod:`mcdenoise.eval.eval_report` the page needs no network: inline CSS, PNGs in
``images/`` referenced by relative paths. Only the interactive image viewer under each scene
(:mod:`~mcdenoise.experiments.viewer`: ``viewer/viewer.js`` and the scenes' pixel files) uses
JavaScript; everything else, the static image strips included, is plain HTML. Every file is written atomically; PNGs of
an earlier report that the new page does not show are removed.
"""

from __future__ import annotations

import html
import math
import os
import re
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from string import Template
from typing import Any

import numpy as np

from mcdenoise.errors import McdenoiseError
from mcdenoise.eval.eval_report import error_scale, percent, write_png
from mcdenoise.eval.metrics import relmse_map
from mcdenoise.eval.preview import choose_crop, crop
from mcdenoise.eval.temporal_metrics import metric_spec
from mcdenoise.eval.tonemap import auto_exposure, colorbar, display, false_color
from mcdenoise.experiments.analysis import ExperimentResult, SceneSummary
from mcdenoise.experiments.dataset import read_level, read_reference
from mcdenoise.experiments.definitions import SEQUENCE_DEFINITIONS, definitions
from mcdenoise.experiments.headlines import headlines
from mcdenoise.experiments.htmlkit import LIM_MARK as _LIM_MARK
from mcdenoise.experiments.htmlkit import esc as _esc
from mcdenoise.experiments.htmlkit import g as _g
from mcdenoise.experiments.htmlkit import img as _img
from mcdenoise.experiments.htmlkit import sec as _sec
from mcdenoise.experiments.htmlkit import slug as _slug
from mcdenoise.experiments.htmlkit import sub as _sub
from mcdenoise.experiments.htmlkit import table as _table
from mcdenoise.experiments.overall_report import equal_time_table, overall_sections, plot_series
from mcdenoise.experiments.plots import plot_error_vs_spp, plot_error_vs_time, plots_unavailable
from mcdenoise.experiments.quality import FLOOR_FACTOR
from mcdenoise.experiments.record_values import number, relmse_of
from mcdenoise.experiments.report_tables import (
    PROCESS_NOTE,
    _process_mark,
    _process_methods,
    _process_methods_note,
    write_csv,
    write_frames_csv,
    write_json,
)
from mcdenoise.experiments.spec_fields import NOISY
from mcdenoise.experiments.temporal_report import scene_images, scene_table, temporal_section
from mcdenoise.experiments.viewer import viewer_section
from mcdenoise.io import load_buffers
from mcdenoise.io.atomic import write_text_atomic

#: Names of the PNGs this module writes (pruned when no longer shown).
_OWN_IMAGE = re.compile(r"^(plot|strip)_[A-Za-z0-9._-]+\.(png|gif)$")
_MAX_ZOOM = 8

HOW_TO_READ = (
    "<p>A Monte Carlo renderer gets more accurate the longer it runs: its error (relMSE, "
    "lower is better) falls as 1/N with the number N of samples per pixel (spp). A denoiser "
    "spends a little extra time to remove much of that error. This report measures, on the "
    "same scenes, <b>what each level of accuracy costs in seconds</b>, with and without each "
    "denoiser.</p>"
    "<p><b>Error vs spp</b>: one line per method; the dashed black line is plain rendering "
    "(<i>noisy</i>), the dotted grey line the 1/N law fitted to it. <b>Error vs time</b>: the "
    "same points against the total time (render + denoise); the thick grey step line is the "
    "<b>Pareto front</b>: the only choices for which nothing else is both faster and more "
    "accurate. <b>Equal time</b>: for a time budget, the most accurate choice that fits. "
    "<b>Equal quality</b>: how many spp (and seconds) plain rendering would need to reach a "
    "method's error, and the resulting speed-up (×); † marks values extrapolated with the 1/N "
    "law beyond the measured spp ladder.</p>"
    "<p>The reference is itself a finite render: its own expected error, the <b>noise "
    "floor</b>, is drawn as a dotted horizontal line. Errors within "
    f"{FLOOR_FACTOR:g}× of it (shaded band, marked ≈) measure the reference as much as the "
    "method, so no method is credited with beating the reference. With several scenes, "
    "ratios to a baseline come with a bootstrap confidence interval over scenes: a "
    "difference whose interval contains 1 is reported as no clear difference.</p>"
    "<p><b>Mean bias</b>: the output's mean over the reference's mean − 1 (−3 % = 3 % darker: "
    "energy lost); the noisy row shows how far plain rendering's mean wanders by noise alone. "
    "A scene whose plain-rendering error <b>rises</b> with more samples is <b>flagged</b>: a few "
    "fireflies dominate its error, and the sections over all scenes can be switched to the "
    "scenes without it.</p>"
)


def write_experiment_report(
    result: ExperimentResult, out_dir: str | os.PathLike[str]
) -> dict[str, Path]:
    """Write ``results.json``, ``results.csv``, ``report.html`` and ``images/*.png``.

    Returns:
        ``{"json": ..., "csv": ..., "html": ..., "images": <folder>}``.

    Raises:
        McdenoiseError: a file cannot be written.
    """
    out = Path(out_dir)
    paths = {
        "json": out / "results.json",
        "csv": out / "results.csv",
        "html": out / "report.html",
        "images": out / "images",
    }
    try:
        paths["images"].mkdir(parents=True, exist_ok=True)
        write_json(result, paths["json"])
        write_csv(result, paths["csv"])
        if result.is_sequences:
            paths["frames_csv"] = out / "frames.csv"
            write_frames_csv(result, paths["frames_csv"])
        page = render_html(result, out)
        write_text_atomic(paths["html"], page)
        shown = {html.unescape(n) for n in re.findall(r'src="images/([^"/]+)"', page)}
        for f in paths["images"].iterdir():
            if f.is_file() and _OWN_IMAGE.match(f.name) and f.name not in shown:
                f.unlink()
    except OSError as err:
        raise McdenoiseError(f"cannot write the report in {out}: {err}") from None
    return paths


# --- JSON and CSV -------------------------------------------------------------------------


# --- plots --------------------------------------------------------------------------------


def _scene_plots(result: ExperimentResult, scene: SceneSummary, index: int, out: Path) -> list[str]:

    recs = result.scene_records(scene.id)
    tag = f"{index:02d}_{_slug(scene.id)}"
    spp_name, time_name = f"plot_{tag}_error_spp.png", f"plot_{tag}_error_time.png"
    c = scene.curve
    plot_error_vs_spp(
        out / "images" / spp_name,
        plot_series(result, recs, "spp"),
        one_over_n=c.one_over_n() if c is not None else None,
        floor=scene.noise_floor,
        title=f"{scene.id}: error vs samples per pixel",
    )
    if not result.render_time_known:
        return [spp_name]
    plot_error_vs_time(
        out / "images" / time_name,
        plot_series(result, recs, "total_seconds"),
        front=[(p.seconds, p.error, f"{p.method} {p.spp}") for p in scene.pareto],
        floor=scene.noise_floor,
        title=f"{scene.id}: error vs total time (render + denoise)",
    )
    return [spp_name, time_name]


# --- sections -----------------------------------------------------------------------------


def _run_table(result: ExperimentResult) -> str:
    spec, prov = result.spec, result.provenance
    machine = prov.get("machine", {})
    first = result.scenes[0] if result.scenes else None
    ladder = ", ".join(str(v.spp) for v in first.levels) if first else ""
    ref_spp = first.reference_spp if first else ""
    folder = Path(first.noisy_file).parent if first else ""
    skipped = "; ".join(f"{k} ({v})" for k, v in result.skipped.items())
    data_hash = str(prov.get("data_hash", ""))[:16]
    rows = [
        ("Scenes", f"{len(result.scenes)}: {_esc(', '.join(s.id for s in result.scenes))}"),
        *(
            [
                (
                    "Sequences",
                    f"{_esc(', '.join(sorted({str(len(s.frames)) for s in result.scenes})))} "
                    f"frames each; the first {result.spec.warmup_frames} reported apart "
                    "(warm-up); times and errors are per frame",
                )
            ]
            if result.is_sequences
            else []
        ),
        (
            "spp ladder",
            f"{_esc(ladder)} "
            + (
                "(progressive: each level reuses the samples of the lower ones); "
                if result.render_time_known
                else "(read from the files: a folder without manifest); "
            )
            + f"reference {_esc(ref_spp)} spp",
        ),
        ("Data", f"render folder {_esc(folder)}, data hash <code>{_esc(data_hash)}</code>…"),
        (
            "Methods",
            _esc(", ".join(result.labels))
            + (f'<br><span class="small">skipped: {_esc(skipped)}</span>' if skipped else "")
            + "".join(
                f'<br><span class="small">not run: {_esc(line)}</span>'
                for line in result.not_applicable
            ),
        ),
        (
            "Timing",
            f"median of {spec.repetitions} timed run(s) after {spec.warmup} warm-up run(s) per "
            f"input; device {_esc(spec.device)}, torch threads "
            f"{_esc(_threads(result))} (libraries outside torch use their own thread pools); "
            f"{_esc(machine.get('cpu', ''))}, "
            f"{_esc(machine.get('cpu_count', ''))} CPU(s), load average at the end "
            f"{_esc(machine.get('load_average', 'unknown'))}"
            + (f"<br>{_esc(_process_methods_note(result))}" if _process_methods(result) else ""),
        ),
        (
            "Version",
            f"mcdenoise {_esc(prov.get('mcdenoise_version'))}, git commit "
            f"<code>{_esc(str(prov.get('git_commit'))[:12])}</code>",
        ),
    ]
    body = "".join(f"<tr><th>{k}</th><td>{v}</td></tr>" for k, v in rows)
    return f'<table class="meta">{body}</table>'


def _threads(result: ExperimentResult) -> str:
    seen = sorted({r.get("threads") for r in result.records if r.get("threads") is not None})
    return ", ".join(map(str, seen)) or "n/a"


def _findings(result: ExperimentResult) -> str:

    items = headlines(result)
    if not items:
        return ""
    return (
        '<div class="findings"><b>Headlines</b><ul>'
        + "".join(f"<li>{i}</li>" for i in items)
        + "</ul></div>"
    )


def _scene_table(result: ExperimentResult, scene: SceneSummary) -> str:
    recs = result.scene_records(scene.id)
    spps = sorted({r["spp"] for r in recs})
    by = {(r["method"], r["spp"]): r for r in recs}
    rows = []
    for label in result.labels:
        cells = []
        for spp in spps:
            r = by.get((label, spp))
            if r is None:
                cells.append("<td>\u2013</td>")
                continue
            if r.get("failed"):
                why = str(r.get("error") or r.get("reason") or "")
                head = "could not run" if r.get("error") else "FAILED"
                short = why if len(why) <= 60 else why[:59] + "…"
                cells.append(f'<td class="fail" title="{_esc(why)}">{head}{_sub(_esc(short))}</td>')
                continue
            lim = _LIM_MARK if r.get("limited_by_reference") else ""
            eq = r.get("equal_quality") or {}
            eq_text = ""
            if eq:
                dag = "†" if eq.get("extrapolated") else ""
                speed = f", {_g(eq.get('speedup'))}×" if eq.get("speedup") is not None else ""
                eq_text = _sub(f"= {_g(eq.get('spp'))} spp plain{speed}{dag}")
            times = f"{_sec(r.get('render_seconds'))} + {_sec(r.get('denoise_seconds'))}"
            times += _process_mark(r)
            cls = "num front" if r.get("pareto") else "num"
            error = _g((r.get("metrics") or {}).get("relmse"))
            cells.append(f'<td class="{cls}">{error}{lim}{_sub(times)}{eq_text}</td>')
        cls = ' class="noisy"' if label == NOISY else ""
        rows.append(f"<tr{cls}><td>{_esc(label)}</td>{''.join(cells)}</tr>")
    return (
        '<p class="small">Each cell: relMSE; render + denoise seconds; for denoisers, the spp '
        "plain rendering needs for the same error and the speed-up (× its time; † "
        "extrapolated). "
        "Green: on this scene's Pareto front. ≈: within 2× of the reference's noise floor."
        + (f" {PROCESS_NOTE}" if any(_process_mark(r) for r in recs) else "")
        + "</p>"
        + _table(["method", *(f"{s} spp" for s in spps)], rows)
    )


def _metric(name: str, value: Any) -> str:
    """A metric value for a table: signed ones (mean bias) in percent."""
    v = number(value)
    if v is not None and math.isfinite(v) and metric_spec(name).signed:
        return percent(v)
    return _g(value, 4)


def _all_metrics_table(result: ExperimentResult, scene: SceneSummary) -> str:
    shown = [
        m
        for m in result.metrics
        if any((r.get("metrics") or {}).get(m) is not None for r in result.scene_records(scene.id))
    ]
    rows = []
    # times from several machines (shards): each timed row names its host
    hosts = len(result.provenance.get("timing_hosts") or {}) > 1
    for r in sorted(
        result.scene_records(scene.id), key=lambda r: (result.labels.index(r["method"]), r["spp"])
    ):
        if r.get("failed"):
            cells = f'<td class="fail" colspan="{len(shown)}">FAILED: {_esc(r.get("reason"))}</td>'
        else:
            cells = "".join(
                f'<td class="num">{_metric(m, (r.get("metrics") or {}).get(m))}</td>' for m in shown
            )
        runs = ", ".join(_g(v) for v in (r.get("timing") or {}).get("runs", []))
        rows.append(
            f'<tr><td>{_esc(r["method"])}</td><td class="num">{r["spp"]}</td>{cells}'
            f'<td class="num">{_g(r.get("render_seconds"))}</td>'
            f'<td class="num">{_g(r.get("denoise_seconds"))}{_process_mark(r)}'
            f"{_sub(_esc(runs))}</td>"
            f"<td>{_esc(r.get('device') or '')}"
            + (_sub(_esc(r.get("host") or "unknown")) if hosts and r.get("timing") else "")
            + "</td></tr>"
        )
    head = [
        "method",
        "spp",
        *(_esc(metric_spec(m).label) for m in shown),
        "render s",
        "denoise s (runs)",
        "device, host" if hosts else "device",
    ]
    summary = f"<summary>All metrics and timings of {_esc(scene.id)}</summary>"
    note = (
        f'<p class="small">{PROCESS_NOTE}</p>'
        if any(_process_mark(r) for r in result.scene_records(scene.id))
        else ""
    )
    return f"<details>{summary}{_table(head, rows)}{note}</details>"


def _strip(result: ExperimentResult, scene: SceneSummary, index: int, out: Path) -> str:

    spp = result.strip_spp
    ref_full = read_reference(scene.reference_file)["color"].numpy().astype(np.float64)
    exposure = auto_exposure(ref_full)
    window = choose_crop(ref_full, exposure)
    ref = crop(ref_full, window).astype(np.float64)
    _, h, w = ref.shape
    zoom = max(1, min(_MAX_ZOOM, 256 // max(h, w)))
    size = f' width="{w * zoom}" height="{h * zoom}"'
    images: list[tuple[str, np.ndarray | None, Mapping[str, Any]]] = []
    for label in result.labels:
        r = result.record(scene.id, spp, label)
        if r is None:
            continue
        if label == NOISY:
            level = next(lv for lv in scene.levels if lv.spp == spp)
            img = read_level(scene.noisy_file, level)["color"].numpy()
        elif r.get("output"):
            p = Path(r["output"])
            p = p if p.is_absolute() else out / p
            img = load_buffers(p)["color"].numpy() if p.is_file() else None
        else:
            img = None
        images.append((label, None if img is None else crop(img, window), r))
    maps = {lb: relmse_map(im, ref) for lb, im, _ in images if im is not None}
    lo, hi = error_scale(list(maps.values())) if maps else (1e-6, 1e-2)
    tag = f"strip_{index:02d}_{_slug(scene.id)}"
    figures = []
    missing = []
    for i, (label, im, r) in enumerate(images):
        if im is None:
            why = str(r.get("error") or "output not kept")
            missing.append(f"{label} ({why if len(why) <= 120 else why[:119] + '…'})")
            continue
        name, err_name = (
            f"{tag}_{i:02d}_{_slug(label)}.png",
            f"{tag}_{i:02d}_{_slug(label)}_err.png",
        )
        write_png(out / "images" / name, display(im, exposure))
        write_png(out / "images" / err_name, false_color(maps[label], lo, hi))
        e = relmse_of(r)
        detail = (
            f"FAILED: {r.get('reason')}"
            if r.get("failed")
            else f"relMSE {_g(e)}, {_sec(r.get('total_seconds'))}{_process_mark(r)}"
        )
        cls = ' class="failed"' if r.get("failed") else ""
        figures.append(
            f"<figure{cls}>{_img(name, label, size)}"
            f"{_img(err_name, f'per-pixel relMSE of {label}', size)}"
            f"<figcaption><b>{_esc(label)}</b>, {spp} spp<br>{_esc(detail)}</figcaption></figure>"
        )
    ref_name, bar_name = f"{tag}_reference.png", f"{tag}_colorbar.png"
    write_png(out / "images" / ref_name, display(ref, exposure))
    write_png(out / "images" / bar_name, colorbar(w * zoom, 12))
    ticks = "".join(
        f"<span>{10.0**e:.0e}</span>"
        for e in range(round(math.log10(lo)), round(math.log10(hi)) + 1)
    )
    bar = _img(bar_name, "colour scale", f' width="{w * zoom}" height="12"')
    figures.append(
        f"<figure>{_img(ref_name, 'reference', size)}"
        f'<div class="legend" style="width:{w * zoom}px">per-pixel relMSE (log scale)<br>'
        f'{bar}<div class="ticks">{ticks}</div></div>'
        f"<figcaption><b>reference</b>, {_esc(scene.reference_spp)} spp</figcaption></figure>"
    )
    y0, x0, ch, cw = window
    full_h, full_w = ref_full.shape[1:]
    if (ch, cw) == (full_h, full_w):
        where = f"the whole {full_w}×{full_h} image"
        where += f", magnified {zoom}×" if zoom > 1 else ""
    else:
        where = f"the crop x {x0}–{x0 + cw - 1}, y {y0}–{y0 + ch - 1}"
        where += f" of the {full_w}×{full_h} image"
    return (
        f'<p class="small">Images at {spp} spp show {_esc(where)}. Same tonemap for all: exposure '
        f"×{exposure:.3g} ({math.log2(exposure):+.2f} EV, chosen from the reference), clamped "
        f"to [0, 1], sRGB. Under each image its per-pixel relMSE on one log scale from "
        f'{lo:.0e} to {hi:.0e} (dark = small error).</p><div class="strip">{"".join(figures)}</div>'
        + (f'<p class="notes">Not shown: {_esc("; ".join(missing))}</p>' if missing else "")
    )


def _scene_section(
    result: ExperimentResult, scene: SceneSummary, index: int, out: Path, plots_ok: bool
) -> str:
    c = scene.curve
    facts = [
        (f"sequence of {len(scene.frames)} frames, " if scene.is_sequence else "")
        + f"reference {_esc(scene.reference_spp)} spp, seed {_esc(scene.seed)}, "
        f"{_esc(scene.variant)}",
        (
            f"reference noise floor {_g(scene.noise_floor)} (expected relMSE of the reference "
            "itself)"
            if scene.noise_floor is not None
            else _esc(scene.floor_note or "noise floor unknown")
        ),
    ]
    if c is not None:
        slope = c.slope()
        facts.append(
            f"noisy curve slope {_g(slope)} in log-log (Monte Carlo: −1)"
            if slope is not None
            else "one level: no slope"
        )
        facts.append(
            f"plain rendering costs {_g(c.seconds_per_spp)} s per spp (at {c.spp[-1]} spp, JIT "
            "excluded)"
            if math.isfinite(c.seconds_per_spp)
            else "render time unknown"
        )
    parts = [
        f'<h2 id="scene-{_esc(_slug(scene.id))}">Scene: {_esc(scene.id)}</h2>',
        f'<p class="small">{"; ".join(facts)}.</p>',
    ]
    if scene.flag_reason:
        parts.append(f'<div class="warn"><b>Flagged.</b> {_esc(scene.flag_reason)}</div>')
    if plots_ok:
        names = _scene_plots(result, scene, index, out)
        parts.append(
            '<div class="plots">'
            + "".join(f"<figure>{_img(n, n)}</figure>" for n in names)
            + "</div>"
        )
    parts.append(_scene_table(result, scene))
    if result.render_time_known:
        summary = f"<summary>Equal-time table of {_esc(scene.id)}</summary>"
        parts.append(f"<details>{summary}{equal_time_table(scene.equal_time)}</details>")
    parts.append(_all_metrics_table(result, scene))
    if scene.is_sequence:
        parts.append(f"<h3>Per frame and over time: {_esc(scene.id)}</h3>")
        parts.append(scene_table(result, scene))
        parts.append(scene_images(result, scene, index, out))
    else:
        parts.append(f"<h3>Images at {result.strip_spp} spp</h3>")
        parts.append(_strip(result, scene, index, out))
    parts.append(viewer_section(result, scene, index, out))
    return "".join(parts)


def _provenance(result: ExperimentResult) -> str:
    prov = result.provenance
    pk = prov.get("packages", {})
    machine = prov.get("machine", {})
    rows = [
        ("mcdenoise", prov.get("mcdenoise_version")),
        ("git commit", prov.get("git_commit")),
        (
            "packages",
            ", ".join(f"{k} {v}" for k, v in pk.items() if v)
            + (
                " (not installed: " + ", ".join(k for k, v in pk.items() if not v) + ")"
                if any(not v for v in pk.values())
                else ""
            ),
        ),
        ("machine", ", ".join(f"{k}: {v}" for k, v in machine.items())),
        ("data folder", prov.get("data_folder")),
        ("data hash", f"{prov.get('data_hash')} ({prov.get('data_hash_method')})"),
        (
            "render seeds",
            f"base seed {result.spec.seed}; per image: "
            + ", ".join(f"{s.id} {s.seed}" for s in result.scenes),
        ),
        (
            "statistics seed",
            f"{result.spec.stats_seed} ({result.spec.bootstrap} bootstrap resamples)",
        ),
        ("spec", result.spec.source),
    ]
    body = "".join(f"<tr><th>{_esc(k)}</th><td>{_esc(v)}</td></tr>" for k, v in rows)

    every = {
        **definitions(result.metrics),
        **(SEQUENCE_DEFINITIONS if result.is_sequences else {}),
    }
    defs = "".join(f"<tr><th>{_esc(k)}</th><td>{_esc(v)}</td></tr>" for k, v in every.items())
    metric_rows = "".join(
        f"<tr><th>{_esc(metric_spec(m).label)}</th>"
        f"<td>{_esc(metric_spec(m).definition)}; {_esc(metric_spec(m).space)}</td></tr>"
        for m in result.metrics
    )
    return (
        '<h2 id="definitions">Definitions</h2><table class="meta">'
        + defs
        + metric_rows
        + "</table>"
        '<h2 id="provenance">Provenance</h2><table class="meta">' + body + "</table>"
    )


def render_html(result: ExperimentResult, out_dir: str | os.PathLike[str]) -> str:
    """The report page; writes the PNGs it shows into ``out_dir/images/``."""

    out = Path(out_dir)
    (out / "images").mkdir(parents=True, exist_ok=True)
    reason = plots_unavailable()
    nav = [
        '<a href="#overall">All scenes</a>',
        '<a href="#equal-time">Equal time</a>',
        '<a href="#equal-quality">Equal quality</a>',
        '<a href="#statistics">Statistics</a>',
    ]
    if result.is_sequences:
        nav.append('<a href="#sequences">Sequences</a>')
    nav += [f'<a href="#scene-{_esc(_slug(s.id))}">{_esc(s.id)}</a>' for s in result.scenes]
    nav += ['<a href="#definitions">Definitions</a>', '<a href="#provenance">Provenance</a>']
    parts = []
    if result.spec.description:
        parts.append(f"<p>{_esc(result.spec.description)}</p>")
    parts.append(f"<nav>{' '.join(nav)}</nav>")
    parts.append(f'<div class="howto"><b>How to read this report</b>{HOW_TO_READ}</div>')
    parts.append(_findings(result))
    parts.append(_run_table(result))
    if result.notes:
        parts.append('<div class="warn">' + "<br>".join(_esc(n) for n in result.notes) + "</div>")
    parts += overall_sections(result, out, reason)
    if result.is_sequences:
        parts.append(temporal_section(result, out, reason is None))
    for i, scene in enumerate(result.scenes):
        parts.append(_scene_section(result, scene, i, out, reason is None))
    parts.append(_provenance(result))
    template = Template(
        resources.files("mcdenoise.experiments")
        .joinpath("templates/experiment.html")
        .read_text("utf-8")
    )
    return template.substitute(
        title=_esc(f"Experiment: {result.spec.name} — what accuracy costs in time"),
        version=_esc(result.provenance.get("mcdenoise_version", "")),
        created=_esc(result.created),
        body="\n".join(p for p in parts if p),
    )
