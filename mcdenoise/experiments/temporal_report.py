"""The parts of the experiment report that only sequences have.

* :func:`temporal_section`: over all sequences, per method and spp, the per-frame error
  (relMSE past the warm-up, and of the warm-up frames) and the temporal errors (temporal
  relMSE, tPSNR, tRMAE) against the total seconds *per frame* — a table and two plots in the
  style of the still report (:func:`mcdenoise.experiments.plots.plot_error_vs_time`);
* :func:`scene_images`: per sequence, at the strip level, an **x–t slice** for the noisy
  input, every method and the reference — one scanline (the middle row) of every frame,
  stacked top to bottom in frame order. A stable output gives straight vertical streaks
  (features move smoothly or stay); flicker shows as a speckled or striped texture across
  the rows, at a glance and without playing anything; the reference's slice is what it should
  look like. And an **animated strip**: every frame of noisy | methods | reference side by
  side, written as an animated PNG (Pillow) or, without Pillow, an animated GIF
  (OpenImageIO); both play in any browser from the file, offline.

Every image goes through one tonemap per sequence (exposure from the reference's middle
frame, :func:`mcdenoise.eval.tonemap.auto_exposure`), so brightness changes between methods
or frames are the images', not the display's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcdenoise.errors import McdenoiseError
from mcdenoise.eval.eval_report import write_png
from mcdenoise.eval.tonemap import auto_exposure, display, to_uint8
from mcdenoise.experiments.htmlkit import esc, g, img, sec, slug, sub, table
from mcdenoise.experiments.plots import plot_error_vs_time
from mcdenoise.experiments.sequence_units import TEMPORAL_OVERALL, frame_name, temporal_rows
from mcdenoise.experiments.spec_fields import NOISY
from mcdenoise.io import load_buffers
from mcdenoise.io.atomic import atomic_path

#: Frames per second of the animated strips (12–16 frames play in 3–4 s).
ANIMATION_FPS = 4
#: Largest magnification of a small image in the slices and the animation.
MAX_ZOOM = 8


# --- the section over all sequences -------------------------------------------------------


def temporal_section(result: Any, out: Path, plots_ok: bool) -> str:
    """The "Sequences" section: table and plots over every sequence (see the module doc)."""
    rows = temporal_rows(result)
    warm = result.spec.warmup_frames
    head = [
        "method",
        "spp",
        "relMSE per frame",
        f"relMSE, warm-up (first {warm})",
        "temporal relMSE",
        "temporal relMSE, warm-up",
        "tPSNR (dB)",
        "tRMAE",
        "s per frame: render + denoise = total",
    ]
    body = []
    for r in rows:
        cls = ' class="noisy"' if r["method"] == NOISY else ""
        if not r["complete"]:
            body.append(
                f'<tr{cls}><td>{esc(r["method"])}</td><td class="num">{r["spp"]}</td>'
                f'<td colspan="{len(head) - 2}">failed or could not run on '
                f"{len(result.scenes) - r['sequences']} sequence(s)</td></tr>"
            )
            continue
        cells = "".join(
            f'<td class="num">{g(r[k], 4)}</td>'
            for k in ("relmse", "relmse_warmup", "trelmse", "trelmse_warmup", "tpsnr", "trmae")
        )
        times = (
            f"{sec(r['render_seconds'])} + {sec(r['denoise_seconds'])} = {sec(r['total_seconds'])}"
        )
        body.append(
            f'<tr{cls}><td>{esc(r["method"])}</td><td class="num">{r["spp"]}</td>{cells}'
            f'<td class="num">{times}</td></tr>'
        )
    n = len(result.scenes)
    parts = [
        '<h2 id="sequences">Sequences: error per frame and over time</h2>',
        f'<p class="small">{n} sequence(s) of {_frame_count(result)} frames. A temporal method '
        "(e.g. svgf) carries a history from frame to frame; per-frame methods denoise each "
        "frame alone, which leaves their error free to change from frame to frame "
        "(flicker). <b>relMSE per frame</b>: the still error averaged over the frames past "
        f"the first {warm} (the warm-up, when a temporal method's history is still short; "
        "shown apart). <b>Temporal relMSE</b>: the relMSE of the frame-to-frame change "
        "o<sub>t</sub> − o<sub>t−1</sub> against the reference's change, i.e. how much of "
        "the change between frames is not in the scene; <b>tPSNR</b> (higher is better) and "
        "<b>tRMAE</b> are Noisebase's measures of the same change on 8-bit display values, "
        "comparable with that benchmark. Times are seconds <b>per frame</b>. "
        f"{esc(TEMPORAL_OVERALL)}.</p>",
        table(head, body),
    ]
    if plots_ok:
        parts.append(_plots(result, rows, out))
    return "".join(parts)


def _frame_count(result: Any) -> str:
    counts = sorted({len(s.frames) for s in result.scenes if s.is_sequence})
    return ", ".join(map(str, counts))


def _plots(result: Any, rows: Sequence[dict[str, Any]], out: Path) -> str:

    names = []
    for key, label, name in (
        ("relmse", "relMSE per frame", "plot_sequences_error_time.png"),
        ("trelmse", "temporal relMSE", "plot_sequences_temporal_time.png"),
    ):
        series: dict[str, tuple[list[float], list[float]]] = {}
        for lb in result.labels:
            pts = [
                (r["total_seconds"], r[key])
                for r in rows
                if r["method"] == lb and r["complete"] and r[key] and r["total_seconds"]
            ]
            if pts:
                series[lb] = ([p[0] for p in pts], [p[1] for p in pts])
        if not series:
            continue
        plot_error_vs_time(
            out / "images" / name,
            series,
            title=f"{label} vs total time per frame (over {len(result.scenes)} sequence(s))",
            ylabel=label,
            xlabel="total seconds per frame: render + denoise (log)",
        )
        names.append(name)
    inner = "".join(f"<figure>{img(n, n)}</figure>" for n in names)
    return f'<div class="plots">{inner}</div>' if names else ""


def scene_table(result: Any, scene: Any) -> str:
    """Per sequence: per-frame and temporal errors and seconds per frame of every record."""
    rows = temporal_rows(result, [scene.id])
    body = []
    for r in rows:
        rec = result.record(scene.id, r["spp"], r["method"])
        if rec is None:
            continue
        cls = ' class="noisy"' if r["method"] == NOISY else ""
        if rec.get("failed"):
            why = str(rec.get("error") or rec.get("reason") or "")
            body.append(
                f'<tr{cls}><td>{esc(r["method"])}</td><td class="num">{r["spp"]}</td>'
                f'<td class="fail" colspan="5">{esc(why[:160])}</td></tr>'
            )
            continue
        cells = "".join(
            f'<td class="num">{g(r[k], 4)}</td>'
            for k in ("relmse", "relmse_warmup", "trelmse", "tpsnr", "trmae")
        )
        per = [f.get("seconds") for f in rec.get("frames") or []]
        detail = f"frames {', '.join(g(v, 2) for v in per)}" if any(per) else ""
        split = f"{g(r['render_seconds'])} + {g(r['denoise_seconds'])} s"
        body.append(
            f'<tr{cls}><td>{esc(r["method"])}</td><td class="num">{r["spp"]}</td>{cells}'
            f'<td class="num">{sec(r["total_seconds"])}'
            f"{sub(esc(split))}"
            f"{sub(esc(detail)) if detail else ''}</td></tr>"
        )
    head = [
        "method",
        "spp",
        "relMSE per frame",
        "relMSE warm-up",
        "temporal relMSE",
        "tPSNR (dB)",
        "tRMAE",
        "s per frame (render + denoise; each frame's denoise s)",
    ]
    return table(head, body)


# --- x-t slices and the animated strip ----------------------------------------------------


def _frames_of(result: Any, scene: Any, label: str, spp: int, out: Path) -> list[np.ndarray] | None:
    """The ``(3, H, W)`` frames of ``label`` at ``spp`` (``None``: not kept or failed)."""

    if label == NOISY:
        return [load_buffers(n, part=f"spp{spp}")["color"].numpy() for n, _ in scene.frames]
    r = result.record(scene.id, spp, label)
    if r is None or r.get("failed") or not r.get("output"):
        return None
    folder = Path(r["output"])
    folder = folder if folder.is_absolute() else out / folder
    paths = [folder / f"{frame_name(t)}.exr" for t in range(len(scene.frames))]
    if not all(p.is_file() for p in paths):
        return None
    return [load_buffers(p)["color"].numpy() for p in paths]


def scene_images(result: Any, scene: Any, index: int, out: Path) -> str:
    """x–t slices and the animated strip of one sequence at the strip level (module doc)."""

    spp = result.strip_spp
    refs = [load_buffers(r)["color"].numpy() for _, r in scene.frames]
    n = len(refs)
    _, h, w = refs[0].shape
    exposure = auto_exposure(refs[n // 2].astype(np.float64))
    row = h // 2
    zoom = max(1, min(MAX_ZOOM, 256 // max(h, w)))
    rows_per_frame = max(2, math.ceil(96 / n))
    panels: list[tuple[str, list[np.ndarray]]] = []
    missing = []
    for label in result.labels:
        frames = _frames_of(result, scene, label, spp, out)
        if frames is None:
            rec = result.record(scene.id, spp, label) or {}
            missing.append(f"{label} ({rec.get('error') or rec.get('reason') or 'not kept'})")
            continue
        panels.append((label, frames))
    panels.append(("reference", refs))
    tag = f"strip_{index:02d}_{slug(scene.id)}"
    figures = []
    for i, (label, frames) in enumerate(panels):
        shown = np.stack([display(f, exposure)[:, row, :] for f in frames], axis=1)  # (3, T, W)
        shown = np.repeat(np.repeat(shown, rows_per_frame, axis=1), zoom, axis=2)
        name = f"{tag}_xt_{i:02d}_{slug(label)}.png"
        write_png(out / "images" / name, shown)
        caption = f"<b>{esc(label)}</b>" + (f", {spp} spp" if label != "reference" else "")
        if label != "reference":
            rec = result.record(scene.id, spp, label) or {}
            caption += (
                f"<br>temporal relMSE {g((rec.get('metrics') or {}).get('trelmse'))}"
                if not rec.get("failed")
                else ""
            )
        figures.append(
            f"<figure>{img(name, f'x-t slice of {label}', _size(shown))}"
            f"<figcaption>{caption}</figcaption></figure>"
        )
    marked = display(refs[n // 2], exposure)
    marked[:, row, :] = np.array([1.0, 0.0, 0.0])[:, None]
    marked = np.repeat(np.repeat(marked, zoom, axis=1), zoom, axis=2)
    where_name = f"{tag}_xt_row.png"
    write_png(out / "images" / where_name, marked)
    figures.append(
        f"<figure>{img(where_name, 'the scanline of the slices', _size(marked))}"
        f"<figcaption>the scanline (red), frame {n // 2} of the reference</figcaption></figure>"
    )
    # the animated strip: every panel side by side, frame by frame
    gap = np.ones((3, h * zoom, 2))
    strip_frames = []
    for t in range(n):
        tiles = []
        for _, frames in panels:
            im = display(frames[t], exposure)
            tiles += [np.repeat(np.repeat(im, zoom, axis=1), zoom, axis=2), gap]
        strip_frames.append(to_uint8(np.concatenate(tiles[:-1], axis=2)))
    anim_base = out / "images" / f"{tag}_anim"
    anim = write_animation(anim_base, strip_frames, fps=ANIMATION_FPS)
    order = " | ".join(label for label, _ in panels)
    labels = "".join(
        f'<span style="display:inline-block;width:{w * zoom + 2}px">{esc(label)}</span>'
        for label, _ in panels
    )
    sh, sw = strip_frames[0].shape[:2]
    return (
        f"<h3>Over time at {spp} spp</h3>"
        f'<p class="small">x–t slices: row {row} of every frame, frame 0 at the top, each '
        f"frame {rows_per_frame} rows tall (x magnified {zoom}×). Features that move or stay "
        "draw smooth streaks; flicker shows as speckle or stripes across the rows (compare "
        "with the reference). Same tonemap for all: exposure "
        f"×{exposure:.3g} from the reference's frame {n // 2}, sRGB.</p>"
        f'<div class="strip">{"".join(figures)}</div>'
        f'<p class="small">Animated strip ({anim.suffix[1:].upper()}, {ANIMATION_FPS} frames '
        f"per second, loops; plays offline), left to right: {esc(order)}.</p>"
        f'<div class="small">{labels}</div>'
        f'<div class="strip">{img(anim.name, "animated strip: " + order, _wh(sw, sh))}</div>'
        + (f'<p class="notes">Not shown: {esc("; ".join(missing))}</p>' if missing else "")
    )


def _size(shown: np.ndarray) -> str:
    return _wh(shown.shape[-1], shown.shape[-2])


def _wh(w: int, h: int) -> str:
    return f' width="{w}" height="{h}"'


# --- animation files ----------------------------------------------------------------------


def animation_writer() -> str:
    """``"apng"`` when Pillow can write animated PNGs here, else ``"gif"`` (OpenImageIO)."""
    try:
        from PIL import Image  # noqa: F401  # lazy: optional, see except
    except ImportError:
        return "gif"
    return "apng"


def write_animation(base: Path, frames: Sequence[np.ndarray], *, fps: int) -> Path:
    """Write ``frames`` (``(H, W, 3)`` uint8, one size) as a looping animation next to
    ``base``: ``base.png`` (animated PNG, lossless, through Pillow) or, without Pillow,
    ``base.gif`` (OpenImageIO's GIF writer: 256 colours per frame); atomically. Returns the
    file written.

    Raises:
        McdenoiseError: no frame, or the file cannot be written.
    """
    if not frames:
        raise McdenoiseError(f"{base}: an animation needs at least one frame")
    delay_ms = round(1000 / fps)
    if animation_writer() == "apng":
        from PIL import Image  # lazy: Pillow only where a GIF is written

        path = base.with_suffix(".png")
        images = [Image.fromarray(np.ascontiguousarray(f), "RGB") for f in frames]
        with atomic_path(path) as tmp:
            images[0].save(
                tmp,
                format="PNG",
                save_all=True,
                append_images=images[1:],
                duration=delay_ms,
                loop=0,
                disposal=0,
                blend=0,
            )
        return path
    return _write_gif(base.with_suffix(".gif"), frames, fps)


def _write_gif(path: Path, frames: Sequence[np.ndarray], fps: int) -> Path:
    """An animated GIF through OpenImageIO: one subimage per frame, ``fps``, looping."""
    import OpenImageIO as oiio  # lazy: OpenImageIO only where an image is written

    h, w = frames[0].shape[:2]
    spec = oiio.ImageSpec(w, h, 3, oiio.UINT8)
    spec.attribute("FramesPerSecond", oiio.TypeRational, (fps, 1))
    spec.attribute("oiio:LoopCount", 0)
    with atomic_path(path) as tmp:
        writer = oiio.ImageOutput.create(str(tmp))
        if writer is None or not writer.open(str(tmp), [spec] * len(frames)):
            why = oiio.geterror() or (writer.geterror() if writer else "") or "no GIF writer"
            raise McdenoiseError(f"cannot write {path}: {why}")
        try:
            for i, f in enumerate(frames):
                if i and not writer.open(str(tmp), spec, "AppendSubimage"):
                    raise McdenoiseError(f"cannot write {path}: {writer.geterror()}")
                if not writer.write_image(np.ascontiguousarray(f)):
                    raise McdenoiseError(f"cannot write {path}: {writer.geterror()}")
        finally:
            writer.close()
    return path
