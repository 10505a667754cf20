"""Metrics and reports: compare denoised outputs with references, write JSON, CSV and HTML.

Typical use (what ``mcdenoise eval`` does)::

    from mcdenoise.eval import evaluate, write_report
    result = evaluate("data/samples/ref", ["out/"])     # reference folder, output folder
    write_report(result, "report/")                     # results.json, results.csv, report.html

Sequences (a reference folder of ``frame_0000.exr`` ...) are evaluated the same way, with
temporal metrics and the warm-up frames apart::

    result = evaluate("data/gen/seq_0/ref", ["out_nlm/", "out_svgf/"], warmup=2)

Modules: :mod:`~mcdenoise.eval.metrics` (relMSE, SMAPE, MSE, PSNR, SSIM, FLIP and their
registry), :mod:`~mcdenoise.eval.temporal_metrics` (temporal relMSE, Noisebase's tPSNR and tRMAE,
per-frame metrics of a sequence), :mod:`~mcdenoise.eval.tonemap` (sRGB, exposure, false colour),
:mod:`~mcdenoise.eval.preview` (crop choice), :mod:`~mcdenoise.eval.results` (records and
their JSON form), :mod:`~mcdenoise.eval.run` (the entry points), :mod:`~mcdenoise.eval.steps`
(the options and the steps stills and sequences share), :mod:`~mcdenoise.eval.matching`
(outputs -> references and noisy inputs, from names and headers),
:mod:`~mcdenoise.eval.evaluate` (files and arrays -> records),
:mod:`~mcdenoise.eval.evaluate_sequences` (folders of frames -> records),
:mod:`~mcdenoise.eval.eval_report` (records -> files).
"""

from mcdenoise.eval.eval_report import write_report
from mcdenoise.eval.evaluate import evaluate_arrays, evaluate_files
from mcdenoise.eval.evaluate_sequences import (
    evaluate_sequence_arrays,
    evaluate_sequences,
    sequence_frames,
)
from mcdenoise.eval.matching import match_prefix
from mcdenoise.eval.metrics import (
    METRICS,
    Metric,
    MetricUnavailable,
    MetricValues,
    compute_metrics,
    flip,
    mse,
    psnr,
    relmse,
    relmse_map,
    smape,
    ssim,
)
from mcdenoise.eval.results import (
    EvalRecord,
    EvalResult,
    FrameRecord,
    ScenePreview,
    SequenceDetail,
)
from mcdenoise.eval.run import evaluate, run_eval
from mcdenoise.eval.steps import EvalOptions
from mcdenoise.eval.temporal_metrics import (
    TEMPORAL_METRICS,
    WARMUP_FRAMES,
    SequenceEvaluator,
    SequenceValues,
    sequence_metrics,
    temporal_relmse,
    tpsnr,
    trmae,
)

__all__ = [
    "METRICS",
    "TEMPORAL_METRICS",
    "WARMUP_FRAMES",
    "EvalOptions",
    "EvalRecord",
    "EvalResult",
    "FrameRecord",
    "Metric",
    "MetricUnavailable",
    "MetricValues",
    "ScenePreview",
    "SequenceDetail",
    "SequenceEvaluator",
    "SequenceValues",
    "compute_metrics",
    "evaluate",
    "evaluate_arrays",
    "evaluate_files",
    "evaluate_sequence_arrays",
    "evaluate_sequences",
    "flip",
    "match_prefix",
    "mse",
    "psnr",
    "relmse",
    "relmse_map",
    "run_eval",
    "sequence_frames",
    "sequence_metrics",
    "smape",
    "ssim",
    "temporal_relmse",
    "tpsnr",
    "trmae",
    "write_report",
]
