"""Robustness of every method against OIDN and against more samples (issue 22, item 3).

Reads the ``results.csv`` of one or more experiment folders (written by ``mcdenoise eval
--experiment SPEC -o DIR``; columns in :data:`mcdenoise.experiments.report_tables.CSV_HEAD`) and
prints, for every method, scene and spp level, the ratio of its relMSE to OIDN's at the same
level, with the violations of the issue's three rules:

(a) **blow-up**: from 2 spp on, a method's relMSE is above 3x OIDN's at that level;
(b) **no gain from more samples**: wherever the noisy input's relMSE falls by at least 1.5x
    from N to 2N spp, a method's relMSE at 2N is above 1.1x its own relMSE at N;
(c) **worse than no denoising**: a method's relMSE is above the noisy input's at that level.

OIDN is a method like the others for rules (b) and (c) (its ratio to itself is 1). Sweep
entries (``xbf[kernel_size=11]``) are methods too: a user can pick them. A unit that did not
produce a relMSE (the method refused the input, or the metric failed) breaks no rule; it is
listed under "not measured". A non-finite relMSE (an output with NaN/inf) breaks (a) and (c).

Output: a markdown table of ratios per scene (violations in bold with their rule letters;
the noisy row marks with ``↓`` the levels where rule (b) applies), the list of violations
(worst first), and the counts per rule and per method; with several folders, a last table
compares their counts (e.g. a baseline and a re-measure). ``--json FILE`` (``-`` for stdout)
writes everything as JSON. The exit status is 0 whatever the counts (this is a benchmark,
not a test); 2 when an input cannot be read.

``--run SPEC -o DIR`` first runs the experiment (``demo`` names data/experiments/demo.toml)
with one torch thread, as ``mcdenoise experiment SPEC -o DIR --threads 1`` does.
``--renders SRC`` copies the render folder of an earlier experiment (``SRC/data``) into
``DIR/data`` first and uses it as the experiment's ``[scenes] folder``, so a re-measure after
a code change re-denoises every unit but renders nothing. ``DIR`` must be new: the runner
reuses a unit whose record has the same fingerprint, and the fingerprint holds the mcdenoise
version, not the code, so the folder of an earlier run would give the earlier code's numbers
(``--resume`` continues an interrupted run of the same code). Only relMSE is read here, so
each unit is timed once without warm-up (``--repetitions 3 --warmup 1`` for the demo's
timing); the denoisers are deterministic, so relMSE does not depend on it.

    python benchmarks/bench_robust.py /tmp/work/demo-base
    python benchmarks/bench_robust.py BASE NEW --json robust.json   # + relMSE NEW/BASE per method, spp
    python benchmarks/bench_robust.py BASE --run robust -o NEW --renders BASE --spp 16,64
    python benchmarks/bench_robust.py --run demo -o /tmp/work/demo-new --renders /tmp/work/demo-base
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import shutil
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
EXPERIMENTS = REPO / "data" / "experiments"

NOISY = "noisy"  # mcdenoise.experiments.spec_fields.NOISY (not imported: reading needs no torch)
RULES = {
    "a": "from 2 spp on, relMSE > 3x OIDN's at that level",
    "b": "noisy relMSE falls >= 1.5x from N to 2N spp, method relMSE at 2N > 1.1x its own at N",
    "c": "relMSE > the noisy input's at that level",
}


class InputError(Exception):
    """An experiment folder or spec that cannot be read (one line for the user)."""


@dataclass(frozen=True)
class Thresholds:
    """The issue's bounds (defaults) for the three rules."""

    oidn_factor: float = 3.0  # (a)
    from_spp: int = 2  # (a) applies from this spp on
    noisy_drop: float = 1.5  # (b) the noisy input must fall by at least this factor ...
    rise: float = 1.1  # (b) ... and the method must not rise above this factor
    # (c) has no parameter: method relMSE > noisy relMSE


@dataclass(frozen=True)
class Violation:
    rule: str
    method: str
    scene: str
    spp: int
    relmse: float
    bound: float  # the value it exceeded (3x OIDN's, 1.1x its own at N, the noisy input's)
    factor: float  # relmse / the compared value (OIDN's, its own at N, the noisy input's)
    against: str  # what was compared, in words

    def to_dict(self) -> dict[str, Any]:
        return {k: _json_float(v) for k, v in dataclasses.asdict(self).items()}


@dataclass
class Analysis:
    """The rules checked on one experiment folder."""

    folder: str
    baseline: str
    scenes: list[str]
    spps: list[int]
    methods: list[str]  # in the order of results.csv, noisy first when present
    relmse: dict[tuple[str, str, int], float]  # (scene, method, spp) -> relMSE
    violations: list[Violation] = field(default_factory=list)
    not_measured: list[tuple[str, str, int, str]] = field(default_factory=list)
    unchecked: list[str] = field(default_factory=list)  # rules that could not be checked
    partial: bool = False  # read from work/ records: the experiment is still running

    def ratio(self, scene: str, method: str, spp: int) -> float | None:
        v = self.relmse.get((scene, method, spp))
        b = self.relmse.get((scene, self.baseline, spp))
        if v is None or b is None:
            return None
        return _div(v, b)

    def counts(self) -> dict[str, int]:
        out = dict.fromkeys(RULES, 0)
        for v in self.violations:
            out[v.rule] += 1
        return out

    def by_method(self) -> dict[str, dict[str, int]]:
        out = {m: dict.fromkeys(RULES, 0) for m in self.methods if m != NOISY}
        for v in self.violations:
            out[v.method][v.rule] += 1
        return out

    def marks(self) -> dict[tuple[str, str, int], str]:
        out: dict[tuple[str, str, int], str] = {}
        for v in self.violations:
            key = (v.scene, v.method, v.spp)
            out[key] = "".join(sorted(out.get(key, "") + v.rule))
        return out

    def to_dict(self) -> dict[str, Any]:
        return {
            "folder": self.folder,
            "partial": self.partial,
            "baseline": self.baseline,
            "scenes": self.scenes,
            "spp": self.spps,
            "methods": self.methods,
            "counts": self.counts(),
            "total": len(self.violations),
            "by_method": self.by_method(),
            "unchecked": self.unchecked,
            "cells": [
                {
                    "scene": s,
                    "method": m,
                    "spp": n,
                    "relmse": _json_float(v),
                    "ratio": _json_float(self.ratio(s, m, n)),
                }
                for (s, m, n), v in sorted(self.relmse.items(), key=self._order)
            ],
            "violations": [v.to_dict() for v in self.violations],
            "not_measured": [
                {"scene": s, "method": m, "spp": n, "reason": r} for s, m, n, r in self.not_measured
            ],
        }

    def _order(self, item: tuple[tuple[str, str, int], float]) -> tuple[int, int, int]:
        (s, m, n), _ = item
        return self.scenes.index(s), self.methods.index(m), self.spps.index(n)


# --- reading ------------------------------------------------------------------------------


def _float(text: str | None) -> float | None:
    """A relMSE cell: '' -> None; 'inf'/'nan' (mcdenoise.eval.results.encode_float) parse."""
    if text is None or text.strip() == "":
        return None
    return float(text)


def _json_float(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)
    return v


def _div(a: float, b: float) -> float:
    if b > 0:
        return a / b
    return math.inf if a > 0 else (1.0 if a == b else 0.0)


def read_rows(folder: Path) -> tuple[list[dict[str, Any]], bool]:
    """``(rows, partial)``: one row per unit with scene, method, spp, relmse (float or None)
    and reason; from ``results.csv``, or from the unit records in ``work/`` while the
    experiment is still running (``partial``)."""
    path = folder / "results.csv" if folder.is_dir() else folder
    if path.is_file():
        try:
            with path.open(newline="", encoding="utf-8") as f:
                table = list(csv.DictReader(f))
        except (OSError, UnicodeDecodeError, csv.Error) as err:
            raise InputError(f"{path}: cannot read: {err}") from None
        need = {"scene", "method", "spp", "relmse"}
        if not table or not need <= set(table[0]):
            raise InputError(
                f"{path}: not an experiment's results.csv (needs the columns "
                f"{', '.join(sorted(need))})"
            )
        rows = []
        for r in table:
            try:
                rows.append(
                    {
                        "scene": r["scene"],
                        "method": r["method"],
                        "spp": int(r["spp"]),
                        "relmse": _float(r["relmse"]),
                        "reason": r.get("error") or r.get("reason") or "no relMSE",
                    }
                )
            except ValueError as err:
                raise InputError(
                    f"{path}: bad row {r.get('scene')}/{r.get('spp')}: {err}"
                ) from None
        return rows, False
    work = folder / "work"
    records = sorted(work.glob("*/spp*/*.json")) if work.is_dir() else []
    if not records:
        raise InputError(f"{folder}: no results.csv and no unit records in {work}")
    rows = []
    for p in records:
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
            relmse = (d.get("metrics") or {}).get("relmse")
            rows.append(
                {
                    "scene": d["scene"],
                    "method": d["method"],
                    "spp": int(d["spp"]),
                    "relmse": None if relmse is None else float(relmse),
                    "reason": d.get("error") or d.get("reason") or "no relMSE",
                }
            )
        except (OSError, ValueError, KeyError, TypeError):
            continue  # a record being written: the next read sees it
    return rows, True


# --- the rules ----------------------------------------------------------------------------


def analyse(
    rows: Iterable[dict[str, Any]],
    *,
    folder: str = "",
    baseline: str = "oidn",
    thresholds: Thresholds = Thresholds(),
    partial: bool = False,
) -> Analysis:
    """Check the three rules on the unit rows of one experiment (see the module docstring)."""
    scenes: list[str] = []
    methods: list[str] = []
    spps: set[int] = set()
    relmse: dict[tuple[str, str, int], float] = {}
    not_measured: list[tuple[str, str, int, str]] = []
    for r in rows:
        s, m, n, v = r["scene"], r["method"], int(r["spp"]), r["relmse"]
        if s not in scenes:
            scenes.append(s)
        if m not in methods:
            methods.append(m)
        spps.add(n)
        if v is None or (math.isnan(v) and m == NOISY):
            not_measured.append((s, m, n, str(r.get("reason") or "no relMSE")))
        else:
            relmse[(s, m, n)] = float(v)
    if NOISY in methods:
        methods.remove(NOISY)
        methods.insert(0, NOISY)
    a = Analysis(
        folder=folder,
        baseline=baseline,
        scenes=scenes,
        spps=sorted(spps),
        methods=methods,
        relmse=relmse,
        not_measured=not_measured,
        partial=partial,
    )
    if baseline not in methods:
        a.unchecked.append(f"a: no {baseline} rows (pyoidn not installed?)")
    if NOISY not in methods:
        a.unchecked += ["b: no noisy rows", "c: no noisy rows"]
    t = thresholds
    for s in scenes:
        for m in methods:
            if m == NOISY:
                continue
            for n in a.spps:
                v = relmse.get((s, m, n))
                if v is None:
                    continue
                bad = math.isnan(v)  # NaN compares False: count it where a number would fail
                base = relmse.get((s, baseline, n))
                if m != baseline and n >= t.from_spp and base is not None:
                    if bad or v > t.oidn_factor * base:
                        a.violations.append(
                            Violation(
                                "a", m, s, n, v, t.oidn_factor * base, _div(v, base), baseline
                            )
                        )
                noisy = relmse.get((s, NOISY, n))
                if noisy is not None and (bad or v > noisy):
                    a.violations.append(Violation("c", m, s, n, v, noisy, _div(v, noisy), NOISY))
                half = n // 2
                prev, noisy_prev = relmse.get((s, m, half)), relmse.get((s, NOISY, half))
                if n % 2 or prev is None or noisy_prev is None or noisy is None:
                    continue
                if noisy_prev >= t.noisy_drop * noisy and (bad or v > t.rise * prev):
                    a.violations.append(
                        Violation("b", m, s, n, v, t.rise * prev, _div(v, prev), f"{half} spp")
                    )
    return a


def b_applies(a: Analysis, scene: str, spp: int, t: Thresholds = Thresholds()) -> bool:
    """Whether rule (b) is checked at ``spp`` (the noisy input fell >= 1.5x from spp/2)."""
    cur, prev = a.relmse.get((scene, NOISY, spp)), a.relmse.get((scene, NOISY, spp // 2))
    return spp % 2 == 0 and cur is not None and prev is not None and prev >= t.noisy_drop * cur


# --- printing -----------------------------------------------------------------------------


def _num(v: float | None) -> str:
    if v is None:
        return "–"
    if not math.isfinite(v):
        return str(v)
    if v == 0:
        return "0"
    if abs(v) >= 100:
        return f"{v:.0f}"
    if abs(v) >= 10:
        return f"{v:.1f}"
    if abs(v) >= 0.1:
        return f"{v:.2f}"
    return f"{v:.3g}"


def format_table(a: Analysis, values: str = "ratio") -> str:
    """The markdown table of one experiment: ratios to the baseline (or relMSE values)."""
    marks = a.marks()
    head = f"| scene | method | {' | '.join(f'{n} spp' for n in a.spps)} |"
    lines = [head, "|" + "---|" * (len(a.spps) + 2)]
    for s in a.scenes:
        for m in a.methods:
            if not any((s, m, n) in a.relmse for n in a.spps) and not any(
                x[:3] == (s, m, n) for x in a.not_measured for n in a.spps
            ):
                continue
            cells = []
            for n in a.spps:
                v = a.relmse.get((s, m, n))
                if values == "ratio" and a.baseline in a.methods:
                    shown = a.ratio(s, m, n)
                else:
                    shown = v
                text = _num(shown) if v is not None else "–"
                if (s, m, n) in marks:
                    text = f"**{text}** {marks[(s, m, n)]}"
                elif m == NOISY and b_applies(a, s, n):
                    text += " ↓"
                cells.append(text)
            lines.append(f"| {s} | {m} | {' | '.join(cells)} |")
    return "\n".join(lines)


def format_violations(a: Analysis, top: int | None = None) -> str:
    rows = sorted(a.violations, key=lambda v: -v.factor if not math.isnan(v.factor) else -1e300)
    if top is not None:
        rows = rows[:top]
    lines = [
        "| rule | method | scene | spp | relMSE | × compared | compared with |",
        "|---|---|---|---|---|---|---|",
    ]
    for v in rows:
        lines.append(
            f"| {v.rule} | {v.method} | {v.scene} | {v.spp} | {_num(v.relmse)} | "
            f"{_num(v.factor)} | {v.against} |"
        )
    return "\n".join(lines)


def format_counts(a: Analysis) -> str:
    lines = ["| method | (a) | (b) | (c) | total |", "|---|---|---|---|---|"]
    for m, c in a.by_method().items():
        lines.append(f"| {m} | {c['a']} | {c['b']} | {c['c']} | {sum(c.values())} |")
    c = a.counts()
    lines.append(
        f"| **all** | **{c['a']}** | **{c['b']}** | **{c['c']}** | **{sum(c.values())}** |"
    )
    return "\n".join(lines)


def _short(reason: str) -> str:
    """A refusal's first clause without the file's path (the JSON keeps it whole)."""
    head = reason.split("; ")[0]
    path, sep, rest = head.partition(": ")
    return rest if sep and ("/" in path or path.endswith(".exr")) else head


def _grouped(rows: Sequence[tuple[str, str, int, str]]) -> dict[tuple[str, str, str], list[int]]:
    out: dict[tuple[str, str, str], list[int]] = {}
    for s, m, n, reason in rows:
        out.setdefault((s, m, _short(reason)), []).append(n)
    return out


def relmse_changes(
    base: Analysis, new: Analysis
) -> dict[str, dict[int, tuple[float, float, str, int]]]:
    """Per method and spp: ``(geometric mean over scenes of new/base relMSE, worst ratio,
    its scene, number of scenes)``, over the units measured in both (the issue's other
    target: the shipped defaults may not get worse at 16 and 64 spp by more than 2 %)."""
    out: dict[str, dict[int, tuple[float, float, str, int]]] = {}
    for m in new.methods:
        if m == NOISY or m not in base.methods:
            continue
        for n in new.spps:
            pairs = [
                (s, new.relmse[(s, m, n)] / base.relmse[(s, m, n)])
                for s in new.scenes
                if (s, m, n) in new.relmse
                and (s, m, n) in base.relmse
                and base.relmse[(s, m, n)] > 0
                and math.isfinite(new.relmse[(s, m, n)])
            ]
            if pairs:
                geo = math.exp(sum(math.log(r) for _, r in pairs) / len(pairs))
                scene, worst = max(pairs, key=lambda p: p[1])
                out.setdefault(m, {})[n] = (geo, worst, scene, len(pairs))
    return out


def format_changes(analyses: Sequence[Analysis]) -> str:
    """relMSE of each later folder over the first's: geometric mean over scenes, and the
    worst scene, per method and spp."""
    base = analyses[0]
    out = []
    for new in analyses[1:]:
        ch = relmse_changes(base, new)
        spps = sorted({n for d in ch.values() for n in d})
        out.append(
            f"relMSE of {new.folder} over {base.folder} (geometric mean over scenes; "
            "worst scene):\n"
        )
        out.append(f"| method | {' | '.join(f'{n} spp' for n in spps)} |")
        out.append("|---|" + "---|" * len(spps))
        for m, d in ch.items():
            cells = [f"{d[n][0]:.3f} ({d[n][1]:.2f} {d[n][2]})" if n in d else "–" for n in spps]
            out.append(f"| {m} | {' | '.join(cells)} |")
    return "\n".join(out)


def format_report(
    analyses: Sequence[Analysis], values: str = "ratio", top: int | None = None
) -> str:
    out = []
    for a in analyses:
        what = (
            "relMSE"
            if values != "ratio" or a.baseline not in a.methods
            else f"relMSE / {a.baseline}'s"
        )
        state = " (PARTIAL: read from work/, the experiment is still running)" if a.partial else ""
        out.append(f"## {a.folder}{state}\n")
        out.append(
            f"{len(a.scenes)} scene(s), spp {', '.join(map(str, a.spps))}, "
            f"{len(a.methods)} row label(s). Cells: {what} at the same spp; **bold** + letters: "
            "the rules it breaks; ↓ on the noisy row: rule (b) is checked at that level.\n"
        )
        out.append(format_table(a, values) + "\n")
        n = len(a.violations)
        shown = f" (the {top} worst)" if top is not None and n > top else ""
        out.append(
            f"Violations: {n}{shown}, worst first (× compared: relMSE over the compared value)\n"
        )
        if n:
            out.append(format_violations(a, top) + "\n")
        out.append("Counts per rule and method:\n")
        out.append(format_counts(a) + "\n")
        for u in a.unchecked:
            out.append(f"- rule {u}: not checked")
        if a.not_measured:
            out.append(f"- not measured ({len(a.not_measured)} unit(s), no relMSE):")
            for (s, m, reason), levels in _grouped(a.not_measured).items():
                out.append(f"  - {m} / {s} / {', '.join(map(str, levels))} spp: {reason}")
        out.append("")
    if len(analyses) > 1:
        out.append("## Counts compared\n")
        out.append("| rule | " + " | ".join(a.folder for a in analyses) + " |")
        out.append("|---|" + "---|" * len(analyses))
        for rule in RULES:
            out.append(
                f"| ({rule}) | " + " | ".join(str(a.counts()[rule]) for a in analyses) + " |"
            )
        out.append("| total | " + " | ".join(str(len(a.violations)) for a in analyses) + " |")
        common = set.intersection(*(set(a.methods) for a in analyses)) - {NOISY}
        if any(set(a.methods) - {NOISY} != common for a in analyses):  # a method came or went
            cells = [
                "/".join(str(sum(a.by_method()[m][r] for m in common)) for r in RULES)
                for a in analyses
            ]
            out.append(f"| (a)/(b)/(c) of the {len(common)} methods in all | {' | '.join(cells)} |")
            for a in analyses:
                if extra := [m for m in a.methods if m != NOISY and m not in common]:
                    out.append(f"\n{a.folder} also has: {', '.join(extra)}")
        out.append("")
        out.append(format_changes(analyses) + "\n")
    out.append("Rules (issue 22): " + "; ".join(f"({k}) {v}" for k, v in RULES.items()) + ".")
    return "\n".join(out)


# --- running the experiment ---------------------------------------------------------------


def spec_path(name: str) -> Path:
    """``demo`` -> data/experiments/demo.toml; a path is taken as it is."""
    p = Path(name)
    if p.suffix == ".toml" or p.exists():
        return p
    return EXPERIMENTS / f"{name}.toml"


def render_source(src: Path) -> Path:
    """The render folder of ``src``: ``src/data`` of an experiment folder, or ``src`` itself."""
    for folder in (src / "data", src):
        if (folder / "manifest.json").is_file():
            return folder
    raise InputError(f"{src}: no render folder (no data/manifest.json or manifest.json)")


def run(
    spec: str,
    out: Path,
    *,
    renders: Path | None = None,
    spp: Sequence[int] | None = None,
    resume: bool = False,
    threads: int = 1,
    repetitions: int | None = 1,
    warmup: int | None = 0,
    progress: str = "lines",
) -> Path:
    """Run the experiment ``spec`` into ``out`` (see the module docstring); return ``out``."""
    from mcdenoise.errors import McdenoiseError
    from mcdenoise.experiments import load_experiment, run_experiment

    path = spec_path(spec)
    try:
        s = load_experiment(path)
    except (McdenoiseError, OSError) as err:
        raise InputError(f"{path}: {' '.join(str(err).split())}") from None
    if (out / "work").exists() and not resume:
        raise InputError(
            f"{out}/work exists: its unit records would be reused (the fingerprint holds the "
            "mcdenoise version, not the code); give a new -o folder, or --resume to continue "
            "an interrupted run of the same code"
        )
    changes: dict[str, Any] = {"threads": threads}
    if repetitions is not None:
        changes["repetitions"] = repetitions
    if warmup is not None:
        changes["warmup"] = warmup
    s = dataclasses.replace(s, **changes)
    if renders is not None:
        src = render_source(renders)
        dst = out / s.render_folder
        if not dst.exists():
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copytree(src, dst, ignore=shutil.ignore_patterns("*.lock"))
        # as a `[scenes] folder`: used as it is, never rendered into, even where a scene spec
        # changed since (a re-render would change the inputs the numbers are compared on)
        s = dataclasses.replace(s, folder=dst.resolve())
    if spp:  # a subset of the ladder (e.g. 16 and 64 spp for a quick no-regression check)
        strip = s.strip_spp if s.strip_spp in spp else min(spp)
        s = dataclasses.replace(s, spp=tuple(sorted(spp)), spp_given=True, strip_spp=strip)
    try:
        summary = run_experiment(s, out, progress=progress)
    except McdenoiseError as err:
        raise InputError(f"{path}: {' '.join(str(err).split())}") from None
    for line, _ in summary.messages():  # on stderr: stdout is the analysis (--json -)
        print(line, file=sys.stderr)
    return out


# --- command line -------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description="Ratios to OIDN and violations of issue 22's robustness rules, per "
        "method, scene and spp, from experiment folders (results.csv).",
    )
    p.add_argument(
        "folders", nargs="*", type=Path, help="experiment folders (or results.csv files)"
    )
    p.add_argument("--run", metavar="SPEC", help="run this experiment first (demo, or a .toml)")
    p.add_argument("-o", "--out", type=Path, help="with --run: the new experiment folder")
    p.add_argument("--renders", type=Path, help="with --run: copy SRC/data (the renders) first")
    p.add_argument("--resume", action="store_true", help="with --run: continue an existing -o")
    p.add_argument(
        "--spp",
        type=lambda t: [int(x) for x in t.split(",")],
        help="only these levels of the ladder (e.g. 16,64): run (with --run) and analysed",
    )
    p.add_argument("--repetitions", type=int, default=1, help="with --run: timed runs (default 1)")
    p.add_argument("--warmup", type=int, default=0, help="with --run: untimed runs (default 0)")
    p.add_argument("--baseline", default="oidn", help="rule (a)'s reference method (oidn)")
    p.add_argument("--values", choices=("ratio", "relmse"), default="ratio", help="table cells")
    p.add_argument("--top", type=int, help="list only the N worst violations")
    p.add_argument("--json", metavar="FILE", help="write the analysis as JSON (- for stdout)")
    args = p.parse_args(argv)
    try:
        folders = list(args.folders)
        if args.run:
            if args.out is None:
                raise InputError("--run needs -o DIR (a new experiment folder)")
            run(
                args.run,
                args.out,
                renders=args.renders,
                spp=args.spp,
                resume=args.resume,
                repetitions=args.repetitions,
                warmup=args.warmup,
            )
            folders.append(args.out)
        elif args.out or args.renders or args.resume:
            raise InputError("-o, --renders and --resume go with --run")
        if not folders:
            raise InputError("give experiment folders, or --run SPEC -o DIR")
        analyses = []
        for f in folders:
            if not f.exists():
                raise InputError(f"{f}: no such folder")
            rows, partial = read_rows(f)
            if args.spp:  # the same levels in every folder, so that their counts compare
                rows = [r for r in rows if r["spp"] in args.spp]
            analyses.append(analyse(rows, folder=str(f), baseline=args.baseline, partial=partial))
    except InputError as err:
        print(f"bench_robust: error: {err}", file=sys.stderr)
        return 2
    doc = {
        "rules": RULES,
        "thresholds": dataclasses.asdict(Thresholds()),
        "experiments": [a.to_dict() for a in analyses],
        "relmse_changes": [
            {
                "base": analyses[0].folder,
                "folder": a.folder,
                "by_method": {
                    m: {
                        str(n): {"geomean": g, "worst": w, "worst_scene": sc, "scenes": k}
                        for n, (g, w, sc, k) in d.items()
                    }
                    for m, d in relmse_changes(analyses[0], a).items()
                },
            }
            for a in analyses[1:]
        ],
    }
    if args.json == "-":
        print(json.dumps(doc, indent=1, ensure_ascii=False))
        return 0
    print(format_report(analyses, args.values, args.top))
    if args.json:
        Path(args.json).write_text(json.dumps(doc, indent=1, ensure_ascii=False) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
