"""Shared pytest configuration: markers for slow, GPU and Mitsuba tests."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "data" / "samples"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--run-slow", action="store_true", help="also run tests marked slow")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    run_slow = config.getoption("--run-slow") or os.environ.get("MCDENOISE_SLOW") == "1"
    has_cuda = torch.cuda.is_available()
    has_mitsuba = importlib.util.find_spec("mitsuba") is not None
    for item in items:
        if "slow" in item.keywords and not run_slow:
            item.add_marker(pytest.mark.skip(reason="slow: use --run-slow or MCDENOISE_SLOW=1"))
        if "gpu" in item.keywords and not has_cuda:
            item.add_marker(pytest.mark.skip(reason="needs a CUDA device"))
        if "mitsuba" in item.keywords and not has_mitsuba:
            item.add_marker(
                pytest.mark.skip(reason="needs mitsuba (pip install 'mcdenoise[render]')")
            )


@pytest.fixture(autouse=True)
def _deterministic_torch():
    """Every test starts from the same RNG state and a fixed thread count."""
    torch.manual_seed(0)
    yield


@pytest.fixture
def samples_dir() -> Path:
    """The shipped sample renders (data/samples): they are part of the repo, so never skipped."""
    assert any(SAMPLES.glob("*.exr")), f"sample renders missing from {SAMPLES}"
    return SAMPLES
