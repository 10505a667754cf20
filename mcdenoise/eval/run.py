"""The evaluation entry points: :func:`evaluate` (stills or a sequence, by the reference) and
:func:`run_eval` (evaluate, then write the report): what ``mcdenoise eval`` calls.

Stills are :func:`mcdenoise.eval.evaluate.evaluate_files`; a reference folder of frames
(``frame_0000.exr``, ...) makes every output a sequence,
:func:`mcdenoise.eval.evaluate_sequences.evaluate_sequences`. Both share the file matching and header
checks of :mod:`mcdenoise.eval.evaluate`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from mcdenoise.eval.evaluate import PathLike, evaluate_files
from mcdenoise.eval.evaluate_sequences import evaluate_sequences, sequence_frames
from mcdenoise.eval.results import EvalResult
from mcdenoise.eval.temporal_metrics import WARMUP_FRAMES


def evaluate(
    reference: PathLike,
    outputs: Sequence[PathLike],
    *,
    inputs: Sequence[PathLike] | None = None,
    metrics: Sequence[str] | None = None,
    progress: bool | str = False,
    force: bool = False,
    warn: Callable[[str], None] | None = None,
    warmup: int = WARMUP_FRAMES,
) -> EvalResult:
    """Evaluate denoised EXR outputs (and their noisy inputs) against references.

    A reference folder of frames (``frame_0000.exr``, ...) is a sequence: every output is a
    folder of frames and the evaluation is
    :func:`~mcdenoise.eval.evaluate_sequences.evaluate_sequences` (per-frame and temporal metrics;
    ``warmup`` is used there only). Anything else is stills:
    :func:`~mcdenoise.eval.evaluate.evaluate_files`, whose docstring gives the matching of
    outputs to references, the scene check (``force``, ``warn``) and the errors raised.
    """
    if sequence_frames(reference) is not None:
        return evaluate_sequences(
            reference,
            outputs,
            inputs=inputs,
            metrics=metrics,
            progress=progress,
            force=force,
            warn=warn,
            warmup=warmup,
        )
    return evaluate_files(
        reference,
        outputs,
        inputs=inputs,
        metrics=metrics,
        progress=progress,
        force=force,
        warn=warn,
    )


def run_eval(
    reference: PathLike,
    outputs: Sequence[PathLike],
    out_dir: PathLike,
    *,
    inputs: Sequence[PathLike] | None = None,
    metrics: Sequence[str] | None = None,
    progress: bool | str = False,
    force: bool = False,
    warn: Callable[[str], None] | None = None,
    warmup: int = WARMUP_FRAMES,
) -> tuple[EvalResult, dict[str, Path]]:
    """:func:`evaluate` then :func:`~mcdenoise.eval.eval_report.write_report` into ``out_dir``.

    Returns:
        The result and the written paths (``json``, ``csv``, ``html``, ``images``).
    """
    from mcdenoise.eval.eval_report import write_report

    result = evaluate(
        reference,
        outputs,
        inputs=inputs,
        metrics=metrics,
        progress=progress,
        force=force,
        warn=warn,
        warmup=warmup,
    )
    return result, write_report(result, out_dir)
