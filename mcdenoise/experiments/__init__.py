"""Experiments that show what accuracy costs in time: ``mcdenoise experiment SPEC``.

An experiment renders a set of scenes at a ladder of sample counts (through
:mod:`mcdenoise.render`), runs every method of the registry on every level, times render and
denoise separately, measures every metric against the references, and writes a report that
answers "what does accuracy cost?": error against spp and against total time (with the
Pareto front), equal-time and equal-quality tables, the reference's noise floor, and
statistics over scenes. Modules, one concern each:

* :mod:`~mcdenoise.experiments.spec`: the TOML schema and its validation;
* :mod:`~mcdenoise.experiments.dataset`: render what is missing, read the render folder;
* :mod:`~mcdenoise.experiments.runner`: methods and sweeps, units, resume, the entry point;
* :mod:`~mcdenoise.experiments.timing`: warm-up, repetitions, medians, machine;
* :mod:`~mcdenoise.experiments.quality`: noisy curve, equal quality, reference noise floor;
* :mod:`~mcdenoise.experiments.tradeoff`: Pareto front, equal-time tables;
* :mod:`~mcdenoise.experiments.stats`: bootstrap intervals over scenes, wins;
* :mod:`~mcdenoise.experiments.analysis`: records -> findings;
* :mod:`~mcdenoise.experiments.provenance`: versions, git commit, data hash;
* :mod:`~mcdenoise.experiments.plots`, :mod:`~mcdenoise.experiments.report`: the output;
* :mod:`~mcdenoise.experiments.sequence_units`, :mod:`~mcdenoise.experiments.temporal_report`:
  sequences (``[render] frames = N``): one unit per (sequence, spp, method), times per frame,
  per-frame and temporal metrics; the temporal table and plots, x–t slices, animated strips.

Typical use::

    from mcdenoise.experiments import load_experiment, run_experiment
    summary = run_experiment(load_experiment("data/experiments/demo.toml"), "demo-out")
    print(summary.paths["html"])
"""

from mcdenoise.experiments.entries import MethodEntry, plan_methods
from mcdenoise.experiments.runner import RunSummary, run_experiment
from mcdenoise.experiments.spec import ExperimentSpec, Sweep, load_experiment, parse_experiment
from mcdenoise.experiments.spec_fields import ExperimentError

__all__ = [
    "ExperimentError",
    "ExperimentSpec",
    "MethodEntry",
    "RunSummary",
    "Sweep",
    "load_experiment",
    "parse_experiment",
    "plan_methods",
    "run_experiment",
]
