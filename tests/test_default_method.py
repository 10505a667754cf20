"""The default method never picks a method that refuses the input (issue 21, item 1).

Synthetic EXR files of every combination of guide buffers (colour plus any subset of albedo,
normal, depth, position), with and without variance channels, in the channel layout of every
renderer profile, are read as ``mcdenoise denoise`` reads them (profile detected). For each,
the default (:func:`mcdenoise.registry.choose_method`) must be a method that accepts the input
and whose preparation succeeds, and it must be the method ``docs/methods.md`` says the input
gets; the chosen method is run for real on a few representative files, and the command line
denoises a plain Mitsuba ``aov`` file (no variance) with no flags. A frame whose pixels a
method's preparation refuses (no geometry hit: no scene extent) gets the next method.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from mcdenoise_cli.main import main

from mcdenoise import registry
from mcdenoise.batch import denoise_paths
from mcdenoise.denoise import denoise
from mcdenoise.errors import InputError
from mcdenoise.io import FeatureBuffers, load_buffers, save_buffers
from mcdenoise.io.buffers import MissingFeatureError
from mcdenoise.io.exr_write import write_exr
from mcdenoise.method import Method
from mcdenoise.methods.kalantari import model_for
from mcdenoise.models.weights import load_kpcn, shipped_model_path
from mcdenoise.prep.inputs import prepare_inputs
from mcdenoise.prep.kalantari import prepare_for_model
from mcdenoise.prep.kpcn import prepare_tensors, source_for

ONE_THREAD = True
H = W = 16
SPP = 16
GUIDES = ("albedo", "normal", "depth", "position")
SUBSETS = [frozenset(c) for n in range(len(GUIDES) + 1) for c in itertools.combinations(GUIDES, n)]
# linear sRGB -> CIE XYZ (D65): Mitsuba's moment integrator stores colour moments as XYZ
XYZ_FROM_SRGB = np.array(
    [
        [0.4124564, 0.3575761, 0.1804375],
        [0.2126729, 0.7151522, 0.0721750],
        [0.0193339, 0.1191920, 0.9503041],
    ]
)


def scene(seed: int = 0) -> dict[str, np.ndarray]:
    """A small noisy render of a tilted, textured plane: every buffer, float32 ``(C, H, W)``."""
    rng = np.random.default_rng(seed)
    yy, xx = np.meshgrid(np.linspace(0, 1, H), np.linspace(0, 1, W), indexing="ij")
    albedo = np.stack([0.2 + 0.6 * ((xx * 4).astype(int) % 2), 0.5 + 0 * xx, 0.3 + 0.4 * yy])
    n = np.array([0.0, 0.6, 0.8])
    normal = np.broadcast_to(n[:, None, None], (3, H, W)) + 0.05 * rng.standard_normal((3, H, W))
    depth = (1.0 + 2.0 * yy)[None]
    position = np.stack([xx * 2 - 1, yy, depth[0]])
    clean = albedo * (0.4 + 0.6 * xx)
    color = np.clip(clean + 0.2 * rng.standard_normal((3, H, W)) * clean, 0, None)
    out = {
        "color": color,
        "albedo": albedo,
        "normal": normal,
        "depth": depth,
        "position": position,
        "color_var": np.full((3, H, W), 0.04 / SPP),
    }
    for g in GUIDES:
        out[f"{g}_var"] = np.full(out[g].shape, 0.01 / SPP)
    return {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in out.items()}


# --- one writer per profile: (path, guides, with variances) -> (file, spp to pass, buffers) ---
Writer = Callable[[Path, frozenset, bool], tuple[Path, "int | None", set[str]]]


def _named(b: dict[str, np.ndarray], name: str, chans: str) -> dict[str, np.ndarray]:
    """Channels ``<name>.<c>`` of buffer ``b[name]`` (or of ``b[key]`` for ``name=key:label``)."""
    key, _, label = name.partition(":")
    return {f"{label or key}.{c}": b[key][i] for i, c in enumerate(chans)}


def write_mcdenoise(path: Path, guides: frozenset, var: bool):
    b = scene()
    keep = {"color", *guides} | ({"color_var", *(f"{g}_var" for g in guides)} if var else set())
    save_buffers(path, FeatureBuffers({k: torch.from_numpy(b[k]) for k in keep}, spp=SPP))
    return path, None, keep


_MITSUBA_AOV = {"albedo": "RGB", "normal": "XYZ", "depth": "T", "position": "XYZ"}


def write_mitsuba(path: Path, guides: frozenset, var: bool):
    """Mitsuba 3 ``aov`` integrator; with variances, nested in a ``moment`` integrator (its
    colour moments in XYZ, the AOVs' moments per channel, ``m2_`` prefixed)."""
    b = scene()
    ch = {c: b["color"][i] for i, c in enumerate("RGB")}
    prefix = "aov." if var else ""
    for g in guides:
        ch.update(_named(b, f"{g}:{prefix}{g}", _MITSUBA_AOV[g]))
    made = {"color", *guides}
    if var:
        xyz = np.einsum("ij,jhw->ihw", XYZ_FROM_SRGB, b["color"]).astype(np.float32)
        for i, c in enumerate("XYZ"):
            ch[f"img.path.{c}"] = xyz[i]
            ch[f"img.m2_path.{c}"] = xyz[i] ** 2 + 0.04
        for name in [n for n in ch if n.startswith("aov.")]:
            ch["m2_" + name] = ch[name] ** 2 + 0.01
        made |= {"color_var", *(f"{g}_var" for g in guides)}
    write_exr(path, ch, attributes={"generatedBy": "Mitsuba version 3.9.1"})
    return path, SPP if var else None, made  # Mitsuba writes no spp: the user gives --spp


def write_cycles(path: Path, guides: frozenset, var: bool):
    """Blender multilayer EXR, one view layer with denoising data (no variance passes)."""
    b = scene()
    L = "ViewLayer"
    ch = _named(b, f"color:{L}.Combined", "RGB") | _named(b, f"color:{L}.Noisy Image", "RGB")
    ch[f"{L}.Combined.A"] = np.ones((H, W), np.float32)
    names = {
        "albedo": ("Denoising Albedo", "RGB"),
        "normal": ("Denoising Normal", "XYZ"),
        "depth": ("Denoising Depth", "Z"),
        "position": ("Position", "XYZ"),
    }
    for g in guides:
        ch.update(_named(b, f"{g}:{L}.{names[g][0]}", names[g][1]))
    attrs = {"BlenderMultiChannel": "Blender V2.55.1 and newer", f"cycles.{L}.samples": SPP}
    write_exr(path, ch, attributes=attrs)
    return path, None, {"color", *guides}


def write_pbrt(path: Path, guides: frozenset, var: bool):
    """pbrt-v4 ``gbuffer`` film: depth is ``P.Z`` of the position, so they come together."""
    b = scene()
    ch = {c: b["color"][i] for i, c in enumerate("RGB")}
    ch["dzdx"] = ch["dzdy"] = np.zeros((H, W), np.float32)  # always written by the film
    if "albedo" in guides:
        ch.update(_named(b, "albedo:Albedo", "RGB"))
    if "normal" in guides:
        ch.update(_named(b, "normal:Ns", "XYZ"))
    if "position" in guides:
        ch.update(_named(b, "position:P", "XYZ"))
    made = {"color", *guides}
    if var:
        ch.update({f"Variance.{c}": b["color_var"][i] * SPP for i, c in enumerate("RGB")})
        made.add("color_var")
    write_exr(path, ch, attributes={"samplesPerPixel": SPP})
    return path, None, made


def write_tungsten(path: Path, guides: frozenset, var: bool):
    """Tungsten as packaged for KPCN (no position); variances ``<x>Variance.Z``."""
    b = scene()
    ch = {c: b["color"][i] for i, c in enumerate("RGB")}
    sfx = {"albedo": "RGB", "normal": "RGB", "depth": "Z"}
    made = {"color", *guides}
    for g in guides:
        ch.update(_named(b, g, sfx[g]))
        if var:
            ch[f"{g}Variance.Z"] = b[f"{g}_var"][0]
    if var:
        ch["colorVariance.Z"] = b["color_var"][0]
        made |= {"color_var", *(f"{g}_var" for g in guides)}
    write_exr(path, ch)
    return path, None, made


WRITERS: dict[str, tuple[Writer, Callable[[frozenset, bool], bool]]] = {
    # profile: (writer, which (guides, variance) combinations the layout can express)
    "mcdenoise": (write_mcdenoise, lambda g, v: True),
    "mitsuba": (write_mitsuba, lambda g, v: True),
    "cycles": (write_cycles, lambda g, v: not v),  # Cycles writes no variance passes
    "pbrt": (write_pbrt, lambda g, v: ("depth" in g) == ("position" in g)),
    "tungsten": (write_tungsten, lambda g, v: "position" not in g),
}
CASES = [
    (profile, guides, var)
    for profile, (_, expressible) in WRITERS.items()
    for guides in SUBSETS
    for var in (False, True)
    if expressible(guides, var)
]


def expected_default(names: set[str]) -> str:
    """The default ``docs/methods.md`` ("Choosing a method") gives an input with ``names``."""
    present = [g for g in GUIDES if g in names]
    if {"albedo", "normal"} <= names and shipped_model_path("kpcn").is_file():
        return "kpcn"
    xbf = {"normal", "depth", "position"} <= names and all(f"{g}_var" in names for g in present)
    if xbf:
        return "kalantari-xbf"
    return "nlm"


def prepare_for(method: str, b: FeatureBuffers) -> None:
    """Run the preparation ``method`` does before its filter or model (raises if refused)."""
    if method.startswith("kalantari-"):
        model = model_for(method.removeprefix("kalantari-"), b, "shipped")
        prepare_for_model(model.card, b)
    elif method == "kpcn":
        model = load_kpcn(shipped_model_path("kpcn"))
        prepare_tensors(b, source_for(b, model.card.sources))
    elif method in ("nlm", "cross-bilateral"):
        prepare_inputs(b)
    else:
        raise AssertionError(f"the default chose {method}, which this test does not know")


def _load(tmp_path: Path, profile: str, guides: frozenset, var: bool) -> FeatureBuffers:
    writer = WRITERS[profile][0]
    name = f"{profile}_{'_'.join(sorted(guides)) or 'colour'}{'_var' if var else ''}.exr"
    path, spp, made = writer(tmp_path / name, guides, var)
    b = load_buffers(path, spp=spp)  # profile detected, as `mcdenoise denoise` reads it
    assert set(b.names()) == made, (profile, b.profile, b.names())
    return b


def test_the_cases_cover_every_profile_and_every_subset() -> None:
    assert (
        {p for p, _, _ in CASES}
        == set(WRITERS)
        == {
            "mcdenoise",
            "mitsuba",
            "cycles",
            "pbrt",
            "tungsten",
        }
    )
    assert len([c for c in CASES if c[0] in ("mcdenoise", "mitsuba")]) == 2 * 2 * 16


@pytest.mark.parametrize("profile", list(WRITERS))
def test_the_default_accepts_and_prepares_every_combination(tmp_path: Path, profile: str) -> None:
    for _, guides, var in [c for c in CASES if c[0] == profile]:
        b = _load(tmp_path, profile, guides, var)
        choice = registry.choose_method(b)
        m = choice.method
        assert m.accepts(b) is None, (profile, b.names(), m.name)
        prepare_for(m.name, b)
        assert m.name == expected_default(set(b.names())), (profile, b.names())
        for name, reason in choice.skipped:  # each one passed over says why, in one line
            assert reason and "\n" not in reason, (name, reason)
            assert registry.get_method(name).priority >= m.priority


@pytest.mark.parametrize(
    ("profile", "guides", "var", "method"),
    [
        ("mitsuba", frozenset(GUIDES), False, "kpcn"),  # the issue's plain aov file
        ("mcdenoise", frozenset(GUIDES), True, "kpcn"),
        ("mcdenoise", frozenset({"normal", "depth", "position"}), True, "kalantari-xbf"),
        ("cycles", frozenset({"depth"}), False, "nlm"),
        ("tungsten", frozenset({"albedo", "normal", "depth"}), True, "kpcn"),
    ],
)
def test_the_default_runs_on_representative_files(
    tmp_path: Path, profile: str, guides: frozenset, var: bool, method: str
) -> None:
    if method == "kpcn" and not shipped_model_path("kpcn").is_file():
        method = "kalantari-xbf" if var and {"normal", "depth", "position"} <= guides else "nlm"
    b = _load(tmp_path, profile, guides, var)
    result = denoise(b, device="cpu")
    assert result.method == method
    assert result.image.shape == (3, H, W) and bool(torch.isfinite(result.image).all())
    assert float(result.image.mean()) > 0


def test_the_plain_mitsuba_aov_file_is_refused_by_kalantari_with_the_reason(
    tmp_path: Path,
) -> None:
    b = _load(tmp_path, "mitsuba", frozenset(GUIDES), False)
    choice = registry.choose_method(b, exclude=("kpcn",))  # kpcn, first, accepts it
    skipped = dict(choice.skipped)
    assert list(skipped)[:2] == ["kalantari-xbf", "kalantari-nlm"]
    for reason in skipped.values():
        assert "albedo_var, normal_var, depth_var, position_var" in reason
        assert "trained with" in reason


def no_geometry() -> FeatureBuffers:
    """Every buffer and variance, but no geometry hit: depth and position 0 everywhere (a
    sky-only frame; Mitsuba writes 0 for misses), so there is no scene extent to normalise
    them by and the learned methods' preparation refuses them for what the pixels hold."""
    b = {k: torch.from_numpy(v) for k, v in scene().items()}
    for g in ("depth", "position"):
        b[g] = torch.zeros_like(b[g])
        b[f"{g}_var"] = torch.zeros_like(b[f"{g}_var"])
    return FeatureBuffers(b, spp=SPP, source="sky.exr")


def test_a_frame_without_geometry_gets_a_method_that_runs(tmp_path: Path) -> None:
    b = no_geometry()
    first = registry.choose_method(b).method.name
    with pytest.raises(MissingFeatureError):  # named explicitly, the first choice refuses
        denoise(b, first, device="cpu")
    result = denoise(b, device="cpu")  # the default goes on to the next method
    assert result.method != first and bool(torch.isfinite(result.image).all())
    save_buffers(tmp_path / "sky.exr", b)
    r = CliRunner().invoke(
        main,
        ["denoise", str(tmp_path / "sky.exr"), "-v", "--threads", "1"],
        catch_exceptions=False,
    )
    assert r.exit_code == 0, r.output
    assert f"sky.exr: skipped {first}: " in r.stderr
    assert r.stderr.splitlines()[-1] == (
        f"sky.exr: chose {result.method} (the best available method that accepts it)"
    )
    assert [p.name for p in tmp_path.glob("sky_*.exr")] == [f"sky_{result.method}.exr"]


# --- the contract: accepts, choose_method ---------------------------------------------------


def _frame(*names: str) -> FeatureBuffers:
    return FeatureBuffers({n: torch.rand(3 if n != "depth" else 1, 4, 4) for n in names})


def _color(b: FeatureBuffers, p: object, d: torch.device) -> torch.Tensor:
    return b["color"]


def test_accepts_checks_requires_then_the_hook_with_resolved_params() -> None:
    seen = []

    def check(b: FeatureBuffers, params) -> str | None:
        seen.append(dict(params))
        return None if "albedo_var" in b else f"needs albedo_var (k={params['k']})"

    m = Method("m", "t", ("color", "albedo"), (), {"k": 1}, _color, check_input=check)
    assert m.accepts(_frame("color")) == "needs albedo; the input has color"
    assert seen == []  # the hook is not asked when a required buffer is missing
    assert m.accepts(_frame("color", "albedo"), {"k": "3"}) == "needs albedo_var (k=3)"
    assert m.accepts(_frame("color", "albedo", "albedo_var")) is None
    assert seen[-1] == {"k": 1}
    assert Method("p", "t", ("color",), (), {}, _color).accepts(_frame("color")) is None


def test_choose_method_skips_refusing_and_unavailable_methods_with_reasons(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    registry.methods()
    monkeypatch.setattr(registry, "_REGISTRY", {})
    monkeypatch.setattr(registry, "_ALIASES", {})
    registry.register(
        Method("picky", "t", ("color",), (), {}, _color, priority=3, check_input=lambda b, p: "no")
    )
    registry.register(
        Method("absent", "t", ("color",), (), {}, _color, priority=2, unavailable=lambda: "gone")
    )
    registry.register(Method("plain", "t", ("color",), (), {}, _color, priority=1))
    choice = registry.choose_method(_frame("color"))
    assert choice.method.name == "plain"
    assert choice.skipped == (("picky", "no"), ("absent", "not available here: gone"))
    assert registry.best_method(_frame("color")).name == "plain"
    assert registry.best_method().name == "picky"  # no input: the best available
    monkeypatch.delitem(registry._REGISTRY, "plain")
    with pytest.raises(InputError, match=r"no denoising method can run .*picky: no"):
        registry.choose_method(_frame("color"))


def test_method_all_skips_a_refusing_method_with_its_reason(tmp_path: Path) -> None:
    path, _, _ = write_mitsuba(tmp_path / "aov.exr", frozenset(GUIDES), False)
    outcomes = list(denoise_paths([path], tmp_path / "out", "all", device="cpu", progress=False))
    skipped = {o.job.method.name: o.skipped for o in outcomes if o.skipped is not None}
    done = {o.job.method.name for o in outcomes if o.result is not None}
    assert all("\n" not in r for r in skipped.values())
    # the AO estimators need the camera this plain file does not record; nfor needs halves
    ao = {"ssao", "hbao", "alchemy", "gtao", "nnao"}
    assert all("no camera recorded" in skipped[k] for k in ao)
    assert all("color_a" in r for k, r in skipped.items() if k == "nfor")
    assert set(skipped) - ao - {"nfor"} == {"kalantari-xbf", "kalantari-nlm"}
    assert all("position_var" in skipped[k] for k in ("kalantari-xbf", "kalantari-nlm"))
    assert {"nlm", "cross-bilateral"} <= done
    assert all(o.result.output.is_file() for o in outcomes if o.result is not None)


# --- the command line ------------------------------------------------------------------------


def test_cli_default_on_a_plain_mitsuba_aov_file(tmp_path: Path) -> None:
    path, _, _ = write_mitsuba(tmp_path / "aov.exr", frozenset(GUIDES), False)
    runner = CliRunner()
    r = runner.invoke(main, ["denoise", str(path), "--threads", "1"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    made = sorted(p.name for p in tmp_path.glob("aov_*.exr"))
    want = "kpcn" if shipped_model_path("kpcn").is_file() else "nlm"
    assert made == [f"aov_{want}.exr"]
    r = runner.invoke(
        main,
        ["denoise", str(path), "-o", str(tmp_path / "v.exr"), "--verbose", "--threads", "1"],
        catch_exceptions=False,
    )
    assert r.exit_code == 0, r.output
    err = r.stderr.splitlines()
    if want == "nlm":  # without shipped kpcn weights the Kalantari models are passed over
        assert err[0].startswith("aov.exr: skipped kalantari-xbf: needs albedo_var")
    assert err[-1] == f"aov.exr: chose {want} (the best available method that accepts it)"
    assert "skipped" not in r.stdout
