"""The trainer table and ``train_model`` (what ``mcdenoise train`` calls): which trainer a
config goes to, how flags, files and the run folder combine, and the printed lines."""

from __future__ import annotations

from pathlib import Path

import pytest

import mcdenoise.train.kalantari as kalantari_module
import mcdenoise.train.kpcn as kpcn_module
from mcdenoise.errors import InputError
from mcdenoise.train.config import TrainConfig
from mcdenoise.train.loop import TrainResult
from mcdenoise.train.patches import LoadReport
from mcdenoise.train.trainers import TRAINERS, get_trainer, train_model


@pytest.fixture
def calls(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, TrainConfig, bool]]:
    """Both training functions replaced by fakes that record (which, config, resume)."""
    seen: list[tuple[str, TrainConfig, bool]] = []

    def fake(which: str):
        def train(cfg, out, *, resume=False, progress=True):
            seen.append((which, cfg, resume))
            metrics = [{"step": 3, "val_loss": 0.5}]
            return TrainResult(3, 0.5, 0, 2.0, metrics), LoadReport(used=2)

        return train

    monkeypatch.setattr(kalantari_module, "train_kalantari", fake("kalantari"))
    monkeypatch.setattr(kpcn_module, "train_kpcn", fake("kpcn"))
    return seen


def test_every_model_has_one_trainer() -> None:
    names = [t.name for t in TRAINERS]
    assert names == ["kalantari-xbf", "kalantari-nlm", "kpcn", "kpcn-temporal", "nnao", "auxnet"]
    assert get_trainer("kpcn").accepts >= {"finetune_encoder", "base", "channels"}
    with pytest.raises(InputError, match="unknown model 'unet'; trainable: kalantari-xbf"):
        get_trainer("unet")


def test_train_model_dispatches_by_model(calls, tmp_path: Path) -> None:
    for model, which in (("kalantari-nlm", "kalantari"), ("kpcn", "kpcn"), (None, "kalantari")):
        outcome = train_model(tmp_path / "r", model=model, data="d", steps=3, progress=False)
        assert calls[-1][0] == which and outcome.config.steps == 3
    assert calls[-1][1].model == "kalantari-xbf"  # the default
    with pytest.raises(InputError, match="unknown model"):
        train_model(tmp_path / "r", model="unet", progress=False)


def test_finetune_encoder_alone_means_kpcn(calls, tmp_path: Path) -> None:
    train_model(tmp_path / "r", finetune_encoder="basic", base="run", progress=False)
    which, cfg, _ = calls[-1]
    assert which == "kpcn" and (cfg.finetune_encoder, cfg.base) == ("basic", "run")


def test_flags_win_over_overrides_and_resume_reads_the_run_folder(calls, tmp_path: Path) -> None:
    run = tmp_path / "r"
    (run).mkdir()
    (run / "config.json").write_text(TrainConfig(model="kpcn", steps=9, lr=0.02).to_json())
    train_model(run, resume=True, overrides={"lr": "0.5"}, steps=4, progress=False)
    which, cfg, resume = calls[-1]
    assert (which, cfg.model, cfg.steps, cfg.lr, resume) == ("kpcn", "kpcn", 4, 0.5, True)


def test_messages_report_the_run_and_warn_on_stderr(tmp_path: Path) -> None:
    from mcdenoise.train.trainers import TrainOutcome

    last = {
        "val_ratio": 0.9,
        "val_scale1_weight": 0.5,
        "val_scale2_weight": 0.001,
        "val_full_ratio_to_noisy": 1.5,
    }
    outcome = TrainOutcome(
        TrainConfig(model="kpcn"),
        tmp_path,
        TrainResult(5, 0.25, 0, 12.0, [last]),
        LoadReport(used=2, skipped=[("a.exr", "no albedo")]),
    )
    lines = outcome.messages()
    assert [err for _, err in lines] == [True, False, False, False, True]
    text = [line for line, _ in lines]
    assert text[1] == (
        "trained kpcn for 5 steps in 12 s; best validation relMSE 0.25 "
        "(learned/fixed geometric mean 0.900)"
    )
    assert text[2] == f"model: {tmp_path / 'model.pt'}"
    assert "1/4 scale is unused" in text[3] and "1/2 scale is unused" not in text[3]
    assert "worse than its noisy input (full 1.50x)" in text[4]
