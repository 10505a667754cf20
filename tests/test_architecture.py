"""The import directions of docs/architecture.md, read from the source with ``ast``.

Every ``import`` and ``from ... import`` in ``mcdenoise/`` counts, at module level and inside
functions alike (a deferred import is still a dependency). The rules:

* ``io`` imports no algorithm (filters, prep, models, methods, train, eval, experiments, render,
  losses, registry, denoise);
* ``filters`` (tensor operators) import nothing of io, prep, models, methods, train, eval,
  experiments, render;
* ``models`` (pure ``nn.Module``\\ s) import nothing of io, prep, methods, train, eval,
  experiments, render, registry, denoise;
* ``modelfile`` sits below models and train;
* no ``mcdenoise`` module imports ``mcdenoise_cli``;
* every model card is a ``modelfile.Card`` and its module a ``modelfile.CardModule``, and
  no model module calls the model-file plumbing (save_model, read_model_file, load_weights);
* no module of ``mcdenoise/methods/`` imports another one (shared names live in ``filters``
  or ``prep``), except ``methods/__init__`` registering them and the pairs listed in
  ``METHOD_CROSS_IMPORTS``;
* no import cycle between subpackages (``mcdenoise.io``, ``mcdenoise.filters``, ...; top-level
  modules such as ``mcdenoise.losses`` count as units of their own).
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import itertools
from collections import defaultdict
from pathlib import Path

import pytest

from mcdenoise.modelfile import Card, CardModule

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "mcdenoise"

#: Every unit a rule can name; each rule below lists what a unit must NOT import.
_UNITS = {
    *("io", "filters", "prep", "models", "methods", "train", "eval", "experiments", "render"),
    *("ao", "losses", "registry", "denoise", "batch", "output", "modelfile"),
}

FORBIDDEN: dict[str, set[str]] = {
    "io": _UNITS - {"io", "modelfile"},
    "filters": _UNITS - {"filters", "losses", "modelfile"},
    # screen-space AO estimators: tensor operators on a G-buffer, like filters
    "ao": _UNITS - {"ao", "filters"},
    "models": _UNITS - {"models", "filters", "losses", "modelfile"},
    "modelfile": _UNITS - {"modelfile", "io", "losses"},
    "losses": {"io", "prep", "models", "methods", "train", "eval", "experiments", "render"},
    "errors": set(_UNITS),
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path) -> set[str]:
    """Absolute names of the modules ``path`` imports (relative imports resolved)."""
    mod = _module_name(path)
    package = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            out.add(target)
            # `from mcdenoise import methods` imports the submodule mcdenoise.methods
            out.update(f"{target}.{a.name}" for a in node.names)
    return out


def _unit(module: str) -> str | None:
    """The subpackage (or top-level module) of ``mcdenoise`` a module belongs to."""
    parts = module.split(".")
    if parts[0] != "mcdenoise" or len(parts) < 2:
        return None
    return parts[1]


def _existing_units() -> set[str]:
    units = {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    units |= {p.stem for p in PACKAGE.glob("*.py") if p.stem != "__init__"}
    return units


def _graph() -> dict[str, dict[str, set[str]]]:
    """unit -> imported unit -> the modules of ``unit`` that import it."""
    units = _existing_units()
    graph: dict[str, dict[str, set[str]]] = defaultdict(lambda: defaultdict(set))
    for path in sorted(PACKAGE.rglob("*.py")):
        src = _module_name(path)
        src_unit = _unit(src)
        for target in _imports(path):
            unit = _unit(target)
            if unit in units and unit != src_unit and src_unit is not None:
                graph[src_unit][unit].add(src)
    return graph


def test_the_parser_sees_imports():
    """The checker itself: a known import is found (so an empty graph cannot pass silently)."""
    graph = _graph()
    assert "io" in graph["denoise"] or "io" in graph.get("methods", {})
    assert _imports(PACKAGE / "io" / "__init__.py")


@pytest.mark.parametrize("unit", sorted(FORBIDDEN))
def test_import_directions(unit):
    graph = _graph()
    bad = {dep: sorted(mods) for dep, mods in graph.get(unit, {}).items() if dep in FORBIDDEN[unit]}
    assert not bad, f"mcdenoise.{unit} must not import {sorted(bad)}: {bad}"


def test_library_never_imports_the_cli():
    offenders = [
        _module_name(p)
        for p in PACKAGE.rglob("*.py")
        if any(t.split(".")[0] == "mcdenoise_cli" for t in _imports(p))
    ]
    assert not offenders


def test_no_cycles_between_subpackages():
    graph = _graph()
    edges = {u: set(deps) for u, deps in graph.items()}
    cycles: list[list[str]] = []

    def visit(node: str, stack: list[str], on_stack: set[str], done: set[str]) -> None:
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(edges.get(node, ())):
            if nxt in on_stack:
                cycles.append([*stack[stack.index(nxt) :], nxt])
            elif nxt not in done:
                visit(nxt, stack, on_stack, done)
        stack.pop()
        on_stack.discard(node)
        done.add(node)

    done: set[str] = set()
    for unit in sorted(edges):
        if unit not in done:
            visit(unit, [], set(), done)
    detail = [
        " -> ".join(c)
        + "  ("
        + "; ".join(f"{a}->{b}: {sorted(graph[a][b])[0]}" for a, b in itertools.pairwise(c))
        + ")"
        for c in cycles
    ]
    assert not cycles, "import cycles between subpackages:\n" + "\n".join(detail)


#: The most lines a module may have: past it, a file holds more than one job (issue 35).
MAX_LINES = 600
#: The core API stays small: everything else lives in output, batch and denoise_files.
MAX_DENOISE_LINES = 300


def test_no_file_over_the_size_bound():
    long = {
        str(p.relative_to(REPO)): n
        for p in PACKAGE.rglob("*.py")
        if (n := len(p.read_text(encoding="utf-8").splitlines())) >= MAX_LINES
    }
    assert not long, f"files of {MAX_LINES} lines or more (split them by job): {long}"
    denoise = len((PACKAGE / "denoise.py").read_text(encoding="utf-8").splitlines())
    assert denoise < MAX_DENOISE_LINES


def _deferred_imports(path: Path) -> list[tuple[int, str]]:
    """The imports inside function bodies of ``path``: (line, source text of the statement)."""
    text = path.read_text(encoding="utf-8")
    lines = text.splitlines()
    out = []
    for fn in ast.walk(ast.parse(text)):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(fn):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                out.append((node.lineno, "\n".join(lines[node.lineno - 1 : node.end_lineno])))
    return sorted(set(out))


def test_the_deferred_import_check_sees_them(tmp_path):
    src = tmp_path / "m.py"
    src.write_text(
        "import os\n\ndef f():\n    import json  # lazy: why\n    from a import (\n        b,\n    )\n"
    )
    found = _deferred_imports(src)
    assert [n for n, _ in found] == [4, 5]
    assert [("# lazy:" in s) for _, s in found] == [True, False]


def test_deferred_imports_say_why():
    """An import inside a function hides the import graph; one that stays says why on its line
    (``# lazy: <reason>``): the start-up of ``mcdenoise denoise``, an optional or heavy
    dependency, or a cycle. Everything else is imported at module level."""
    silent = [
        f"{p.relative_to(REPO)}:{n}"
        for p in sorted(PACKAGE.rglob("*.py"))
        for n, s in _deferred_imports(p)
        if "# lazy:" not in s
    ]
    assert not silent, (
        "imports inside functions without a '# lazy: <reason>' comment:\n" + "\n".join(silent)
    )


#: The plumbing of model files that only the card bases (modelfile.Card, CardModule) call.
_MODEL_FILE_PLUMBING = {"save_model", "read_model_file", "load_weights"}


def _model_modules() -> list[Path]:
    return sorted(p for p in (PACKAGE / "models").glob("*.py") if p.name != "__init__.py")


def test_every_model_card_uses_the_card_base():
    """Every model's card derives from ``modelfile.Card`` and its module from
    ``modelfile.CardModule`` (one ``to_dict``/format check/``save``/``load`` for all)."""
    cards, modules, bad = set(), set(), []
    for path in _model_modules():
        mod = importlib.import_module(_module_name(path))
        for obj in vars(mod).values():
            if not isinstance(obj, type) or obj.__module__ != mod.__name__:
                continue
            is_card = dataclasses.is_dataclass(obj) and any(
                f.name == "format" for f in dataclasses.fields(obj)
            )
            if is_card:
                cards.add(obj)
                if not issubclass(obj, Card):
                    bad.append(f"{obj.__module__}.{obj.__name__} is a card, not a Card")
            if isinstance(getattr(obj, "card_class", None), type) or "card" in getattr(
                obj, "__annotations__", {}
            ):
                if not issubclass(obj, CardModule):
                    bad.append(f"{obj.__module__}.{obj.__name__} has a card, not a CardModule")
            if issubclass(obj, CardModule):
                modules.add(obj.card_class)
    assert len(cards) >= 5, cards  # kalantari, kpcn, temporal, nnao, auxnet
    assert not bad, bad
    assert cards <= modules, f"cards without a CardModule: {cards - modules}"


def test_models_leave_model_file_plumbing_to_the_base():
    """No model module calls save_model/read_model_file/load_weights itself."""
    offenders = {}
    for path in _model_modules():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        names = {
            a.name
            for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and node.module == "mcdenoise.modelfile"
            for a in node.names
        }
        if names & _MODEL_FILE_PLUMBING:
            offenders[path.name] = sorted(names & _MODEL_FILE_PLUMBING)
    assert not offenders, offenders


#: The method modules that may import another module of ``mcdenoise/methods/``, each with why.
METHOD_CROSS_IMPORTS: dict[tuple[str, str], str] = {
    ("mcdenoise.methods.selection", "mcdenoise.methods.cross_bilateral"): (
        "the selection runs the cross-bilateral method's whole pipeline (denoise_xbf) as candidates"
    ),
    ("mcdenoise.methods.kalantari", "mcdenoise.methods.selection"): (
        "selection.py is the Kalantari methods' `-p select`, not a method of its own"
    ),
    ("mcdenoise.methods.nnao", "mcdenoise.methods.ao"): (
        "the learned AO estimator shares the AO methods' camera and G-buffer checks and "
        "their priority"
    ),
}


def _method_cross_imports() -> set[tuple[str, str]]:
    """(importer, imported) pairs of modules of ``mcdenoise/methods/``, its ``__init__`` aside.

    A private module (``methods/_learned.py``) registers no method: it is the methods' shared
    plumbing, which any of them may import, so it is not a target here."""
    paths = sorted(p for p in (PACKAGE / "methods").glob("*.py") if p.name != "__init__.py")
    names = {_module_name(p) for p in paths if not p.name.startswith("_")}
    pairs = set()
    for path in paths:
        src = _module_name(path)
        for target in _imports(path):
            if target == "mcdenoise.methods":  # the package registers every method
                pairs.add((src, target))
            pairs.update((src, m) for m in names if m != src and (target + ".").startswith(m + "."))
    return pairs


def test_no_method_module_imports_another():
    """A name two methods share belongs in ``filters`` or ``prep``, not in one of the methods."""
    pairs = _method_cross_imports()
    assert ("mcdenoise.methods.nnao", "mcdenoise.methods.ao") in pairs  # the checker sees them
    unexpected = sorted(pairs - set(METHOD_CROSS_IMPORTS))
    assert not unexpected, f"method modules importing other method modules: {unexpected}"
    stale = sorted(set(METHOD_CROSS_IMPORTS) - pairs)
    assert not stale, f"METHOD_CROSS_IMPORTS lists imports that are gone: {stale}"
