"""What the report's numbers mean: the definition of every metric, time and ratio an experiment
reports, for stills and for sequences (shown under each table and in ``results.json``).
"""

from __future__ import annotations

from collections.abc import Sequence

from mcdenoise.eval.temporal_metrics import metric_spec
from mcdenoise.experiments.quality import (
    FLOOR_FACTOR,
)


def definitions(metrics: Sequence[str]) -> dict[str, str]:
    """How every derived number is defined (results.json and the report state them)."""
    return {
        "render_seconds": (
            "cumulative wall seconds of Mitsuba rendering up to this spp level (progressive "
            "levels: level n contains the samples of the lower levels), JIT kernel compilation "
            "and scene loading excluded; from the render folder's manifest.json (null, "
            "unknown, for data without one)"
        ),
        "denoise_seconds": (
            "median wall seconds of the method over the timed repetitions (warm-up runs "
            "excluded; method only, no file I/O); 0 for noisy"
        ),
        "total_seconds": "render_seconds + denoise_seconds",
        "relmse_vs_noisy": "relMSE of the record / relMSE of the noisy image at the same spp",
        "equal_quality": (
            "spp plain rendering needs for the same relMSE, from the scene's measured noisy "
            "curve (log-log interpolation between levels; 1/N law anchored at the highest "
            "level beyond it, flagged 'extrapolated', or at the lowest level below it, flagged "
            "'below ladder'); seconds = spp x the seconds per spp of plain rendering at the "
            "highest level; speedup = those seconds / total_seconds"
        ),
        "noise_floor": (
            "expected relMSE of the reference itself: mean(color_var / (ref^2 + 0.01)) over "
            "pixels and channels, color_var being the reference's variance of the mean; "
            f"records with relMSE below {FLOOR_FACTOR:g}x the floor are 'limited by the "
            "reference'"
        ),
        "pareto": "no other (method, spp) is at least as fast and at least as accurate",
        "equal_time": "lowest relMSE among the (method, spp) whose total_seconds fit the budget",
        "statistics": (
            "ratio = geometric mean over scenes of relMSE(method) / relMSE(baseline) at the "
            "same spp, percentile bootstrap interval over scenes (seeded); wins = scenes where "
            "the method has the lowest relMSE of all methods at that spp"
        ),
        "mean_bias": (
            "output mean / reference mean - 1 (metric 'bias', per channel 'bias_r', 'bias_g', "
            "'bias_b'); over scenes: the arithmetic mean of the scenes' values and their range; "
            "the report names every method whose |bias| exceeds 2 %"
        ),
        "flagged": (
            "a scene whose measured noisy relMSE rises from one spp level to the next (outside "
            f"{FLOOR_FACTOR:g}x the reference's noise floor): fireflies dominate its error; the "
            "overall findings are also given without the flagged scenes"
        ),
        "metrics": ", ".join(f"{metric_spec(m).label}: {metric_spec(m).space}" for m in metrics),
    }


#: The report's note when the data came without render seconds.
RENDER_TIME_UNKNOWN = (
    "render time unknown: the data came without a manifest.json recording how long each "
    "level took to render (a folder of inputs and references), so total times, Pareto fronts, "
    "equal-time tables and equal-quality seconds and speed-ups are not computed; errors, the "
    "equal-quality spp and the denoise times are"
)


#: Added to :func:`definitions` when the experiment's scenes are sequences.
SEQUENCE_DEFINITIONS = {
    "sequences": (
        "each scene is a sequence of frames; one (scene, spp, method) runs the method over "
        "the whole sequence, a temporal method with its history, a per-frame method on each "
        "frame alone; every time is per frame"
    ),
    "render_seconds per frame": (
        "mean over the frames of each frame's cumulative render seconds at this level, JIT "
        "excluded frame by frame"
    ),
    "denoise_seconds per frame": (
        "the method's seconds summed over the frames of one run and divided by their number; "
        "median over the timed runs of the whole sequence"
    ),
    "per-frame metrics": (
        "still metrics of every frame against its reference, averaged over the frames past "
        "the warm-up (the first warmup_frames frames, reported apart as 'warm-up')"
    ),
    "temporal metrics": (
        "temporal relMSE, tPSNR and tRMAE of mcdenoise.eval.temporal_metrics (frame differences of "
        "the output against the reference's), averaged over the frame pairs past the warm-up"
    ),
}
