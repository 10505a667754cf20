"""Tests of ``mcdenoise/experiments/spec.py``: the schema, its defaults, and errors that name
the file and the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from mcdenoise.experiments.spec import load_experiment, parse_experiment
from mcdenoise.experiments.spec_fields import ExperimentError

REPO = Path(__file__).resolve().parents[2]
SCENES = REPO / "data" / "scenes"


def parse(text_or_dict, tmp_path: Path | None = None):
    import tomllib

    data = tomllib.loads(text_or_dict) if isinstance(text_or_dict, str) else text_or_dict
    return parse_experiment(data, source="exp.toml", base=tmp_path or SCENES)


def error_of(data, tmp_path: Path | None = None) -> str:
    with pytest.raises(ExperimentError) as info:
        parse(data, tmp_path)
    msg = str(info.value)
    assert msg.startswith("exp.toml: "), msg
    assert "\n" not in msg
    return msg


MINIMAL = {"scenes": {"specs": ["cornell.toml"]}}


def test_minimal_spec_gets_documented_defaults():
    spec = parse(MINIMAL)
    assert spec.name == "exp"  # the file stem
    assert spec.scene_specs == ((SCENES / "cornell.toml").resolve(),)
    assert spec.methods == "all" and spec.sweeps == ()
    assert (spec.width, spec.height, spec.spp, spec.ref_spp) == (128, 128, (1, 2, 4, 8, 16), 1024)
    assert (spec.repetitions, spec.warmup, spec.device) == (3, 1, "cpu")
    assert spec.metrics is None and spec.baseline == "noisy" and spec.outputs == "all"
    assert spec.strip_level(spec.spp) == 4  # the middle level
    d = spec.to_dict()
    assert d["render"]["spp"] == [1, 2, 4, 8, 16] and d["methods"] == "all"


def test_full_spec_round_trips_every_section():
    spec = parse(
        """
        name = "x"
        methods = ["nlm", "xbf"]
        metrics = ["relmse", "ssim"]
        repetitions = 2
        warmup = 0
        threads = 1
        [scenes]
        specs = ["."]
        random = 2
        [render]
        resolution = [64, 48]
        spp = [2, 8]
        ref_spp = 256
        variant = "scalar_rgb"
        [params.nlm]
        search_radius = 4
        [[sweep]]
        method = "xbf"
        param = "kernel_size"
        values = [5, 11]
        params = { sigma_spatial = 3.0 }
        [stats]
        baseline = "nlm"
        bootstrap = 500
        confidence = 0.9
        [report]
        strip_spp = 8
        budgets = [2, 0.5]
        outputs = "strip"
        """
    )
    assert len(spec.scene_specs) == len(list(SCENES.glob("*.toml"))) == 11  # a folder expands
    assert spec.random == 2 and (spec.width, spec.height) == (64, 48)
    assert spec.methods == ("nlm", "xbf") and spec.params == {"nlm": {"search_radius": 4}}
    (sw,) = spec.sweeps
    assert (sw.method, sw.param, sw.values, dict(sw.params)) == (
        "xbf",
        "kernel_size",
        (5, 11),
        {"sigma_spatial": 3.0},
    )
    assert spec.metrics == ("relmse", "ssim") and spec.threads == 1
    assert spec.budgets == (0.5, 2.0) and spec.outputs == "strip" and spec.strip_level([2, 8]) == 8
    assert (spec.baseline, spec.bootstrap, spec.confidence) == ("nlm", 500, 0.9)


@pytest.mark.parametrize(
    ("data", "where"),
    [
        ({**MINIMAL, "colour": 1}, "top level: unknown key(s) colour"),
        ({"scenes": {"specs": ["nope.toml"]}}, "scenes.specs[0]: 'nope.toml' not found"),
        ({"scenes": {}}, "scenes: no scenes"),
        ({"scenes": {"specs": ["cornell.toml"], "folder": "."}}, "scenes: give either"),
        ({**MINIMAL, "render": {"spp": [4, 2]}}, "render.spp: must be strictly increasing"),
        ({**MINIMAL, "render": {"spp": [1, 0]}}, "render.spp[1]: must be >= 1"),
        ({**MINIMAL, "render": {"spp": [1, 64], "ref_spp": 64}}, "render.ref_spp: must exceed"),
        ({**MINIMAL, "render": {"resolution": [1, 2, 3]}}, "render.resolution: must be N or"),
        ({**MINIMAL, "render": {"variant": "fast"}}, "render.variant: 'fast' is not one of"),
        ({**MINIMAL, "methods": "some"}, 'methods: must be "all" or a list'),
        ({**MINIMAL, "methods": ["nlm", "nlmm"]}, "methods[1]: unknown method 'nlmm'"),
        ({**MINIMAL, "methods": ["nlm", "nlm"]}, "methods: names a method twice"),
        (
            {**MINIMAL, "params": {"nlm": {"radius": 3}}},
            "params.nlm: method 'nlm' has no parameter 'radius'",
        ),
        ({**MINIMAL, "params": {"noisy": {"x": 1}}}, "params.noisy: 'noisy'"),
        (
            {**MINIMAL, "sweep": [{"method": "xbf", "param": "size", "values": [3]}]},
            "sweep[0].values[0]: method 'cross-bilateral' has no parameter 'size'",
        ),
        (
            {**MINIMAL, "sweep": [{"method": "xbf", "param": "kernel_size", "values": [3, "x"]}]},
            "sweep[0].values[1]: parameter kernel_size='x' is not a valid int",
        ),
        ({**MINIMAL, "sweep": [{"method": "xbf", "values": [3]}]}, "sweep[0].param: missing"),
        (
            {**MINIMAL, "sweep": [{"method": "xbf", "param": "kernel_size", "values": [3, 3]}]},
            "sweep[0].values: lists a value twice",
        ),
        ({**MINIMAL, "metrics": ["ssim"]}, "metrics: must include relmse"),
        ({**MINIMAL, "metrics": ["relmse", "ssimm"]}, "metrics: unknown metric 'ssimm'"),
        ({**MINIMAL, "repetitions": 0}, "repetitions: must be >= 1"),
        ({**MINIMAL, "device": "tpu"}, "device: 'tpu' is not one of"),
        ({**MINIMAL, "stats": {"confidence": 1.5}}, "stats.confidence: must be a number in"),
        ({**MINIMAL, "report": {"strip_spp": 3}}, "report.strip_spp: 3 is not a level"),
        ({**MINIMAL, "report": {"budgets": [1, -2]}}, "report.budgets[1]: must be seconds > 0"),
        ({**MINIMAL, "report": {"outputs": "some"}}, "report.outputs: 'some' is not one of"),
    ],
)
def test_errors_name_the_file_and_the_key(data, where):
    assert where in error_of(data)


def test_scene_spec_paths_are_collected_like_the_render_command(tmp_path: Path):
    """Folders stand for their *.toml (``collect_specs``, as for ``mcdenoise render``); errors
    are named by the key."""
    (tmp_path / "empty").mkdir()
    (tmp_path / "two").mkdir()
    for name in ("b.toml", "a.toml", "notes.txt"):
        (tmp_path / "two" / name).write_text("", encoding="utf-8")
    spec = parse({"scenes": {"specs": ["two"]}}, tmp_path)
    assert [p.name for p in spec.scene_specs] == ["a.toml", "b.toml"]
    msg = error_of({"scenes": {"specs": ["two", "empty"]}}, tmp_path)
    assert "scenes.specs[1]: folder 'empty' holds no *.toml scene spec" in msg
    msg = error_of({"scenes": {"specs": ["two", "two/a.toml"]}}, tmp_path)
    assert "scenes.specs: names a scene spec twice" in msg


def test_folder_scenes_allow_only_a_subset_of_spp(tmp_path: Path):
    (tmp_path / "rendered").mkdir()
    spec = parse({"scenes": {"folder": "rendered"}}, tmp_path)
    assert spec.folder == (tmp_path / "rendered").resolve() and not spec.spp_given
    assert spec.to_dict()["render"] == {"spp": None, "from_folder": True}
    msg = error_of({"scenes": {"folder": "rendered"}, "render": {"ref_spp": 99}}, tmp_path)
    assert "render.ref_spp: not allowed with scenes.folder" in msg
    assert "scenes.folder: 'missing' is not a folder" in error_of(
        {"scenes": {"folder": "missing"}}, tmp_path
    )


def test_load_experiment_errors(tmp_path: Path):
    with pytest.raises(ExperimentError, match="experiment spec not found"):
        load_experiment(tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("name = [", encoding="utf-8")
    with pytest.raises(ExperimentError, match=r"bad\.toml: not valid TOML"):
        load_experiment(bad)
    ok = tmp_path / "sub" / "named.toml"
    ok.parent.mkdir()
    ok.write_text(f'[scenes]\nspecs = ["{SCENES / "cornell.toml"}"]\n', encoding="utf-8")
    spec = load_experiment(ok)
    assert spec.name == "named" and spec.source == str(ok)


@pytest.mark.parametrize("name", ["demo", "full"])
def test_shipped_experiments_load(name: str):
    spec = load_experiment(REPO / "data" / "experiments" / f"{name}.toml")
    assert spec.methods == "all" and spec.scene_specs
    assert all(p.is_file() and p.parent == SCENES for p in spec.scene_specs)
    assert 1 <= spec.repetitions <= 3 and spec.strip_level(spec.spp) in spec.spp
    if name == "demo":
        assert len(spec.scene_specs) == 4 and (spec.width, spec.height) == (128, 128)
        assert spec.spp == (1, 2, 4, 8, 16, 32, 64) and spec.ref_spp == 1024
    else:
        assert len(spec.scene_specs) == 11 and spec.random > 0 and spec.width == 256
