"""Experiments on data without our manifests: a folder of inputs and references.

A ``[scenes] folder`` without ``manifest.json`` is read here instead of through the manifest
(:func:`mcdenoise.experiments.dataset.load_dataset` calls :func:`scan_folder`). Two layouts:

* **OIDN's training layout** (:mod:`mcdenoise.io.oidn_layout`): anywhere below the folder,
  ``<name>_<spp>spp.hdr.exr`` (+ ``.alb.exr``, ``.nrm.exr``) and ``<name>_ref.hdr.exr``; an
  image is ``<subfolder>/<name>``, its levels its noisy versions, its reference the ``ref``
  (``reference``, ``gt``, ``target``) version or else the one with the most samples, as
  OIDN's toolkit takes it.
* **inputs and references**, as ``mcdenoise eval --ref`` matches them: every ``*.exr`` in the
  folder (not in subfolders) is an input from any renderer profile (plain Mitsuba ``aov``
  output, Blender, pbrt, Tungsten, mcdenoise's own), and its scene is the reference in
  ``ref/`` (or ``[scenes] references``) whose name is the longest prefix of the input's
  (``cornell_spp4.exr`` -> ``ref/cornell.exr``, :func:`mcdenoise.eval.match_prefix`). The
  level of an input is its spp, from its name (``_spp16``, ``_16spp``, ``_0016spp``), else
  its ``mcdenoise:spp`` header; an input whose parts are ``spp<n>`` (a render folder whose
  manifest was lost) gives one level per part.

What is not known is not made up. **Render time is unknown** (``Level.render_seconds`` is
``None``): no file format records how long its samples took, so total times, Pareto fronts,
equal-time tables and equal-quality speed-ups are left out, and the report says so; the
equal-quality spp (from the error curve alone) and every error are computed as usual. Seeds,
variant and the reference's spp are ``None`` unless the reference's header records its spp.

Every scene must have the same levels (else one line names the difference and suggests
``[render] spp``). Results are cached by the content of the files (SHA-256 of every input and
reference, with their names), so a changed file is measured again.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Sequence
from pathlib import Path

from mcdenoise.errors import InputError
from mcdenoise.eval.matching import PrefixMatcher
from mcdenoise.experiments.scene_data import Level, SceneData
from mcdenoise.experiments.spec_fields import ExperimentError
from mcdenoise.io.atomic import TMP_PREFIX
from mcdenoise.io.exr import probe_exr
from mcdenoise.io.oidn_layout import find_oidn_images, is_oidn_tree
from mcdenoise.render.manifest import MANIFEST

#: The spp in an input's name: ``_spp16``, ``_16spp``, ``_0016spp`` at the end of the stem.
SPP_IN_NAME = re.compile(r"(?:^|[_\-.])(?:spp(?P<a>[0-9]+)|(?P<b>[0-9]+)spp)$")
#: Part names of a multi-part input (one level per part).
SPP_PART = re.compile(r"^spp(?P<n>[0-9]+)$")


def has_manifest(folder: str | Path) -> bool:

    return (Path(folder) / MANIFEST).is_file()


def _digest(files: Sequence[Path]) -> str:
    h = hashlib.sha256()
    for p in files:
        h.update(p.name.encode("utf-8") + b"\0")
        with open(p, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()[:16]


def _scene(image_id: str, levels: Sequence[Level], reference: Path, layout: str) -> SceneData:
    ref_spp = _header_spp(reference) if layout != "oidn" else None
    scene = SceneData(
        id=image_id,
        noisy=levels[0].file or reference,
        reference=reference,
        levels=tuple(sorted(levels, key=lambda lv: lv.spp)),
        reference_spp=ref_spp,
        seed=None,
        variant=None,
        fingerprint="",
        record={"id": image_id, "layout": layout},
    )
    fingerprint = _digest(sorted(set(scene.files())))
    return SceneData(**{**scene.__dict__, "fingerprint": fingerprint})


def _header_spp(path: Path) -> int | None:

    value = probe_exr(path)[0].attributes.get("mcdenoise:spp")
    try:
        return int(value) if value is not None else None
    except (TypeError, ValueError):
        return None


def _oidn(root: Path) -> list[SceneData]:

    try:
        images = find_oidn_images(root)
    except InputError as err:
        raise ExperimentError(str(err)) from None
    scenes = []
    for im in images:
        assert im.reference is not None
        levels = [Level(spp, "", None, 0.0, path) for spp, path in im.levels.items()]
        scenes.append(_scene(im.id, levels, im.reference, "oidn"))
    return scenes


def _input_levels(path: Path) -> list[Level]:
    """The levels of one input file: one per ``spp<n>`` part, else one of the spp in its name
    or header."""

    parts = probe_exr(path)
    named = [(p, SPP_PART.match(p.name or "")) for p in parts]
    if len(parts) > 1 and all(m is not None for _, m in named):
        return [Level(int(m["n"]), p.name, None, 0.0, path) for p, m in named if m is not None]
    m = SPP_IN_NAME.search(path.stem)
    spp = int(m["a"] or m["b"]) if m else _header_spp(path)
    if spp is None or spp < 1:
        raise ExperimentError(
            f"{path}: its spp is unknown (neither in its name, e.g. {path.stem}_spp16.exr, nor "
            "in an mcdenoise:spp header); an experiment needs the spp of every input"
        )
    return [Level(spp, "", None, 0.0, path)]


def _inputs(root: Path, references: Path | None) -> list[SceneData]:

    refdir = references if references is not None else root / "ref"
    refs = {
        p.stem: p
        for p in sorted(refdir.glob("*.exr"))
        if refdir.is_dir() and not p.name.startswith(TMP_PREFIX)
    }
    if not refs:
        raise ExperimentError(
            f"{root}: no manifest.json and no reference in {refdir}: an experiment on a folder "
            "of inputs needs their references (set [scenes] references, or put them in ref/)"
        )
    found: dict[str, dict[int, Level]] = {}
    inputs = [p for p in sorted(root.glob("*.exr")) if not p.name.startswith(TMP_PREFIX)]
    if not inputs:
        raise ExperimentError(f"{root}: no *.exr input (and no manifest.json)")
    scene_of = PrefixMatcher(refs)
    for path in inputs:
        scene = scene_of(path.stem)
        if scene is None:
            raise ExperimentError(
                f"{path}: no reference in {refdir} whose name begins its name (inputs are "
                f"matched to references by the longest prefix: cornell_spp4.exr -> "
                "ref/cornell.exr)"
            )
        for lv in _input_levels(path):
            have = found.setdefault(scene, {})
            if lv.spp in have:
                raise ExperimentError(
                    f"{root}: scene {scene!r} has two inputs of {lv.spp} spp "
                    f"({have[lv.spp].file.name if have[lv.spp].file else ''}, {path.name})"
                )
            have[lv.spp] = lv
    return [_scene(s, list(levels.values()), refs[s], "files") for s, levels in found.items()]


def scan_folder(
    folder: str | Path,
    *,
    references: str | Path | None = None,
    spp: Sequence[int] | None = None,
) -> list[SceneData]:
    """The scenes of a folder without manifest (see the module docstring), restricted to the
    levels ``spp`` (default: the levels every scene has, which must be all of each's).

    Raises:
        ExperimentError: no input or no reference, an input without reference or spp, two
            inputs of one scene and spp, scenes of different levels, a level of ``spp``
            missing.
    """

    root = Path(folder).resolve()
    refs = None if references is None else Path(references).resolve()
    scenes = _oidn(root) if refs is None and is_oidn_tree(root) else _inputs(root, refs)
    ladders = {s.id: [lv.spp for lv in s.levels] for s in scenes}
    if spp is not None:
        for s in scenes:
            lacking = [v for v in spp if v not in ladders[s.id]]
            if lacking:
                raise ExperimentError(
                    f"{root}: scene {s.id!r} has no level(s) {', '.join(map(str, lacking))} "
                    f"(levels: {', '.join(map(str, ladders[s.id]))})"
                )
        scenes = [_restrict(s, spp) for s in scenes]
    elif len({tuple(v) for v in ladders.values()}) > 1:
        common = sorted(set.intersection(*(set(v) for v in ladders.values())))
        shown = "; ".join(f"{k}: {', '.join(map(str, v))}" for k, v in ladders.items())
        raise ExperimentError(
            f"{root}: the scenes have different spp levels ({shown}); set [render] spp to "
            f"levels every scene has ({', '.join(map(str, common)) or 'none'})"
        )
    return sorted(scenes, key=lambda s: s.id)


def _restrict(scene: SceneData, spp: Sequence[int]) -> SceneData:
    levels = tuple(lv for lv in scene.levels if lv.spp in spp)
    return SceneData(**{**scene.__dict__, "levels": levels})
