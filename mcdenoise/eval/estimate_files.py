"""Reference-free error estimates of output files on disk (``mcdenoise eval`` without
``--ref``): one row per output of ``mcdenoise denoise``, its method run again on each half
and normalised as :mod:`mcdenoise.eval.estimate` explains, and one row per noisy input."""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from torch import Tensor

from mcdenoise.errors import InputError, McdenoiseError
from mcdenoise.eval.estimate import (
    MATCHED,
    OWN_OLD,
    SHARED_WARNING,
    ErrorEstimate,
    estimate_from_outputs,
    matched_normaliser,
    pseudo_reference,
    shown_value,
    split_halves,
)
from mcdenoise.io import load_buffers, probe_exr
from mcdenoise.io.buffers import (
    FeatureBuffers,
    check_halves,
    has_halves,
    sanitize,
    shared_guides,
)
from mcdenoise.registry import header_method

if TYPE_CHECKING:
    from mcdenoise.method import Method


def estimate_noisy(
    buffers: FeatureBuffers, pseudo_reference: Tensor | None = None
) -> ErrorEstimate:
    """The estimated error of the noisy input itself (the identity on each half:
    ``¼(A − B)²`` per pixel, unbiased for the variance of ``color``), normalised by
    ``pseudo_reference`` (e.g. the median of denoised outputs of it) or else by ``color``
    (whose square its own noise inflates: an underestimate at low spp)."""
    check_halves(buffers)
    if not has_halves(buffers):
        raise InputError(f"{buffers.source or 'input'}: no half buffers (color_a, color_b)")
    return estimate_from_outputs(
        buffers["color_a"], buffers["color_b"], buffers, output=pseudo_reference
    )


#: Runs a method again: ``(half input, the method, its recorded parameters) -> (3, H, W)``;
#: the method is the one the output's header names, looked up with
#: :func:`mcdenoise.registry.header_method` (never an external command).
Rerun = Callable[[FeatureBuffers, "Method", dict[str, Any]], Tensor]


def estimate_files(
    outputs: Sequence[str | os.PathLike[str]],
    *,
    rerun: Rerun | None = None,
    log: Callable[[str], None] | None = None,
) -> list[dict[str, Any]]:
    """One row per output of ``mcdenoise denoise`` (files or folders of them), and one
    ``noisy`` row per source input that has halves (:func:`estimate_noisy`). Every row is
    marked ``"estimated": True`` and names its ``normaliser``; nothing here is measured
    against a reference.

    Where two or more outputs of one input with halves are given, every one of them (and the
    noisy input) is normalised by one :func:`pseudo_reference`, the pixelwise median of those
    outputs (:func:`matched_normaliser` of it): ``rerun`` runs the method recorded in each
    output's header (``mcdenoise:method``, ``mcdenoise:params``) again on each half of the
    source to get the per-pixel squared error (``--estimate-error`` keeps only its scalar),
    so this costs two runs of every method; ``log`` is told before each. (``rerun`` is
    passed in, e.g. by ``mcdenoise eval``, so that this module does not import the denoisers.)
    One output alone, no ``rerun``, or a method that cannot run again keeps the estimate
    ``--estimate-error`` recorded in its header (normalised by the output itself). An output
    without an estimate gets a row whose note says so.
    """

    files: list[Path] = []
    for p in map(Path, outputs):
        files += sorted(p.glob("*.exr")) if p.is_dir() else [p]
    rows: list[dict[str, Any]] = []
    sources: dict[tuple[str, str | None, str | None], list[tuple[Path, dict[str, Any]]]] = {}
    for f in files:
        attrs = probe_exr(f)[0].attributes
        scene = str(attrs.get("mcdenoise:image") or attrs.get("mcdenoise:scene") or f.stem)
        row: dict[str, Any] = {
            "scene": scene,
            "method": str(attrs.get("mcdenoise:method", "?")),
            "spp": attrs.get("mcdenoise:spp"),
            "relmse_estimated": _number(attrs.get("mcdenoise:relmse_estimated")),
            "relmse_estimated_upper": _number(attrs.get("mcdenoise:relmse_estimated_upper")),
            "relmse_estimated_se": _number(attrs.get("mcdenoise:relmse_estimated_se")),
            "estimate_of": attrs.get("mcdenoise:estimate_of"),
            "normaliser": str(attrs.get("mcdenoise:estimate_normaliser", OWN_OLD))
            if _has_estimate(attrs)
            else "",
            "file": str(f),
            "warning": str(attrs.get("mcdenoise:estimate_warning") or ""),
            "note": "",
            "estimated": True,
        }
        if not _has_estimate(attrs):
            row["note"] = str(
                attrs.get("mcdenoise:estimate_note")
                or "no estimate: denoise with --estimate-error (an input with halves)"
            )
        rows.append(row)
        src = attrs.get("mcdenoise:source")
        if src:
            part, prof = attrs.get("mcdenoise:source_part"), attrs.get("mcdenoise:source_profile")
            key = (str(src), None if part is None else str(part), prof and str(prof))
            sources.setdefault(key, []).append((f, {**attrs, "_row": row}))
    for (src, part, prof), outs in sources.items():
        try:
            fb = load_buffers(src, part=part, profile=prof or "auto")
        except (McdenoiseError, OSError) as err:  # a moved or unreadable source: say so
            msg = " ".join(str(err).split())
            rows.append({**_noisy_row(src, None), "note": f"source not read: {msg}"})
            continue
        if not has_halves(fb):
            continue
        colors = [load_buffers(o)["color"] for o, _ in outs]
        pseudo = matched_normaliser(pseudo_reference(colors), sanitize(fb)[0]["color"])
        shared = f"median of {len(colors)} outputs, {MATCHED}"
        if len(colors) > 1 and rerun is not None:
            _renormalise(fb, outs, pseudo, shared, rerun, log)
        est = estimate_noisy(fb, pseudo)
        rows.append(
            {
                **_noisy_row(src, fb),
                **_values(est),
                "estimate_of": "noisy input",
                "normaliser": shared if len(colors) > 1 else f"the output, {MATCHED}",
            }
        )
    rows.sort(key=lambda r: (r["scene"], r["spp"] or 0, r["method"] != "noisy", r["method"]))
    return rows


def _renormalise(
    fb: FeatureBuffers,
    outs: Sequence[tuple[Path, dict[str, Any]]],
    pseudo: Tensor,
    shared: str,
    rerun: Rerun,
    log: Callable[[str], None] | None,
) -> None:
    """Each output's row of ``outs`` re-estimated with ``pseudo`` as normaliser: its method
    (from the header) run again on each half of ``fb``; a row whose method cannot run again
    keeps its own-normalised estimate, with a note saying why. A header naming an external
    command or a method not installed here is refused (:func:`mcdenoise.registry.
    header_method`: a file never makes mcdenoise run a program), told to ``log`` in one line
    naming the file."""

    half_a, half_b = split_halves(fb)
    clean, _ = sanitize(fb)
    for f, attrs in outs:
        row = attrs["_row"]
        if not _has_estimate(attrs):
            continue
        method = row["method"]
        try:
            m = header_method(method, str(f))
        except InputError as err:
            row["note"] = f"own normaliser: {' '.join(str(err).split())}"
            if log is not None:
                log(" ".join(str(err).split()))
            continue
        try:
            params = _header_params(attrs.get("mcdenoise:params"))
            if log is not None:
                log(f"{f.name}: {method} on each half of its source (shared normaliser)")
            out_a, out_b = rerun(half_a, m, params), rerun(half_b, m, params)
        except (McdenoiseError, ValueError, TypeError) as err:
            # TypeError: a header's parameter of the wrong JSON type (features = 5)
            row["note"] = (
                f"own normaliser: {method} did not run again: {' '.join(str(err).split())}"
            )
            continue
        est = estimate_from_outputs(out_a, out_b, clean, normaliser=pseudo)
        header = shown_value(row)
        guides = shared_guides(fb, (*m.requires, *m.uses))
        row.update(
            **_values(est),
            normaliser=shared,
            note=f"header value {header} ({row['normaliser']})",
            warning=SHARED_WARNING.format(", ".join(guides)) if guides else "",
        )


def _number(value: Any) -> float | None:
    """A header's number as a float; anything else (a file may come from anyone: a string,
    a vector) as ``None``, i.e. no value."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value)


def _has_estimate(attrs: dict[str, Any]) -> bool:
    """Whether an output's header holds an estimate (a value or an upper bound)."""
    return any(
        _number(attrs.get(f"mcdenoise:{k}")) is not None
        for k in ("relmse_estimated", "relmse_estimated_upper")
    )


def _values(est: ErrorEstimate) -> dict[str, Any]:
    """A row's estimate fields from ``est``: the value, or its upper bound below its noise."""
    d = est.to_dict()
    return {
        "relmse_estimated": d["relmse_estimated"],
        "relmse_estimated_upper": d.get("relmse_estimated_upper"),
        "relmse_estimated_se": d["relmse_estimated_se"],
    }


def _header_params(text: Any) -> dict[str, Any]:
    """The parameters an output's header records (``mcdenoise:params``): a JSON object, or
    ``ValueError`` in one line (a file may come from anyone: a list, a string or JSON nested
    past Python's recursion limit is refused, not an internal error)."""

    try:
        params = json.loads(str(text or "{}"))
    except RecursionError:
        raise ValueError("header mcdenoise:params is nested too deeply") from None
    if not isinstance(params, dict):
        raise ValueError(
            f"header mcdenoise:params is not a JSON object (a {type(params).__name__})"
        )
    return params


def _noisy_row(src: str, fb: FeatureBuffers | None) -> dict[str, Any]:
    attrs = fb.attributes if fb is not None else {}
    scene = attrs.get("mcdenoise:image") or attrs.get("mcdenoise:scene") or Path(src).stem
    return {
        "scene": str(scene),
        "method": "noisy",
        "spp": fb.spp if fb is not None else None,
        "relmse_estimated": None,
        "relmse_estimated_upper": None,
        "relmse_estimated_se": None,
        "estimate_of": None,
        "normaliser": "",
        "file": src,
        "warning": "",
        "note": "",
        "estimated": True,
    }
