"""The columns of an experiment: the spec's methods and sweeps as labelled entries.

:func:`plan_methods` turns the spec's ``methods`` (names, or ``"all"``: every registered
method) and its sweeps into :class:`MethodEntry` values, ``noisy`` first; methods that cannot
run here are skipped with the reason. The runner runs them
(:mod:`~mcdenoise.experiments.runner`), the analysis groups the results by them
(:mod:`~mcdenoise.experiments.analysis`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from mcdenoise.experiments.spec import ExperimentSpec
from mcdenoise.experiments.spec_fields import NOISY, ExperimentError
from mcdenoise.registry import get_method, methods


@dataclass(frozen=True)
class MethodEntry:
    """One column of the experiment: a registry method with parameter overrides, or noisy.

    Attributes:
        label: how the report names it (``nlm``, ``xbf[kernel_size=5]``, ``noisy``).
        method: registry name (``cross-bilateral`` for ``xbf``), or ``"noisy"``.
        overrides: parameters given by the spec (defaults fill the rest).
        summary: the registry's one-line description.
    """

    label: str
    method: str
    overrides: Mapping[str, Any] = field(default_factory=dict)
    summary: str = ""

    @property
    def is_noisy(self) -> bool:
        return self.method == NOISY

    def params(self) -> dict[str, Any]:
        """The resolved parameters (defaults updated with the overrides); ``{}`` for noisy."""
        if self.is_noisy:
            return {}
        return get_method(self.method).resolve_params(self.overrides)

    def to_dict(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "method": self.method,
            "overrides": dict(self.overrides),
            "params": self.params(),
            "summary": self.summary,
        }


def _value_text(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float) and v.is_integer():
        return repr(v)
    return str(v)


def plan_methods(spec: ExperimentSpec) -> tuple[list[MethodEntry], dict[str, str]]:
    """The spec's methods as entries (``noisy`` first, then the methods in registry or spec
    order, then the sweeps) and the skipped ones: label -> reason it cannot run here.

    ``methods = "all"`` takes every registered method, so a method added to the registry is
    in the next experiment without any change here; never an external command (a spec's
    ``[[external]]`` method runs where the spec names it; see
    :mod:`mcdenoise.experiments.spec`).

    Raises:
        ExperimentError: two entries would get the same label.
    """
    entries = [MethodEntry(NOISY, NOISY, {}, "plain Monte Carlo rendering, no denoiser")]
    skipped: dict[str, str] = {}
    if spec.methods == "all":
        names = [m.name for m in methods()]
    else:
        names = [n for n in spec.methods if n != NOISY]
    for name in names:
        m = get_method(name)
        overrides = dict(spec.params.get(name) or spec.params.get(m.name) or {})
        reason = m.unavailable()
        if reason:
            skipped[name] = reason
            continue
        entries.append(MethodEntry(name, m.name, overrides, m.summary))
    for sw in spec.sweeps:
        m = get_method(sw.method)
        base = {**(spec.params.get(sw.method) or spec.params.get(m.name) or {}), **sw.params}
        for value in sw.values:
            label = f"{sw.method}[{sw.param}={_value_text(value)}]"
            reason = m.unavailable()
            if reason:
                skipped[label] = reason
                continue
            entries.append(MethodEntry(label, m.name, {**base, sw.param: value}, m.summary))
    labels = [e.label for e in entries]
    dup = sorted({x for x in labels if labels.count(x) > 1})
    if dup:
        raise ExperimentError(f"{spec.source}: method label(s) {', '.join(dup)} appear twice")
    return entries, skipped


__all__ = ["MethodEntry", "plan_methods"]


def run_device(method: Any, device: Any, notes: list[str], name: str) -> Any:
    """The device ``method`` (given as ``name`` in the spec) runs on in a unit: ``device``,
    or the CPU (with a note in ``notes``) when the method does not support it."""
    if device.type in method.devices:
        return device
    import torch  # lazy: start-up without torch

    notes.append(f"{name} does not run on {device.type}: ran on the CPU")
    return torch.device("cpu")
