"""Write an evaluation as ``results.json``, ``results.csv`` and a self-contained ``report.html``.

The HTML page needs no network and no JavaScript: CSS is inline and every image is a PNG in
``out_dir/images/`` referenced by a relative path. Per scene it shows a table (best value of
each column in bold, failed outputs in red) and an image strip: the noisy input(s), every
output and the reference through the same crop and the same tonemap (exposure chosen from the
reference), each with its per-pixel relMSE error map in false colour on one shared log scale.

A sequence (a folder of frames) is one row per method: its metrics are the means past the
warm-up, with the warm-up's value under each; a per-frame table follows, ``frames.csv`` holds
every frame's values, and the image strip shows the last frame.

Every file is written atomically (:mod:`mcdenoise.io.atomic`). Non-finite numbers follow
:mod:`mcdenoise.eval.results`: ``"inf"`` strings in JSON and CSV, never bare ``Infinity``/``NaN``.
"""

from __future__ import annotations

import csv
import html
import io
import json
import math
import os
import re
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from string import Template

import numpy as np

from mcdenoise.errors import McdenoiseError
from mcdenoise.eval.metrics import METRICS, PARTS, flip_status, relmse_map
from mcdenoise.eval.results import ROLE_NOISY, EvalRecord, EvalResult, ScenePreview, encode_float
from mcdenoise.eval.temporal_metrics import TEMPORAL_METRICS, metric_spec
from mcdenoise.eval.tonemap import colorbar, display, false_color, to_uint8
from mcdenoise.io.atomic import atomic_path, sweep_stale_temporaries, write_text_atomic

#: Columns of results.csv before the metric columns.
CSV_HEAD = ("scene", "role", "method", "file", "input", "spp", "seconds", "device")
#: Columns of results.csv after the metric columns.
CSV_TAIL = ("relmse_ratio", "failed", "bad_pixels", "reason", "unavailable", "notes", "params")
#: Columns of frames.csv (one row per frame of every sequence) before the metric columns.
FRAMES_HEAD = ("scene", "role", "method", "sequence", "frame", "index", "warmup", "file", "seconds")
#: Columns of frames.csv after the metric columns.
FRAMES_TAIL = ("failed", "bad_pixels", "reason", "unavailable")

#: Largest on-screen magnification of small crops (nearest neighbour).
_MAX_ZOOM = 16
#: Decades shown by the error-map colour scale.
_ERROR_DECADES = 4
#: Colour of the crop rectangle drawn on the overview thumbnail.
_BOX_RGB = (0.1, 0.9, 0.2)
#: Names of the images this module writes (``<scene index>_<scene>_...png``).
_OWN_IMAGE = re.compile(r"^\d{2}_[A-Za-z0-9._-]+\.png$")

HOW_TO_READ_SEQUENCES = (
    "Sequences: each row is one method over the whole sequence. Per-frame metrics are means "
    "over the frames after the warm-up; the temporal metrics judge frame differences "
    "(o\u209c \u2212 o\u209c\u208b\u2081 against r\u209c \u2212 r\u209c\u208b\u2081): "
    "lower temporal relMSE and tRMAE, higher tPSNR mean less flicker. The small line under a "
    "value is the same metric over the warm-up frames, reported apart because a temporal "
    "method has little history there. The per-frame table below shows every frame "
    "(warm-up frames in grey)."
)

HOW_TO_READ = (
    "Each scene compares denoised outputs with a high-sample-count reference. Lower relMSE, "
    "SMAPE, MSE and FLIP are better; higher PSNR and SSIM are better; the best value of each "
    "column is bold. Mean bias is the output's mean over the reference's mean \u2212 1 "
    "(\u22123 % = 3 % darker: energy lost; best is closest to 0), with R, G and B below it. "
    "The grey \u201cnoisy\u201d row is the input before denoising, and "
    "\u201crelMSE \u00f7 noisy\u201d below 1 means the method reduced the error (0.1 = ten "
    "times lower). Rows in red failed: the output has NaN/Inf pixels, so no metric is given. "
    "Under each image, its per-pixel relMSE map: dark = small error, bright = large error "
    "(magenta = NaN/Inf)."
)


def write_report(result: EvalResult, out_dir: str | os.PathLike[str]) -> dict[str, Path]:
    """Write ``results.json``, ``results.csv``, ``report.html`` and ``images/*.png``.

    Args:
        result: what :func:`~mcdenoise.eval.run.evaluate` returned.
        out_dir: folder to write into (created if needed); existing files are replaced
            atomically.

    Returns:
        ``{"json": ..., "csv": ..., "html": ..., "images": <folder>}``.

    Raises:
        McdenoiseError: the folder cannot be created or a file cannot be written.
    """
    out = Path(out_dir)
    try:
        (out / "images").mkdir(parents=True, exist_ok=True)
        sweep_stale_temporaries(out / "images")  # once: the images are written without a sweep
    except OSError as err:
        raise McdenoiseError(f"cannot create report folder {out}: {err.strerror or err}") from None
    paths = {
        "json": out / "results.json",
        "csv": out / "results.csv",
        "html": out / "report.html",
        "images": out / "images",
    }
    if result.has_sequences:
        paths["frames"] = out / "frames.csv"
    try:
        write_json(result, paths["json"])
        write_csv(result, paths["csv"])
        if "frames" in paths:
            write_frames_csv(result, paths["frames"])
        page = render_html(result, out)
        write_text_atomic(paths["html"], page)
        shown = {html.unescape(n) for n in re.findall(r'src="images/([^"/]+)"', page)}
        _prune_images(paths["images"], shown)
    except OSError as err:
        raise McdenoiseError(f"cannot write the report in {out}: {err}") from None
    return paths


def _prune_images(folder: Path, keep: set[str]) -> None:
    """Delete PNGs of an earlier report in ``folder`` (our ``NN_*.png`` names) not in ``keep``."""
    for f in folder.iterdir():
        if f.is_file() and _OWN_IMAGE.match(f.name) and f.name not in keep:
            f.unlink()


# --- JSON and CSV -------------------------------------------------------------------------


def write_json(result: EvalResult, path: str | os.PathLike[str]) -> None:
    """Write ``result.to_dict()`` as strict JSON (``allow_nan=False``), atomically."""
    text = json.dumps(result.to_dict(), indent=2, ensure_ascii=False, allow_nan=False)
    write_text_atomic(path, text + "\n")


def csv_columns(result: EvalResult) -> list[str]:
    """Header of results.csv: identification, one column per metric, then status columns."""
    return [*CSV_HEAD, *result.metrics, *CSV_TAIL]


def csv_cell(value: object) -> str:
    """A CSV cell: empty for ``None``, ``true``/``false``, floats as the JSON files write them."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return str(encode_float(value))
    return str(value)


def write_csv(result: EvalResult, path: str | os.PathLike[str]) -> None:
    """Write one row per record (missing values empty, infinity as ``inf``), atomically."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(csv_columns(result))
    for rec in result.records:
        row = [rec.scene, rec.role, rec.method, rec.file, rec.input, rec.spp, rec.seconds]
        row.append(rec.device)
        row += [rec.metrics.get(m) for m in result.metrics]
        row += [rec.relmse_ratio, rec.failed, rec.bad_pixels, rec.reason]
        row.append("; ".join(f"{k}: {v}" for k, v in rec.unavailable.items()) or None)
        row.append("; ".join(rec.notes) or None)
        row.append(rec.params)
        writer.writerow([csv_cell(v) for v in row])
    write_text_atomic(path, buf.getvalue())


def write_frames_csv(result: EvalResult, path: str | os.PathLike[str]) -> None:
    """Write one row per frame of every evaluated sequence (its still metrics, and the
    temporal metrics of the pair it closes; empty for the first frame), atomically."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow([*FRAMES_HEAD, *result.metrics, *FRAMES_TAIL])
    for rec in result.records:
        if rec.sequence is None:
            continue
        for f in rec.sequence.frames:
            row = [rec.scene, rec.role, rec.method, rec.file, f.frame, f.index, f.warmup]
            row += [f.file, f.seconds, *(f.metrics.get(m) for m in result.metrics)]
            row += [f.failed, f.bad_pixels, f.reason]
            row.append("; ".join(f"{k}: {v}" for k, v in f.unavailable.items()) or None)
            writer.writerow([csv_cell(v) for v in row])
    write_text_atomic(path, buf.getvalue())


# --- images -------------------------------------------------------------------------------


def write_png(path: str | os.PathLike[str], rgb: np.ndarray, *, sweep: bool = True) -> None:
    """Write display-encoded ``(3, H, W)`` values in ``[0, 1]`` as an 8-bit sRGB PNG, atomically
    (``sweep``: see :func:`~mcdenoise.io.atomic.atomic_path`; the report's images pass False,
    :func:`write_report` sweeps their folder once)."""
    import OpenImageIO as oiio  # lazy: OpenImageIO only where an image is written

    pixels = to_uint8(rgb)  # (H, W, 3)
    buf = oiio.ImageBuf(pixels)
    with atomic_path(path, sweep=sweep) as tmp:
        if not buf.write(str(tmp)):
            raise McdenoiseError(f"cannot write {path}: {buf.geterror() or 'OpenImageIO error'}")


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._") or "x"


def error_scale(maps: list[np.ndarray]) -> tuple[float, float]:
    """Shared log scale ``(lo, hi)`` for per-pixel relMSE maps: ``hi`` is the power of ten at or
    above the largest 99th percentile of the maps, ``lo = hi / 10**4``."""
    tops = [float(np.percentile(m[np.isfinite(m)], 99)) for m in maps if np.isfinite(m).any()]
    top = max([t for t in tops if t > 0], default=1e-2)
    hi = 10.0 ** math.ceil(math.log10(max(top, 1e-8)))
    return hi / 10.0**_ERROR_DECADES, hi


def _with_box(thumb: np.ndarray, window: tuple[int, int, int, int], factor: int) -> np.ndarray:
    out = thumb.copy()
    y0, x0, h, w = (v // factor for v in window)
    h, w = max(h, 2), max(w, 2)
    y1, x1 = min(y0 + h, out.shape[1]) - 1, min(x0 + w, out.shape[2]) - 1
    for c, v in enumerate(_BOX_RGB):
        out[c, y0 : y1 + 1, x0] = v
        out[c, y0 : y1 + 1, x1] = v
        out[c, y0, x0 : x1 + 1] = v
        out[c, y1, x0 : x1 + 1] = v
    return out


# --- HTML ---------------------------------------------------------------------------------


def _esc(text: object) -> str:
    return html.escape(str(text), quote=True)


def _fmt(metric: str, value: float | None) -> str:
    if value is None:
        return "\u2013"
    if metric == "spp":
        return str(value)
    if metric == "seconds":
        return f"{value:.3g}"
    if math.isinf(value):
        return "\u221e" if value > 0 else "\u2212\u221e"
    if math.isnan(value):
        return "NaN"
    if metric in ("psnr", "tpsnr"):
        return f"{value:.2f}"
    if metric in ("ssim", "flip"):
        return f"{value:.4f}"
    if metric in result_metric_names() and metric_spec(metric).signed:
        return percent(value)
    if value != 0 and (abs(value) < 1e-3 or abs(value) >= 1e5):
        return f"{value:.3e}"
    return f"{value:.4g}"


def percent(value: float, digits: int = 2) -> str:
    """A signed fraction as a percentage: ``-0.0392`` -> ``"\u22123.92 %"``."""
    if math.isnan(value):
        return "NaN"
    if math.isinf(value):
        return "\u221e" if value > 0 else "\u2212\u221e"
    text = f"{100.0 * value:+.{digits}f} %"
    return text.replace("-", "\u2212")


def _best(
    records: list[EvalRecord], get: Callable[[EvalRecord], float | None], better: str
) -> float | None:
    """The best value of a column: ``better`` is "higher", "lower" or "zero" (closest to 0)."""
    vals = [v for r in records if not r.failed and (v := get(r)) is not None and not math.isnan(v)]
    if not vals:
        return None
    if better == "zero":
        return min(vals, key=abs)
    return max(vals) if better == "higher" else min(vals)


def result_metric_names() -> set[str]:
    """Every registered metric name, still and temporal."""

    return {*METRICS, *TEMPORAL_METRICS}


def _direction(metric: str) -> str:
    m = metric_spec(metric)
    return "zero" if m.signed else ("higher" if m.higher_is_better else "lower")


def _table(result: EvalResult, scene: str, shown_metrics: list[str]) -> str:
    records = result.scene_records(scene)
    parts = {m: [p for p in PARTS.get(m, ()) if p in result.metrics] for m in shown_metrics}
    cols: list[tuple[str, str, Callable[[EvalRecord], float | None], str]] = [
        (m, metric_spec(m).label, (lambda r, m=m: r.metrics.get(m)), _direction(m))
        for m in shown_metrics
    ]
    per_frame = any(r.sequence is not None for r in records)
    seconds = "seconds / frame" if per_frame else "seconds"
    cols.append(("seconds", seconds, lambda r: r.seconds, "lower"))
    cols.append(("ratio", "relMSE \u00f7 noisy", lambda r: r.relmse_ratio, "lower"))
    best = {key: _best(records, get, hi) for key, _, get, hi in cols}
    head = "".join(f"<th>{_esc(label)}</th>" for _, label, _, _ in cols)
    rows = []
    for rec in records:
        cls = "failed" if rec.failed else ("noisy" if rec.role == ROLE_NOISY else "")
        name = Path(rec.file).name
        cells = [
            f'<td title="{_esc(rec.file)}">{_esc(rec.method)}<br><span class="small">'
            f"{_esc(name)}</span></td>",
            f'<td class="num">{_fmt("spp", rec.spp)}</td>',
        ]
        if rec.failed:
            cells.append(
                f'<td class="fail" colspan="{len(shown_metrics)}">FAILED: {_esc(rec.reason)}</td>'
            )
            tail = cols[len(shown_metrics) :]
        else:
            tail = cols
        for key, _, get, _ in tail:
            value = get(rec)
            if key in rec.unavailable:
                cells.append(f'<td class="num na" title="{_esc(rec.unavailable[key])}">n/a</td>')
                continue
            text = _esc(_fmt(key, value))
            if (
                value is not None
                and best[key] is not None
                and value == best[key]
                and not rec.failed
            ):
                text = f'<b class="best">{text}</b>'
            text += _parts_line(rec, parts.get(key, []))
            text += _warmup_line(rec, key)
            cells.append(f'<td class="num">{text}</td>')
        rows.append(f'<tr class="{cls}">{"".join(cells)}</tr>')
    return (
        '<table class="results"><thead><tr><th>method / file</th><th>input spp</th>'
        f"{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>"
    )


def _warmup_line(rec: EvalRecord, metric: str) -> str:
    """Under a sequence's value: the same metric over its warm-up frames."""
    seq = rec.sequence
    if seq is None or not seq.warmup or metric not in seq.warmup_metrics:
        return ""
    v = seq.warmup_metrics.get(metric)
    text = "n/a" if v is None else _fmt(metric, v)
    why = seq.warmup_unavailable.get(metric, "")
    title = f' title="{_esc(why)}"' if why else ""
    return f'<br><span class="small"{title}>warm-up: {_esc(text)}</span>'


def _frames_table(result: EvalResult, scene: str) -> str:
    """Per-frame relMSE and temporal relMSE (those evaluated; else the first still and the
    first temporal metric) of every sequence of ``scene``; warm-up frames in grey."""
    records = [r for r in result.scene_records(scene) if r.sequence is not None]
    if not records:
        return ""
    still = [m for m in result.metrics if m in METRICS]
    temporal = [m for m in result.metrics if m not in METRICS]
    keys = [m for m in ("relmse", "trelmse") if m in result.metrics] or [*still[:1], *temporal[:1]]
    head = "".join(
        f"<th>{_esc(r.method)}<br>{_esc(metric_spec(m).label)}</th>" for r in records for m in keys
    )
    first = records[0].sequence
    assert first is not None
    rows = []
    for i, fr in enumerate(first.frames):
        cells = [f"<td>{_esc(fr.frame)}{' (warm-up)' if fr.warmup else ''}</td>"]
        for r in records:
            seq = r.sequence
            f = seq.frames[i] if seq is not None and i < len(seq.frames) else None
            for m in keys:
                v = None if f is None else f.metrics.get(m)
                cells.append(f'<td class="num">{_esc(_fmt(m, v))}</td>')
        rows.append(f'<tr class="{"noisy" if fr.warmup else ""}">{"".join(cells)}</tr>')
    return (
        f'<h3>Per frame</h3><p class="small">Temporal values of a frame are those of the pair '
        f"(previous frame, this frame); the first frame has none. Every metric of every frame "
        f"is in frames.csv and results.json.</p>"
        f'<table class="results"><thead><tr><th>frame</th>{head}</tr></thead>'
        f"<tbody>{''.join(rows)}</tbody></table>"
    )


def _parts_line(rec: EvalRecord, parts: list[str]) -> str:
    """The detail metrics of a summary cell (``R \u22121.2 % G ...``) as a second line."""
    if not parts:
        return ""
    items = []
    for p in parts:
        v = rec.metrics.get(p)
        label = METRICS[p].label.split()[-1]
        items.append(f"{label} {'n/a' if v is None else _fmt(p, v)}")
    return f'<br><span class="small">{_esc(" ".join(items))}</span>'


def _strip(result: EvalResult, scene: str, out: Path, index: int) -> str:
    preview: ScenePreview | None = result.previews.get(scene)
    if preview is None:
        return '<p class="notes">No images: this result holds no preview crops.</p>'
    images_dir = out / "images"
    prefix = f"{index:02d}_{_slug(scene)}"
    ref = preview.reference.astype(np.float64)
    _, h, w = ref.shape
    zoom = max(1, min(_MAX_ZOOM, 256 // max(h, w)))
    size = f'width="{w * zoom}" height="{h * zoom}"'
    records = [r for r in result.scene_records(scene) if r.file in preview.images]
    maps = {rec.file: relmse_map(preview.images[rec.file], ref) for rec in records}
    lo, hi = error_scale(list(maps.values()))

    figures = []
    for i, rec in enumerate(records):
        img_name = f"{prefix}_{i:02d}_{_slug(rec.method)}.png"
        err_name = f"{prefix}_{i:02d}_{_slug(rec.method)}_relmse.png"
        shown = display(preview.images[rec.file], preview.exposure)
        write_png(images_dir / img_name, shown, sweep=False)
        write_png(images_dir / err_name, false_color(maps[rec.file], lo, hi), sweep=False)
        spp = f", {rec.spp} spp" if rec.spp is not None else ""
        if rec.failed:
            detail = (
                f"FAILED: {rec.bad_pixels} NaN/Inf pixels (magenta)"
                if rec.bad_pixels
                else f"FAILED: {rec.reason}"
            )
        else:
            v = rec.metrics.get("relmse")
            detail = f"relMSE {_fmt('relmse', v)}" if v is not None else ""
        if rec.sequence is not None and rec.sequence.frames:
            last = rec.sequence.frames[-1]
            v = last.metrics.get("relmse")
            detail = f"{last.frame}" + (f": relMSE {_fmt('relmse', v)}" if v is not None else "")
        cls = ' class="failed"' if rec.failed else ""
        figures.append(
            f'<figure{cls}><img src="images/{_esc(img_name)}" {size} '
            f'alt="{_esc(rec.method)}"><img src="images/{_esc(err_name)}" {size} '
            f'alt="per-pixel relMSE of {_esc(rec.method)}"><figcaption><b>{_esc(rec.method)}</b>'
            f"{_esc(spp)}<br>{_esc(Path(rec.file).name)}<br>{_esc(detail)}</figcaption></figure>"
        )
    ref_name = f"{prefix}_reference.png"
    bar_name = f"{prefix}_colorbar.png"
    seq = next((r.sequence for r in records if r.sequence is not None and r.sequence.frames), None)
    last_frame = f" / {seq.frames[-1].frame}" if seq is not None else ""
    write_png(images_dir / ref_name, display(ref, preview.exposure), sweep=False)
    write_png(images_dir / bar_name, colorbar(w * zoom, 12), sweep=False)
    ticks = "".join(
        f"<span>{10.0**e:.0e}</span>"
        for e in range(round(math.log10(lo)), round(math.log10(hi)) + 1)
    )
    figures.append(
        f'<figure><img src="images/{_esc(ref_name)}" {size} alt="reference">'
        f'<div class="legend" style="width:{w * zoom}px">per-pixel relMSE (log scale)<br>'
        f'<img src="images/{_esc(bar_name)}" width="{w * zoom}" height="12" alt="colour scale">'
        f'<div class="ticks">{ticks}</div></div>'
        f"<figcaption><b>reference</b><br>{_esc(Path(result.references.get(scene, '')).name)}"
        f"{_esc(last_frame)}</figcaption></figure>"
    )
    y0, x0, ch, cw = preview.window
    full_h, full_w = preview.full_shape
    if preview.overview is not None:
        ov_name = f"{prefix}_overview.png"
        thumb = display(preview.overview, preview.exposure)
        thumb = _with_box(thumb, preview.window, preview.overview_factor)
        write_png(images_dir / ov_name, thumb, sweep=False)
        where = (
            f"Images show the crop x {x0}\u2013{x0 + cw - 1}, y {y0}\u2013{y0 + ch - 1} of the "
            f"{full_w}\u00d7{full_h} image (green box), chosen where the reference has the most "
            "visible detail."
        )
        figures.insert(
            0,
            f'<figure><img src="images/{_esc(ov_name)}" alt="whole reference with the crop">'
            "<figcaption><b>where the crop is</b></figcaption></figure>",
        )
    else:
        where = f"Images show the whole {full_w}\u00d7{full_h} image"
        where += f", magnified {zoom}\u00d7." if zoom > 1 else "."
    exposure = (
        f"Same tonemap for all: exposure \u00d7{preview.exposure:.3g} "
        f"({math.log2(preview.exposure):+.2f} EV, chosen from the reference), clamped to [0, 1], "
        f"sRGB. Error maps share one log scale from {lo:.0e} to {hi:.0e}."
    )
    if seq is not None:
        where = f"Sequences: the last frame ({seq.frames[-1].frame}). " + where
    return (
        f'<p class="small">{_esc(where)} {_esc(exposure)}</p>'
        f'<div class="strip">{"".join(figures)}</div>'
    )


def _header(result: EvalResult) -> str:
    refs = "".join(
        f"<li><b>{_esc(scene)}</b>: <code>{_esc(path)}</code></li>"
        for scene, path in result.references.items()
    )
    metric_rows = "".join(
        f"<tr><th>{_esc(metric_spec(m).label)}</th><td>{_esc(metric_spec(m).definition)}</td>"
        f"<td>{_esc(metric_spec(m).space)}</td>"
        f"<td>{metric_spec(m).describe()['best']} is best</td></tr>"
        for m in result.metrics
    )
    flip_note = ""
    if "flip" in result.metrics:
        missing = [r for r in result.records if "flip" in r.unavailable]
        reasons = sorted({r.unavailable["flip"] for r in missing})
        if missing:
            flip_note = (
                f'<p class="notes">FLIP not computed for {len(missing)} of '
                f"{len(result.records)} images: {_esc('; '.join(reasons))}</p>"
            )
        elif flip_status() is not None:
            flip_note = f'<p class="notes">FLIP: {_esc(flip_status())}</p>'
    failed = sum(r.failed for r in result.records)
    status = (
        f'<p class="fail" style="color:#b00020"><b>{failed} image(s) FAILED</b> '
        "(NaN/Inf pixels): see the red rows.</p>"
        if failed
        else ""
    )
    howto = HOW_TO_READ
    spaces = (
        "relMSE, SMAPE and MSE on linear HDR RGB; PSNR and SSIM on sRGB clamped to [0,1] "
        "(no exposure); FLIP and mean bias on linear HDR RGB."
    )
    sequences = ""
    if result.has_sequences:
        howto += " " + HOW_TO_READ_SEQUENCES
        spaces += (
            " Temporal relMSE on linear HDR RGB; tPSNR and tRMAE on Noisebase's 8-bit display "
            "values (ACES, gamma 2.2, truncated to 8 bits), as Noisebase computes them."
        )
        w = result.warmup or 0
        sequences = (
            f"<tr><th>Sequences</th><td>Warm-up: the first {w} frame(s), reported apart. "
            f"Per-frame metrics: mean over frames t \u2265 {w}; temporal metrics: mean over the "
            f"frame pairs (t \u2212 1, t) with t \u2212 1 \u2265 {w} (both frames past the "
            "warm-up, as Noisebase). The warm-up line under a value: frames t &lt; "
            f"{w} and pairs ending at t \u2264 {w}. Seconds: mean per frame.</td></tr>"
        )
    return (
        f'<p class="howto"><b>How to read this:</b> {_esc(howto)}</p>{status}'
        '<table class="meta">'
        f"<tr><th>Reference{'s' if len(result.references) != 1 else ''}</th><td><ul>{refs}</ul>"
        "</td></tr>"
        f"<tr><th>Colour spaces</th><td>{_esc(spaces)}</td></tr>{sequences}"
        f"<tr><th>mcdenoise</th><td>version {_esc(result.version)}, evaluated "
        f"{_esc(result.created)}</td></tr></table>"
        '<h3>Metric definitions</h3><table class="meta">'
        f"<tr><th>metric</th><th>definition (x = output, r = reference)</th><th>colour space</th>"
        f"<th></th></tr>{metric_rows}</table>{flip_note}"
    )


def render_html(result: EvalResult, out_dir: str | os.PathLike[str]) -> str:
    """The report page as text; writes the PNGs it references into ``out_dir/images/``."""
    out = Path(out_dir)
    (out / "images").mkdir(parents=True, exist_ok=True)
    # FLIP gets a column only when some row has a value (it is an optional extra)
    # FLIP only when some row has a value; the parts of a summary (bias R, G, B) under it
    shown = [
        m
        for m in result.metrics
        if (m != "flip" or any(r.metrics.get(m) is not None for r in result.records))
        and metric_spec(m).part_of not in result.metrics
    ] or list(result.metrics)
    sections = [_header(result)]
    for index, scene in enumerate(result.scenes()):
        records = result.scene_records(scene)
        notes = [f"{Path(r.file).name}: {n}" for r in records for n in r.notes]
        section = f'<h2 id="scene-{_esc(_slug(scene))}">Scene: {_esc(scene)}</h2>'
        section += _table(result, scene, shown)
        section += _frames_table(result, scene)
        if notes:
            section += '<p class="notes">' + "<br>".join(_esc(n) for n in notes) + "</p>"
        section += _strip(result, scene, out, index)
        sections.append(section)
    template = Template(
        resources.files("mcdenoise.eval").joinpath("templates/report.html").read_text("utf-8")
    )
    return template.substitute(
        title=_esc("mcdenoise evaluation report"),
        version=_esc(result.version),
        created=_esc(result.created),
        body="\n".join(sections),
    )
