"""TrainConfig: TOML + overrides, type coercion, one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mcdenoise.errors import InputError
from mcdenoise.train.config import TrainConfig, load_config


def test_file_then_overrides_win_and_resolved_json_round_trips(tmp_path: Path) -> None:
    f = tmp_path / "c.toml"
    f.write_text('[train]\nmodel = "kalantari-nlm"\nsteps = 50\nhidden = [16, 8]\nlr = 0.01\n')
    cfg = load_config(f, {"steps": "7", "hidden": "4,2", "deterministic": "false"})
    assert (cfg.model, cfg.steps, cfg.hidden, cfg.lr, cfg.deterministic) == (
        "kalantari-nlm",
        7,
        [4, 2],
        0.01,
        False,
    )
    again = tmp_path / "config.json"
    again.write_text(cfg.to_json())
    assert load_config(again) == cfg
    assert json.loads(cfg.to_json())["guides"] == ["albedo", "normal", "depth", "position"]


@pytest.mark.parametrize(
    ("overrides", "needle"),
    [
        ({"stepz": "3"}, "unknown key(s) stepz"),
        ({"steps": "many"}, "'steps'"),
        ({"steps": "2.5"}, "'steps'"),
        ({"lr": "-1"}, "lr must be > 0"),
        ({"hidden": "4,x"}, "'hidden'"),
        ({"deterministic": "maybe"}, "'deterministic'"),
        ({"val_fraction": "1"}, "val_fraction"),
    ],
)
def test_bad_values_are_one_line_errors(overrides: dict, needle: str) -> None:
    with pytest.raises(InputError) as err:
        load_config(None, overrides)
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_bad_toml_names_the_file(tmp_path: Path) -> None:
    f = tmp_path / "bad.toml"
    f.write_text("steps = = 3\n")
    with pytest.raises(InputError, match=r"bad\.toml"):
        load_config(f)
    with pytest.raises(InputError, match="cannot read"):
        load_config(tmp_path / "missing.toml")


def test_defaults_are_valid() -> None:
    assert TrainConfig().steps > 0
