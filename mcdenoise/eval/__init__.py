"""Metrics and reports: compare denoised outputs with references, write JSON, CSV and HTML.

Typical use (what ``mcdenoise eval`` does)::

    from mcdenoise.eval import evaluate, write_report
    result = evaluate("data/samples/ref", ["out/"])     # reference folder, output folder
    write_report(result, "report/")                     # results.json, results.csv, report.html

Modules: :mod:`~mcdenoise.eval.metrics` (relMSE, SMAPE, MSE, PSNR, SSIM, FLIP and their
registry), :mod:`~mcdenoise.eval.tonemap` (sRGB, exposure, false colour),
:mod:`~mcdenoise.eval.preview` (crop choice), :mod:`~mcdenoise.eval.results` (records and
their JSON form), :mod:`~mcdenoise.eval.evaluate` (files and arrays -> records),
:mod:`~mcdenoise.eval.report` (records -> files).
"""

from mcdenoise.eval.evaluate import evaluate, evaluate_arrays, match_prefix, run_eval
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
from mcdenoise.eval.report import write_report
from mcdenoise.eval.results import EvalRecord, EvalResult, ScenePreview

__all__ = [
    "METRICS",
    "EvalRecord",
    "EvalResult",
    "Metric",
    "MetricUnavailable",
    "MetricValues",
    "ScenePreview",
    "compute_metrics",
    "evaluate",
    "evaluate_arrays",
    "flip",
    "match_prefix",
    "mse",
    "psnr",
    "relmse",
    "relmse_map",
    "run_eval",
    "smape",
    "ssim",
    "write_report",
]
