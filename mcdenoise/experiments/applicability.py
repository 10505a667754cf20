"""Which method applies to which scene of an experiment: only those run (issue 39).

An experiment with ``methods = "all"`` takes every method of the registry, but not every
method can say something about every scene: an ambient-occlusion estimator has nothing to do
on a colour render, a method that needs half buffers nothing on a render without them, and a
temporal method (``kpcn-temporal``, ``svgf``) on a still image is its single-frame fallback,
a row that repeats another method or shows a first-frame filter. Such pairs used to run, fail
or repeat, and fill the report with "could not run" cells and warnings.

:func:`plan_applicable` decides, before anything runs, for every (method, scene) pair:

* a temporal method (:attr:`~mcdenoise.method.Method.temporal`) applies to sequences only;
* a method applies to a level of a scene when it accepts its buffers (a sequence's first
  frame's) with the entry's parameters (:meth:`~mcdenoise.method.Method.accepts`: the buffers
  it requires, then its own input check; the check the default method and ``--method all``
  make).

A method that applies nowhere is left out of the experiment with one line saying why
("not run: ``ssao``: …"); one that applies to some scenes or levels (``nfor`` needs half
buffers, which a 1-spp level cannot have) runs on those only, and the others show "–" in its
row (the overall tables mark its rows incomplete, as for a failed unit). The
noisy input always applies.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from mcdenoise.errors import McdenoiseError
from mcdenoise.experiments.entries import MethodEntry
from mcdenoise.experiments.scene_data import SceneData, read_level
from mcdenoise.io import load_buffers
from mcdenoise.registry import get_method

#: Why a temporal method does not run on still images.
TEMPORAL_ON_STILLS = (
    "a temporal method (it filters a frame with its neighbours); these scenes are still images"
)


@dataclass
class Applicability:
    """The plan: which entries run, on which scenes and levels, and why the others do not.

    Attributes:
        entries: the entries that apply somewhere (``noisy`` first, order kept).
        runs: ``(label, scene id, spp)`` of every unit that runs.
        not_run: label -> why it applies nowhere (one line).
        partial: label -> ``{(scene id, spp): why not}`` for entries that run on some scenes
            or levels only.
    """

    entries: list[MethodEntry]
    runs: set[tuple[str, str, int]]
    not_run: dict[str, str] = field(default_factory=dict)
    partial: dict[str, dict[tuple[str, int], str]] = field(default_factory=dict)

    def notes(self) -> list[str]:
        """One line per reason, naming the entries it keeps out (the five AO estimators on
        colour renders are one line), then one per entry run on some scenes or levels only."""
        by_reason: dict[str, list[str]] = {}
        for label, why in self.not_run.items():
            by_reason.setdefault(why, []).append(label)
        lines = [f"{', '.join(labels)}: {why}" for why, labels in by_reason.items()]
        for label, where in self.partial.items():
            places: dict[str, list[str]] = {}
            for (scene, spp), why in where.items():
                places.setdefault(why, []).append(f"{scene} at {spp} spp")
            parts = []
            for why, at in places.items():
                more = f" (+{len(at) - 4} more)" if len(at) > 4 else ""
                parts.append(f"not on {', '.join(at[:4])}{more}: {why}")
            lines.append(f"{label}: " + "; ".join(parts))
        return lines


def level_buffers(scene: SceneData, level: Any) -> Any:
    """The buffers a method's check sees for one level of ``scene`` (for a sequence, those of
    its first frame)."""
    if scene.is_sequence:
        return load_buffers(scene.frames[0].noisy, part=level.part)
    return read_level(scene.noisy, level)


def why_not(entry: MethodEntry, scene: SceneData, buffers: Any) -> str | None:
    """Why ``entry`` does not apply to ``scene`` (whose buffers are ``buffers``), or ``None``."""
    if entry.is_noisy:
        return None
    method = get_method(entry.method)
    if method.temporal and not scene.is_sequence:
        return TEMPORAL_ON_STILLS
    try:  # the check of the default method and of `--method all`
        why = method.accepts(buffers, entry.overrides)
    except McdenoiseError as err:  # a check that raises says why as well
        why = " ".join(str(err).split())
    if why is None:
        return None
    # checks name the file first ("data/cornell.exr: a render of ..."): the reason is the
    # same for every scene, so one line can say it for all of them
    prefixes = [f"{buffers.source}: "] if buffers.source else []
    for prefix in [*prefixes, "input: "]:
        if why.startswith(prefix):
            return why[len(prefix) :]
    return why


def _short(reason: str, limit: int = 200) -> str:
    text = " ".join(reason.split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _same_kind(reasons: Any) -> bool:
    """Whether reasons differ only after their first few words (the same check refusing each
    scene for its own details)."""
    heads = {" ".join(str(r).split()[:3]) for r in reasons}
    return len(heads) == 1


def plan_applicable(entries: Sequence[MethodEntry], scenes: Sequence[SceneData]) -> Applicability:
    """Which of ``entries`` run on which levels of ``scenes`` (see the module docstring).

    Every level of every scene is read once (one at a time: nothing is held beyond a level),
    since a level can lack what another has (no half buffers at 1 spp)."""
    reasons: dict[str, dict[tuple[str, int], str | None]] = {e.label: {} for e in entries}
    for scene in scenes:
        for level in scene.levels:
            buffers = level_buffers(scene, level)
            for entry in entries:
                why = why_not(entry, scene, buffers)
                reasons[entry.label][(scene.id, level.spp)] = None if why is None else _short(why)
    kept: list[MethodEntry] = []
    plan = Applicability(kept, set())
    for entry in entries:
        mine = reasons[entry.label]
        runs = [key for key, why in mine.items() if why is None]
        if not runs:
            # the first scene's reason: others differ in detail only (the AO check names each
            # render's light effects), and the line must stay one line
            first = str(next(iter(mine.values())))
            distinct = len({str(w) for w in mine.values()})
            plan.not_run[entry.label] = first + (
                f" (and {distinct - 1} other reason(s) on other scenes)"
                if distinct > 1 and not _same_kind(mine.values())
                else ""
            )
            continue
        kept.append(entry)
        plan.runs.update((entry.label, sid, spp) for sid, spp in runs)
        others = {key: str(why) for key, why in mine.items() if why is not None}
        if others:
            plan.partial[entry.label] = others
    return plan


__all__ = ["TEMPORAL_ON_STILLS", "Applicability", "level_buffers", "plan_applicable", "why_not"]
