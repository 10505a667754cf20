"""The experiment report's interactive image viewer: HDR pixels of every method at every spp.

The static strip of :mod:`mcdenoise.experiments.report` shows one spp level as 8-bit PNGs. The
viewer, in the manner of Disney's JERI and ``tev``, shows the HDR pixels themselves: per scene
the noisy input and every method at every spp level, and the reference; two images side by
side (A | B) or one at a time with keys to flip between them, synchronised zoom (to single
pixels, nearest neighbour) and pan, an exposure slider in EV applied to the HDR values before
sRGB, per-pixel error views (relMSE, and FLIP where ``flip_evaluator`` is installed), the value
under the cursor, and two automatic crops where the methods disagree most, as papers' figures
show them. For a sequence, every frame with a frame slider.

The report works opened from ``file://``, offline: Chromium blocks ``fetch()`` and canvas
reads of images from ``file://`` URLs, so each scene's pixels are a script,
``viewer/scene_NN.js``, that calls ``mcdViewerRegister({...})`` (``templates/viewer.js``,
copied next to it with ``viewer.css``, adds it to the page when the scene's viewer comes near
the window: a long report holds only the scenes looked at). Each colour layer (one frame of one image, ``(3, H,
W)``) is stored as

    base64( zlib( low bytes ‖ high bytes of the little-endian float16 values, C-order CHW ) )

— half floats (values beyond ±65504 clipped to it; NaN and Inf kept), their two byte planes
one after the other because the high bytes (sign, exponent) compress far better apart — and
decoded in the browser with ``DecompressionStream("deflate")`` and a half→float table. A FLIP
layer is ``(H, W)`` uint8 (FLIP × 255, rounded), zlib, base64, computed at the strip level
only (HDR-FLIP takes up to 0.3 s an image of 128×128). The demo (4 scenes of 128×128, 7
levels, 8 images a level) stores 20 MB this way, 5 MB a scene.

Nothing here fails a report: an output that is missing, failed or unreadable is shown in the
viewer as "not available" with the reason; a scene whose reference cannot be read gets a note
instead of a viewer.
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import os
import re
import zlib
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from mcdenoise.errors import McdenoiseError
from mcdenoise.eval.eval_report import error_scale
from mcdenoise.eval.metrics import _FLIP_MIN_LUMINANCE, flip_status, relmse_map
from mcdenoise.eval.tonemap import auto_exposure, colorbar, to_uint8
from mcdenoise.experiments.dataset import read_level, read_reference
from mcdenoise.experiments.htmlkit import esc, g, sec
from mcdenoise.experiments.record_values import relmse_of
from mcdenoise.experiments.spec_fields import NOISY
from mcdenoise.experiments.temporal_report import _frames_of
from mcdenoise.io import load_buffers
from mcdenoise.io.atomic import write_bytes_atomic, write_text_atomic

#: The viewer's folder next to ``report.html``.
VIEWER_DIR = "viewer"
#: The static files copied from ``templates/`` into it.
STATIC_FILES = ("viewer.js", "viewer.css")
#: Side of the automatic crops (smaller on small images, see :func:`crop_size`) and how many.
CROP_SIDE = 32
CROP_COUNT = 2
#: Half-float bytes one scene may store; the levels past it are named as not stored, so a
#: report of large images stays a page a browser opens (the demo's scenes hold 5.6 MB each).
MAX_SCENE_BYTES = 96_000_000
#: Threads of the FLIP maps (flip_evaluator releases the GIL).
FLIP_THREADS = max(1, min(4, os.cpu_count() or 1))
#: The largest finite float16.
F16_MAX = float(np.finfo(np.float16).max)
#: Name of the reference image in the viewer.
REFERENCE = "reference"

_SCENE_FILE = re.compile(r"^scene_(\d+)\.js$")
_READ_ERRORS = (McdenoiseError, OSError, ValueError, KeyError, StopIteration)


# --- encoding -----------------------------------------------------------------------------


def encode_f16(image: np.ndarray) -> tuple[str, int]:
    """A colour layer as the viewer stores it (module doc) and how many values were clipped to
    ±65504 (beyond float16's range)."""
    a = np.asarray(image, dtype=np.float32)
    finite = np.isfinite(a)
    clipped = int(np.count_nonzero(finite & (np.abs(a) > F16_MAX)))
    a = np.where(finite, np.clip(a, -F16_MAX, F16_MAX), a)
    planes = np.ascontiguousarray(a.astype("<f2")).view(np.uint8).reshape(-1, 2)
    raw = planes[:, 0].tobytes() + planes[:, 1].tobytes()
    return base64.b64encode(zlib.compress(raw, 6)).decode("ascii"), clipped


def encode_u8(values: np.ndarray) -> str:
    """A scalar map in ``[0, 1]`` as uint8 (×255, rounded), zlib, base64."""
    q = np.round(np.clip(np.nan_to_num(values, nan=1.0), 0.0, 1.0) * 255.0).astype(np.uint8)
    return base64.b64encode(zlib.compress(np.ascontiguousarray(q).tobytes(), 6)).decode("ascii")


# --- error maps and crops -----------------------------------------------------------------


def flip_maps(pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> list[np.ndarray | str]:
    """Per ``(image, reference)`` pair (``(3, H, W)`` linear), the per-pixel HDR-FLIP error
    ``(H, W)``, or the reason there is none: ``flip_evaluator`` not installed, non-finite
    pixels, a black reference (flip_evaluator ends the interpreter on one, see
    :mod:`mcdenoise.eval.metrics`), or the library refusing the input.

    HDR-FLIP evaluates one LDR-FLIP per exposure step (2 to 8 on the demo's scenes, up to
    0.3 s an image of 128×128); flip_evaluator releases the GIL, so the pairs run on a few
    threads, with standard output redirected once around them all (it prints before exiting).
    """
    reason = flip_status()
    if reason is not None:
        return [reason] * len(pairs)
    import flip_evaluator  # lazy: optional, flip_status() said it is there

    def one(pair: tuple[np.ndarray, np.ndarray]) -> np.ndarray | str:
        image, reference = pair
        if not (np.isfinite(image).all() and np.isfinite(reference).all()):
            return "FLIP needs finite pixels"
        ref = np.ascontiguousarray(np.moveaxis(np.maximum(reference, 0.0), 0, -1), np.float32)
        test = np.ascontiguousarray(np.moveaxis(np.maximum(image, 0.0), 0, -1), np.float32)
        if not (np.isfinite(ref).all() and np.isfinite(test).all()):
            return "FLIP computes in float32: values beyond its range"
        luminance = ref @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
        if float(luminance.max()) < _FLIP_MIN_LUMINANCE:
            return "the reference is black: FLIP is undefined"
        try:
            values, _, _ = flip_evaluator.evaluate(
                ref, test, "HDR", applyMagma=False, computeMeanError=False
            )
        except SystemExit:
            return "flip_evaluator refused the input"
        except (RuntimeError, ValueError, TypeError) as err:
            return f"flip_evaluator failed: {' '.join(str(err).split())}"
        return np.asarray(values, dtype=np.float64).reshape(ref.shape[:2])

    with contextlib.redirect_stdout(io.StringIO()), ThreadPoolExecutor(FLIP_THREADS) as pool:
        return list(pool.map(one, pairs))


def crop_size(height: int, width: int) -> int:
    """The side of the automatic crops: :data:`CROP_SIDE`, or a third of a smaller image."""
    return max(1, min(CROP_SIDE, max(4, min(height, width) // 3), height, width))


def disagreement_crops(
    images: Sequence[np.ndarray], reference: np.ndarray, *, count: int = CROP_COUNT
) -> list[dict[str, Any]]:
    """The ``count`` square regions where the methods' outputs disagree most.

    The score of a window is the mean over its pixels of the variance across ``images`` of
    their per-pixel relMSE maps (clipped to 1, NaN counted as 1: one firefly is an error of
    100 %, not of a million, and cannot outweigh a region of visible differences); with one
    image, of its relMSE itself. Windows are taken greedily, each not overlapping the ones
    before. Returns ``[{"x", "y", "w", "h", "score"}]`` (image pixels, top-left origin),
    fewer when nothing disagrees.
    """
    if not images:
        return []
    maps = np.stack([np.nan_to_num(relmse_map(im, reference), nan=1.0) for im in images])
    maps = np.clip(maps, 0.0, 1.0)
    per_pixel = maps.var(axis=0) if len(images) > 1 else maps[0]
    h, w = per_pixel.shape
    s = crop_size(h, w)
    # window sums over every s×s window through an integral image
    ii = np.pad(per_pixel.cumsum(0).cumsum(1), ((1, 0), (1, 0)))
    score = (ii[s:, s:] - ii[:-s, s:] - ii[s:, :-s] + ii[:-s, :-s]) / (s * s)
    crops: list[dict[str, Any]] = []
    for _ in range(count):
        best = float(score.max())
        if not best > 0.0:
            break
        y, x = np.unravel_index(int(np.argmax(score)), score.shape)
        crops.append({"x": int(x), "y": int(y), "w": s, "h": s, "score": best})
        score[max(0, y - s + 1) : y + s, max(0, x - s + 1) : x + s] = -1.0
    return crops


# --- reading the images -------------------------------------------------------------------


def _frames(
    result: Any, scene: Any, label: str, spp: int, out: Path
) -> tuple[list[np.ndarray] | None, str]:
    """The ``(3, H, W)`` frames of ``label`` at ``spp`` (one for a still), or ``None`` and
    why they are not available."""
    r = result.record(scene.id, spp, label)
    if r is None:
        return None, "no result at this level"
    if r.get("failed") and label != NOISY:
        why = str(r.get("error") or r.get("reason") or "failed")
        return None, ("could not run: " if r.get("error") else "FAILED: ") + why[:300]
    try:
        if scene.is_sequence:
            frames = _frames_of(result, scene, label, spp, out)
            return frames, "" if frames is not None else "output not kept"
        if label == NOISY:
            level = next(lv for lv in scene.levels if lv.spp == spp)
            return [read_level(scene.noisy_file, level)["color"].numpy()], ""
        if not r.get("output"):
            return None, "output not kept ([report] outputs)"
        p = Path(r["output"])
        p = p if p.is_absolute() else out / p
        if not p.is_file():
            return None, f"output file missing: {r['output']}"
        return [load_buffers(p)["color"].numpy()], ""
    except _READ_ERRORS as err:
        return None, f"unreadable: {' '.join(str(err).split())[:300]}"


def _references(scene: Any) -> list[np.ndarray]:
    if scene.is_sequence:
        return [load_buffers(r)["color"].numpy() for _, r in scene.frames]
    return [read_reference(scene.reference_file)["color"].numpy()]


def _caption(r: Mapping[str, Any] | None) -> str:
    if not r:
        return ""
    if r.get("failed"):
        return "FAILED"
    parts = [f"relMSE {g(relmse_of(r))}"]
    if r.get("total_seconds") is not None:
        parts.append(sec(r.get("total_seconds")))
    return ", ".join(parts)


def _levels_in_budget(result: Any, scene: Any, image_bytes: int) -> list[int]:
    """The spp levels stored: the strip level first, then the others from the lowest, while
    the scene's colour layers (the noisy input and the outputs kept at each level, and the
    reference) stay within :data:`MAX_SCENE_BYTES`; at least one level."""
    strip = result.strip_spp
    order = sorted((lv.spp for lv in scene.levels), key=lambda s: (s != strip, s))
    total, keep = image_bytes, []
    for spp in order:
        records = (result.record(scene.id, spp, label) for label in result.labels)
        kept = sum(1 for r in records if r and r.get("output") and not r.get("failed"))
        total += (1 + kept) * image_bytes
        if keep and total > MAX_SCENE_BYTES:
            break
        keep.append(spp)
    return sorted(keep)


# --- the data of one scene ----------------------------------------------------------------


def scene_data(result: Any, scene: Any, index: int, out: Path) -> dict[str, Any]:
    """Everything the viewer shows of one scene, as the JSON object of its ``scene_NN.js``.

    Raises:
        McdenoiseError: the reference cannot be read (no viewer for this scene).
    """
    try:
        refs = _references(scene)
    except _READ_ERRORS as err:
        raise McdenoiseError(f"the reference cannot be read: {err}") from None
    n = len(refs)
    _, h, w = refs[0].shape
    mid = n // 2
    exposure = auto_exposure(refs[mid].astype(np.float64))
    flip_note = flip_status()
    strip = result.strip_spp
    levels = _levels_in_budget(result, scene, n * 3 * h * w * 2)
    crop_level = strip if strip in levels else levels[len(levels) // 2]
    notes: list[str] = []
    dropped = [lv.spp for lv in scene.levels if lv.spp not in levels]
    if dropped:
        notes.append(
            f"not stored, to keep the scene under {MAX_SCENE_BYTES / 1e6:g} MB of pixels: "
            f"{', '.join(map(str, dropped))} spp"
        )
    images: list[dict[str, Any]] = []
    crop_inputs: list[np.ndarray] = []
    flip_inputs: list[tuple[dict[str, Any], list[np.ndarray]]] = []
    strip_maps: list[np.ndarray] = []
    clipped = 0
    for spp in levels:
        for label in result.labels:
            frames, why = _frames(result, scene, label, spp, out)
            entry: dict[str, Any] = {"label": label, "spp": spp}
            rec = result.record(scene.id, spp, label)
            entry["caption"] = _caption(rec)
            if frames is None or len(frames) != n or frames[0].shape != refs[0].shape:
                entry["missing"] = why or "the output's size differs from the reference's"
                images.append(entry)
                continue
            layers = [encode_f16(f) for f in frames]
            entry["frames"] = [s for s, _ in layers]
            clipped += sum(c for _, c in layers)
            if spp == crop_level:
                flip_inputs.append((entry, frames))
                strip_maps.append(relmse_map(frames[mid], refs[mid]))
                if label != NOISY:
                    crop_inputs.append(frames[mid])
            images.append(entry)
    if flip_note is None:  # at the crop level only: HDR-FLIP is slow (flip_maps)
        pairs = [(f, r) for _, frames in flip_inputs for f, r in zip(frames, refs)]
        maps = iter(flip_maps(pairs))
        for entry, frames in flip_inputs:
            got = [next(maps) for _ in frames]
            if all(isinstance(m, np.ndarray) for m in got):
                entry["flip"] = [encode_u8(m) for m in got]  # type: ignore[arg-type]
            else:
                entry["flip_missing"] = next(m for m in got if isinstance(m, str))
    ref_layers = [encode_f16(r) for r in refs]
    clipped += sum(c for _, c in ref_layers)
    images.append(
        {
            "label": REFERENCE,
            "spp": scene.reference_spp,
            "caption": f"{scene.reference_spp} spp" if scene.reference_spp else "",
            "frames": [s for s, _ in ref_layers],
        }
    )
    if clipped:
        notes.append(f"{clipped} values beyond ±65504 (float16's range) are stored as ±65504")
    lo, hi = error_scale(strip_maps) if strip_maps else (1e-6, 1e-2)
    ramp = to_uint8(colorbar(256, 1))[0]  # (256, 3)
    return {
        "index": index,
        "id": scene.id,
        "width": w,
        "height": h,
        "frames": n,
        "sequence": bool(scene.is_sequence),
        "exposure": exposure,
        "levels": levels,
        "strip_spp": strip if strip in levels else crop_level,
        "labels": [*result.labels, REFERENCE],
        "error_scale": [lo, hi],
        "colormap": ramp.reshape(-1).tolist(),
        "flip_note": flip_note,
        "flip_spp": crop_level,
        "crops": disagreement_crops(crop_inputs, refs[mid]),
        "crop_spp": crop_level,
        "images": images,
        "notes": notes,
    }


# --- files and HTML -----------------------------------------------------------------------


def _copy_static(folder: Path) -> None:
    templates = resources.files("mcdenoise.experiments").joinpath("templates")
    for name in STATIC_FILES:
        data = templates.joinpath(name).read_bytes()
        target = folder / name
        if not target.is_file() or target.read_bytes() != data:
            write_bytes_atomic(target, data)


def _prune(folder: Path, scenes: int) -> None:
    """Remove the scene files of an earlier report with more scenes."""
    for f in folder.iterdir():
        m = _SCENE_FILE.match(f.name)
        if m and int(m.group(1)) >= scenes and f.is_file():
            f.unlink()


HOW_TO_USE = (
    "<b>How to use the viewer:</b> <kbd>1</kbd>–<kbd>9</kbd> or <kbd>←</kbd>/<kbd>→</kbd> "
    "choose image A, <kbd>↑</kbd>/<kbd>↓</kbd> the spp level, <kbd>r</kbd> flips to the "
    "reference, <kbd>f</kbd> or space flips between A and B, <kbd>s</kbd> side by side or one "
    "at a time, <kbd>e</kbd> the error view (relMSE, FLIP), <kbd>c</kbd> the crops where the "
    "methods disagree most, <kbd>0</kbd> the whole image, <kbd>[</kbd>/<kbd>]</kbd> exposure, "
    "<kbd>,</kbd>/<kbd>.</kbd> frames. Mouse wheel zooms (down to single pixels), drag pans, "
    "double-click resets; both sides move together. Keys act on the viewer under the mouse "
    "or last clicked."
)


def viewer_section(result: Any, scene: Any, index: int, out: Path) -> str:
    """The HTML of the viewer of one scene; writes its data to ``out/viewer/scene_NN.js`` and
    the viewer's script and style next to it (module doc).

    Raises:
        OSError: a file cannot be written (the report's caller reports it).
    """
    folder = Path(out) / VIEWER_DIR
    folder.mkdir(parents=True, exist_ok=True)
    _copy_static(folder)
    _prune(folder, len(result.scenes))
    name = f"scene_{index:02d}.js"
    try:
        data = scene_data(result, scene, index, out)
    except McdenoiseError as err:
        (folder / name).unlink(missing_ok=True)
        return f'<p class="notes">Interactive viewer not available: {esc(err)}</p>'
    text = "mcdViewerRegister(" + json.dumps(data, separators=(",", ":"), allow_nan=False) + ");\n"
    write_text_atomic(folder / name, text)
    stored = sum(len(i.get("frames", ())) for i in data["images"])
    size = len(text) / 1e6
    levels = ", ".join(map(str, data["levels"]))
    return (
        f'<div class="mcdv" id="viewer-{index}" data-src="{VIEWER_DIR}/{name}">'
        f"<h3>Interactive viewer: {esc(scene.id)}</h3>"
        f'<p class="small mcdv-howto">{HOW_TO_USE}</p>'
        '<div class="mcdv-app"><p class="notes mcdv-loading">Loading the viewer (it needs '
        "JavaScript; the images above show one level without it).</p></div>"
        f'<p class="small">Stored in {VIEWER_DIR}/{name} ({size:.1f} MB): the HDR pixels '
        f"(half floats) of {stored} image{'s' if stored != 1 else ''}: the noisy input and "
        f"every output kept at {levels} spp, and the reference"
        + (f", {data['frames']} frames each" if data["frames"] > 1 else "")
        + ("" if data["flip_note"] else f"; FLIP maps (8-bit) at {data['flip_spp']} spp")
        + ".</p></div>"
        f'<link rel="stylesheet" href="{VIEWER_DIR}/viewer.css">'
        f'<script defer src="{VIEWER_DIR}/viewer.js"></script>'
    )
