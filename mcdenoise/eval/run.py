"""The evaluation entry points: :func:`evaluate` (stills or a sequence, by the reference) and
:func:`run_eval` (evaluate, then write the report): what ``mcdenoise eval`` calls.

Stills are :func:`mcdenoise.eval.evaluate.evaluate_files`; a reference folder of frames
(``frame_0000.exr``, ...) makes every output a sequence,
:func:`mcdenoise.eval.evaluate_sequences.evaluate_sequences`. Both take one
:class:`~mcdenoise.eval.steps.EvalOptions` and run the steps of :mod:`mcdenoise.eval.steps`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mcdenoise.eval.eval_report import write_report
from mcdenoise.eval.evaluate import evaluate_files
from mcdenoise.eval.evaluate_sequences import evaluate_sequences, sequence_frames
from mcdenoise.eval.matching import PathLike
from mcdenoise.eval.results import EvalResult
from mcdenoise.eval.steps import DEFAULT_OPTIONS, EvalOptions


def evaluate(
    reference: PathLike,
    outputs: Sequence[PathLike],
    options: EvalOptions = DEFAULT_OPTIONS,
    **fields: Any,
) -> EvalResult:
    """Evaluate denoised EXR outputs (and their noisy inputs) against references.

    A reference folder of frames (``frame_0000.exr``, ...) is a sequence: every output is a
    folder of frames and the evaluation is
    :func:`~mcdenoise.eval.evaluate_sequences.evaluate_sequences` (per-frame and temporal
    metrics, the first ``warmup`` frames apart). Anything else is stills:
    :func:`~mcdenoise.eval.evaluate.evaluate_files`, whose docstring gives the matching of
    outputs to references, the scene check (``force``, ``warn``) and the errors raised.

    Args:
        options: how to evaluate (:class:`~mcdenoise.eval.steps.EvalOptions`).
        fields: fields of :class:`~mcdenoise.eval.steps.EvalOptions` that replace those of
            ``options`` (``evaluate(ref, outs, metrics=["relmse"])``).
    """
    options = dataclasses.replace(options, **fields)
    if sequence_frames(reference) is not None:
        return evaluate_sequences(reference, outputs, options)
    return evaluate_files(reference, outputs, options)


def run_eval(
    reference: PathLike,
    outputs: Sequence[PathLike],
    out_dir: PathLike,
    options: EvalOptions = DEFAULT_OPTIONS,
    **fields: Any,
) -> tuple[EvalResult, dict[str, Path]]:
    """:func:`evaluate` then :func:`~mcdenoise.eval.eval_report.write_report` into ``out_dir``.

    Returns:
        The result and the written paths (``json``, ``csv``, ``html``, ``images``).
    """
    result = evaluate(reference, outputs, options, **fields)
    return result, write_report(result, out_dir)
