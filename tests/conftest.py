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


def make_tiny_dataset(folder: Path, size: int = 40, y0: int = 44, x0: int = 44) -> Path:
    """A data set in the ``mcdenoise render`` layout cut from the shipped sample renders.

    ``folder/<scene>.exr`` (parts ``spp4``, ``spp16``: ``size``² crops of the real renders,
    every buffer) and ``folder/ref/<scene>.exr`` (the reference crop).
    """
    from mcdenoise.io import load_buffers, save_buffers
    from mcdenoise.io.buffer_files import save_buffers_parts

    (folder / "ref").mkdir(parents=True, exist_ok=True)
    for ref in sorted((SAMPLES / "ref").glob("*.exr")):
        scene = ref.stem
        parts = {
            f"spp{spp}": load_buffers(SAMPLES / f"{scene}_spp{spp}.exr").crop(y0, x0, size, size)
            for spp in (4, 16)
        }
        for fb in parts.values():
            fb.data_window = fb.display_window = (0, 0, size - 1, size - 1)
        save_buffers_parts(folder / f"{scene}.exr", parts)
        rb = load_buffers(ref).crop(y0, x0, size, size)
        rb.data_window = rb.display_window = (0, 0, size - 1, size - 1)
        save_buffers(folder / "ref" / f"{scene}.exr", rb)
    return folder


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """See :func:`make_tiny_dataset` (made once per test session)."""
    return make_tiny_dataset(tmp_path_factory.mktemp("tiny-set"))
