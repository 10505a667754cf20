"""From unit records to the experiment's findings: curves, Pareto fronts, equal-time and
equal-quality tables, the reference's noise floor, statistics over scenes.

:func:`assemble` takes the records of every (scene, spp, method) unit (as written by
:mod:`mcdenoise.experiments.runner`) and returns an :class:`ExperimentResult`, which
:mod:`mcdenoise.experiments.report` writes out. Per scene:

* the measured **noisy curve** (relMSE of plain rendering per level) with its log-log slope
  and ``1/N`` fit (:mod:`~mcdenoise.experiments.quality`);
* the **reference's noise floor** from its ``color_var``; records within 2× of it are flagged
  ``limited_by_reference``;
* per record the **equal-quality** spp and seconds of plain rendering and the speed-up;
* the **Pareto front** and the **equal-time** table of (total seconds, relMSE)
  (:mod:`~mcdenoise.experiments.tradeoff`).

Over scenes ("overall"): per (method, spp) the mean total seconds and the geometric mean
relMSE over the scenes (only for (method, spp) that succeeded in every scene, so means are
comparable), the geometric means of the equal-quality spp and speed-up, the overall Pareto
front and equal-time table, and the bootstrap statistics of :mod:`~mcdenoise.experiments.stats`
(an :class:`OverallView`), plus the mean bias over scenes (arithmetic mean, with its range).

A scene whose measured noisy curve rises with spp (:func:`~.quality.noisy_rises`: fireflies)
is *flagged*; when some scenes are flagged and others not, the same overall findings are also
computed without the flagged scenes (``ExperimentResult.without_flagged``), so the report can
show both.
"""

from __future__ import annotations

import datetime as _dt
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mcdenoise.eval.results import jsonable
from mcdenoise.eval.temporal_metrics import metric_spec
from mcdenoise.experiments.curves import _noise_floor, _noisy_curve, _points
from mcdenoise.experiments.dataset import Level, SceneData
from mcdenoise.experiments.definitions import RENDER_TIME_UNKNOWN, SEQUENCE_DEFINITIONS, definitions
from mcdenoise.experiments.entries import MethodEntry
from mcdenoise.experiments.provenance import provenance
from mcdenoise.experiments.quality import (
    NoisyCurve,
    equal_quality,
    limited_by_reference,
    noisy_rises,
)
from mcdenoise.experiments.record_values import (
    _geomean,
    _mean,
    _num,
    _short,
    bias_of,
    number,
    relmse_of,
)
from mcdenoise.experiments.sequence_units import TEMPORAL_OVERALL, temporal_rows
from mcdenoise.experiments.shards import hosts_note, timing_hosts
from mcdenoise.experiments.spec import ExperimentSpec
from mcdenoise.experiments.spec_fields import NOISY
from mcdenoise.experiments.stats import RatioStats, compare_methods
from mcdenoise.experiments.tradeoff import (
    EqualTimeRow,
    Point,
    equal_time,
    log_budgets,
    pareto_front,
)

#: Version of the results.json layout of experiments; bump when fields change meaning.
SCHEMA = "mcdenoise.experiment/1"


@dataclass
class SceneSummary:
    """The per-scene findings (see the module docstring)."""

    id: str
    noisy_file: str
    reference_file: str
    reference_spp: int | None
    seed: int | None
    variant: str | None
    levels: tuple[Level, ...]
    noise_floor: float | None
    floor_note: str | None = None
    curve: NoisyCurve | None = None
    budgets: tuple[float, ...] = ()
    pareto: list[Point] = field(default_factory=list)
    equal_time: list[EqualTimeRow] = field(default_factory=list)
    #: where the noisy curve rises with spp: (spp_a, e_a, spp_b, e_b), see ``noisy_rises``
    rises: list[tuple[int, float, int, float]] = field(default_factory=list)
    #: a sequence's frames as (noisy file, reference file); ``()`` for a still image
    frames: tuple[tuple[str, str], ...] = ()

    @property
    def is_sequence(self) -> bool:
        return bool(self.frames)

    @property
    def flagged(self) -> bool:
        """The noisy curve is not monotone (fireflies): see :attr:`flag_reason`."""
        return bool(self.rises)

    @property
    def flag_reason(self) -> str | None:
        """One sentence for the reader: what rose, and why that matters."""
        if not self.rises:
            return None
        where = "; ".join(
            f"from {_num(ea)} at {a} spp to {_num(eb)} at {b} spp" for a, ea, b, eb in self.rises
        )
        return (
            f"The error (relMSE) of plain rendering rises with more samples ({where}), although "
            "Monte Carlo error falls as 1/N on average: a few very bright pixels (fireflies, "
            "rare light paths of high energy) dominate this scene's relMSE, so its numbers, and "
            "every mean over scenes that includes it, depend on where those few samples landed."
        )

    def to_dict(self) -> dict[str, Any]:
        c = self.curve
        return {
            "id": self.id,
            "noisy_file": self.noisy_file,
            "reference_file": self.reference_file,
            "reference_spp": self.reference_spp,
            "seed": self.seed,
            "variant": self.variant,
            "levels": [
                {
                    "spp": lv.spp,
                    "part": lv.part,
                    "render_seconds": lv.render_seconds,
                    "jit_seconds_excluded": lv.jit_seconds,
                }
                for lv in self.levels
            ],
            "noise_floor": self.noise_floor,
            "noise_floor_note": self.floor_note,
            "noisy_curve": None
            if c is None
            else {
                "spp": list(c.spp),
                "relmse": list(c.error),
                "render_seconds": [v if math.isfinite(v) else None for v in c.seconds],
                "loglog_slope": c.slope(),
                "one_over_n_constant": c.one_over_n(),
                "seconds_per_spp": c.seconds_per_spp if math.isfinite(c.seconds_per_spp) else None,
            },
            "flagged": self.flagged,
            "flag_reason": self.flag_reason,
            "noisy_rises": [
                {"from_spp": a, "from_relmse": ea, "to_spp": b, "to_relmse": eb}
                for a, ea, b, eb in self.rises
            ],
            "budgets": list(self.budgets),
            "pareto": [p.to_dict() for p in self.pareto],
            "equal_time": [r.to_dict() for r in self.equal_time],
            **({"frames": [list(f) for f in self.frames]} if self.frames else {}),
        }


@dataclass(frozen=True)
class OverallRow:
    """One (method, spp) over every scene.

    ``relmse`` is the geometric mean over scenes and ``seconds`` the mean total seconds, both
    ``None`` unless the method succeeded in every scene (``complete``); ``eq_spp`` and
    ``speedup`` are geometric means of the per-scene equal-quality values; ``extrapolated`` and
    ``limited`` count the scenes where the equal-quality value was extrapolated / the error
    was within 2× of the reference's noise floor. ``bias`` is the arithmetic mean over the
    scenes of the mean bias, ``bias_min``/``bias_max`` its range (``None`` without values).
    """

    method: str
    spp: int
    scenes: int
    complete: bool
    seconds: float | None
    render_seconds: float | None
    denoise_seconds: float | None
    relmse: float | None
    eq_spp: float | None
    speedup: float | None
    extrapolated: int
    limited: int
    bias: float | None = None
    bias_min: float | None = None
    bias_max: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class OverallView:
    """The findings over a set of scenes: rows, Pareto front, equal time, statistics."""

    scenes: list[str]
    rows: list[OverallRow]
    budgets: tuple[float, ...]
    pareto: list[Point]
    equal_time: list[EqualTimeRow]
    stats: list[RatioStats]

    def to_dict(self) -> dict[str, Any]:
        return {
            "scenes": list(self.scenes),
            "rows": [r.to_dict() for r in self.rows],
            "budgets": list(self.budgets),
            "pareto": [p.to_dict() for p in self.pareto],
            "equal_time": [r.to_dict() for r in self.equal_time],
            "statistics": [s.to_dict() for s in self.stats],
        }


@dataclass
class ExperimentResult:
    """Everything the report shows (see the module docstring)."""

    spec: ExperimentSpec
    created: str
    provenance: dict[str, Any]
    entries: list[MethodEntry]
    skipped: dict[str, str]
    metrics: list[str]
    scenes: list[SceneSummary]
    records: list[dict[str, Any]]
    overall: list[OverallRow]
    overall_budgets: tuple[float, ...]
    overall_pareto: list[Point]
    overall_equal_time: list[EqualTimeRow]
    stats: list[RatioStats]
    baseline: str
    strip_spp: int
    out: Path
    data_folder: Path
    notes: list[str] = field(default_factory=list)
    #: the overall findings without the flagged scenes (``None``: none or all flagged)
    without_flagged: OverallView | None = None
    #: one line per method that does not apply to (some of) the scenes, so did not run there
    #: (:mod:`~mcdenoise.experiments.applicability`)
    not_applicable: list[str] = field(default_factory=list)

    @property
    def flagged(self) -> list[str]:
        """Ids of the flagged scenes (noisy curve not monotone)."""
        return [s.id for s in self.scenes if s.flagged]

    @property
    def view(self) -> OverallView:
        """The overall findings over every scene."""
        return OverallView(
            scenes=[s.id for s in self.scenes],
            rows=self.overall,
            budgets=self.overall_budgets,
            pareto=self.overall_pareto,
            equal_time=self.overall_equal_time,
            stats=self.stats,
        )

    @property
    def labels(self) -> list[str]:
        return [e.label for e in self.entries]

    @property
    def spps(self) -> list[int]:
        return sorted({int(r["spp"]) for r in self.records})

    def record(self, scene: str, spp: int, label: str) -> dict[str, Any] | None:
        for r in self.records:
            if r["scene"] == scene and r["spp"] == spp and r["method"] == label:
                return r
        return None

    def scene_records(self, scene: str) -> list[dict[str, Any]]:
        return [r for r in self.records if r["scene"] == scene]

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict (non-finite numbers as strings, see :mod:`mcdenoise.eval.results`)."""
        return jsonable(
            {
                "schema": SCHEMA,
                "name": self.spec.name,
                "created": self.created,
                "encoding": (
                    'Non-finite numbers are strings: "inf", "-inf", "nan"; missing values are '
                    "null. Times are seconds; errors are relMSE unless named."
                ),
                "provenance": self.provenance,
                "spec": self.spec.to_dict(),
                "definitions": {
                    **definitions(self.metrics),
                    **(SEQUENCE_DEFINITIONS if self.is_sequences else {}),
                },
                "metrics": {m: metric_spec(m).describe() for m in self.metrics},
                "methods": [e.to_dict() for e in self.entries],
                "skipped_methods": [{"label": k, "reason": v} for k, v in self.skipped.items()],
                "not_applicable": self.not_applicable,
                "strip_spp": self.strip_spp,
                "notes": self.notes,
                "scenes": [s.to_dict() for s in self.scenes],
                "records": self.records,
                "overall": {
                    "rows": [r.to_dict() for r in self.overall],
                    "budgets": list(self.overall_budgets),
                    "pareto": [p.to_dict() for p in self.overall_pareto],
                    "equal_time": [r.to_dict() for r in self.overall_equal_time],
                },
                "statistics": {
                    "baseline": self.baseline,
                    "resamples": self.spec.bootstrap,
                    "confidence": self.spec.confidence,
                    "seed": self.spec.stats_seed,
                    "rows": [s.to_dict() for s in self.stats],
                },
                "flagged_scenes": self.flagged,
                "overall_without_flagged": (
                    None if self.without_flagged is None else self.without_flagged.to_dict()
                ),
                **({"temporal": self.temporal_dict()} if self.is_sequences else {}),
            }
        )

    @property
    def render_time_known(self) -> bool:
        """Every level of every scene has its render seconds (not data without manifest)."""
        return all(lv.render_seconds is not None for s in self.scenes for lv in s.levels)

    @property
    def is_sequences(self) -> bool:
        """The scenes are sequences (``[render] frames``)."""
        return any(s.is_sequence for s in self.scenes)

    def temporal_dict(self) -> dict[str, Any]:
        """The over-sequences table of per-frame and temporal errors against time per frame
        (:func:`mcdenoise.experiments.sequence_units.temporal_rows`)."""

        return {
            "warmup_frames": self.spec.warmup_frames,
            "definition": TEMPORAL_OVERALL,
            "rows": temporal_rows(self),
        }


def assemble(
    spec: ExperimentSpec,
    *,
    scenes: Sequence[SceneData],
    entries: Sequence[MethodEntry],
    skipped: Mapping[str, str],
    records: Sequence[Mapping[str, Any]],
    not_applicable: Sequence[str] = (),
    metrics: Sequence[str],
    data_folder: Path,
    strip_spp: int,
    out: Path,
    machine_at_start: Mapping[str, Any] | None = None,
) -> ExperimentResult:
    """Compute every finding from the unit ``records`` (one per scene × level × entry).

    ``machine_at_start`` (:func:`~mcdenoise.experiments.timing.machine_info` taken before the
    units ran) goes into the provenance next to the machine at the end (load averages)."""

    recs = [dict(r) for r in records]
    labels = [e.label for e in entries]
    notes: list[str] = []
    summaries: list[SceneSummary] = []
    for scene in scenes:
        mine = [r for r in recs if r["scene"] == scene.id]
        floor, floor_note = _noise_floor(scene)
        curve = _noisy_curve(mine)
        noisy_at = {r["spp"]: relmse_of(r) for r in mine if r["method"] == NOISY}
        for r in mine:
            e = relmse_of(r)
            n = noisy_at.get(r["spp"])
            r["relmse_vs_noisy"] = e / n if e is not None and n else None
            r["limited_by_reference"] = limited_by_reference(e, floor)
            r["equal_quality"] = None
            if r["method"] != NOISY and e is not None and curve is not None:
                eq = equal_quality(curve, e, number(r.get("total_seconds"))).to_dict()
                if not math.isfinite(curve.seconds_per_spp):  # render time unknown
                    eq["seconds"] = eq["speedup"] = None
                r["equal_quality"] = eq
        points = _points(mine)
        front = pareto_front(points)
        on_front = {(p.method, p.spp) for p in front}
        for r in mine:
            r["pareto"] = (r["method"], r["spp"]) in on_front
        budgets = spec.budgets or log_budgets([p.seconds for p in points])
        summaries.append(
            SceneSummary(
                id=scene.id,
                noisy_file=str(scene.noisy),
                reference_file=str(scene.reference),
                reference_spp=scene.reference_spp,
                seed=scene.seed,
                variant=scene.variant,
                levels=scene.levels,
                noise_floor=floor,
                floor_note=floor_note,
                curve=curve,
                budgets=tuple(budgets),
                pareto=front,
                equal_time=equal_time(points, budgets, noisy_label=NOISY),
                rises=noisy_rises(curve, floor) if curve is not None else [],
                frames=tuple((str(f.noisy), str(f.reference)) for f in scene.frames),
            )
        )
        if curve is None:
            notes.append(f"{scene.id}: no usable noisy curve (every noisy level failed)")

    baseline = spec.baseline
    if baseline not in labels:
        notes.append(
            f"statistics baseline {baseline!r} is not in this run"
            + (f" ({skipped[baseline]})" if baseline in skipped else "")
            + "; ratios are to 'noisy'"
        )
        baseline = NOISY
    every = overall_view(spec, recs, [s.id for s in summaries], labels, baseline)
    kept = [s.id for s in summaries if not s.flagged]
    without = (
        overall_view(spec, recs, kept, labels, baseline)
        if kept and len(kept) < len(summaries)
        else None
    )
    for label, reason in skipped.items():
        notes.append(f"skipped {label}: {reason}")
    for label in labels:
        errs = [r for r in recs if r["method"] == label and r.get("error")]
        if errs:
            reasons = sorted({_short(str(r["error"])) for r in errs})
            notes.append(
                f"{label} could not run on {len(errs)} of "
                f"{sum(1 for r in recs if r['method'] == label)} inputs: "
                + "; ".join(reasons[:3])
                + (f" (+{len(reasons) - 3} more)" if len(reasons) > 3 else "")
            )
    if any(lv.render_seconds is None for s in scenes for lv in s.levels):
        notes.append(RENDER_TIME_UNKNOWN)
    hosts = timing_hosts(recs)
    if (note := hosts_note(hosts)) is not None:
        notes.append(note)
    files = sorted({p for s in scenes for p in s.files()})
    prov = provenance(data_root=data_folder, files=files)
    prov["timing_hosts"] = hosts
    if machine_at_start is not None:
        prov["machine_at_start"] = dict(machine_at_start)
    return ExperimentResult(
        spec=spec,
        created=_dt.datetime.now(_dt.UTC).astimezone().isoformat(timespec="seconds"),
        provenance=prov,
        entries=list(entries),
        skipped=dict(skipped),
        not_applicable=list(not_applicable),
        metrics=list(metrics),
        scenes=summaries,
        records=recs,
        overall=every.rows,
        overall_budgets=every.budgets,
        overall_pareto=every.pareto,
        overall_equal_time=every.equal_time,
        stats=every.stats,
        baseline=baseline,
        strip_spp=strip_spp,
        out=out,
        data_folder=data_folder,
        notes=notes,
        without_flagged=without,
    )


def errors_by_key(recs: Sequence[Mapping[str, Any]]) -> dict[tuple[str, int, str], float]:
    """``(scene, spp, method) -> relMSE`` of every record that has one."""
    return {
        (r["scene"], int(r["spp"]), r["method"]): e for r in recs if (e := relmse_of(r)) is not None
    }


def overall_view(
    spec: ExperimentSpec,
    recs: Sequence[Mapping[str, Any]],
    scenes: Sequence[str],
    labels: Sequence[str],
    baseline: str,
) -> OverallView:
    """The overall findings over ``scenes`` (rows, front, equal time, statistics)."""
    spps = sorted({int(r["spp"]) for r in recs})
    rows = _overall(recs, scenes, labels, spps)
    points = [
        Point(o.method, o.spp, o.seconds, o.relmse)
        for o in rows
        if o.complete and o.seconds is not None and o.relmse is not None
    ]
    budgets = spec.budgets or log_budgets([p.seconds for p in points])
    stats = compare_methods(
        errors_by_key(recs),
        scenes=list(scenes),
        methods=labels,
        spps=spps,
        baseline=baseline,
        resamples=spec.bootstrap,
        confidence=spec.confidence,
        seed=spec.stats_seed,
    )
    return OverallView(
        scenes=list(scenes),
        rows=rows,
        budgets=tuple(budgets),
        pareto=pareto_front(points),
        equal_time=equal_time(points, budgets, noisy_label=NOISY),
        stats=stats,
    )


def _overall(
    recs: Sequence[Mapping[str, Any]],
    scenes: Sequence[str],
    labels: Sequence[str],
    spps: Sequence[int],
) -> list[OverallRow]:
    by_key = {(r["scene"], int(r["spp"]), r["method"]): r for r in recs}
    rows = []
    for label in labels:
        for spp in spps:
            rs = [by_key.get((s, spp, label)) for s in scenes]
            ok = [r for r in rs if r is not None and relmse_of(r) is not None]
            complete = len(ok) == len(scenes) and bool(scenes)
            errs = [relmse_of(r) for r in ok]
            biases = [b for r in ok if (b := bias_of(r)) is not None]
            eqs = [r.get("equal_quality") for r in ok if r.get("equal_quality")]
            eq_spp = (
                _geomean([number(q["spp"]) for q in eqs]) if eqs and len(eqs) == len(ok) else None
            )
            speed = (
                _geomean([number(q["speedup"]) for q in eqs])
                if eqs and len(eqs) == len(ok)
                else None
            )
            rows.append(
                OverallRow(
                    method=label,
                    spp=spp,
                    scenes=len(ok),
                    complete=complete,
                    seconds=_mean([number(r.get("total_seconds")) for r in ok])
                    if complete
                    else None,
                    render_seconds=_mean([number(r.get("render_seconds")) for r in ok])
                    if complete
                    else None,
                    denoise_seconds=float(np.mean([float(r["denoise_seconds"]) for r in ok]))
                    if complete
                    else None,
                    relmse=_geomean(errs) if complete else None,
                    eq_spp=eq_spp if complete else None,
                    speedup=speed if complete else None,
                    extrapolated=sum(1 for q in eqs if q.get("extrapolated")),
                    limited=sum(1 for r in ok if r.get("limited_by_reference")),
                    bias=float(np.mean(biases)) if biases else None,
                    bias_min=min(biases) if biases else None,
                    bias_max=max(biases) if biases else None,
                )
            )
    return rows
