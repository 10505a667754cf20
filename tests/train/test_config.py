"""TrainConfig: TOML + overrides, type coercion, one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

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


#: Settings of a recipe that describe the machine or the data, not the model or its training.
NOT_RECIPE = {"data", "threads"}


def test_kpcn_defaults_are_the_recipe_of_the_shipped_weights() -> None:
    """``mcdenoise train --model kpcn`` with no other setting trains what the shipped weights'
    first stage trained (data/recipes/kpcn.md; the card records the resolved config of each
    stage: the shipped model is the last fine-tuning, ``base_training`` the one it started
    from, down to the model from scratch)."""
    import mcdenoise

    weights = Path(mcdenoise.__file__).parent / "models" / "weights" / "kpcn.pt"
    card = torch.load(weights, map_location="cpu", weights_only=True)["card"]
    first = card["training"]
    while "base_training" in first:  # the fine-tunings' chain back to the model from scratch
        first = first["base_training"]
    recipe = first["config"]
    cfg = load_config(None, {"model": "kpcn"}).to_dict()
    keys = sorted(set(recipe) - NOT_RECIPE)
    assert {k: cfg[k] for k in keys} == {k: recipe[k] for k in keys}
    assert cfg["kernel"] == card["kernel"] == 5
    # a file or a flag still wins over the model's defaults
    assert load_config(None, {"model": "kpcn", "kernel": "11"}).kernel == 11


def test_model_defaults_apply_to_new_models_only(tmp_path: Path) -> None:
    plain = TrainConfig()
    assert load_config(None, {}) == plain  # kalantari-xbf: the field defaults
    # from a base (continued training, a new encoder) the architecture is the base's
    cont = load_config(None, {"model": "kpcn", "base": "run"})
    assert (cont.kernel, cont.steps, cont.lr) == (0, plain.steps, plain.lr)
    # a resolved config.json (every field) is reproduced exactly, whatever the defaults
    f = tmp_path / "config.json"
    f.write_text(TrainConfig(model="kpcn", steps=7).to_json())
    again = load_config(f)
    assert (again.kernel, again.steps, again.lr) == (0, 7, plain.lr)
