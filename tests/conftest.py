"""Shared pytest configuration: markers for slow, GPU, Mitsuba and heavy tests."""

from __future__ import annotations

import importlib.util
import os
import warnings
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "data" / "samples"
HEAVY_LIST = Path(__file__).with_name("heavy_tests.txt")


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--run-slow", action="store_true", help="also run tests marked slow")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    run_slow = config.getoption("--run-slow") or os.environ.get("MCDENOISE_SLOW") == "1"
    has_cuda = torch.cuda.is_available()
    has_mitsuba = importlib.util.find_spec("mitsuba") is not None
    _mark_heavy(items)
    for item in items:
        if "slow" in item.keywords and not run_slow:
            item.add_marker(pytest.mark.skip(reason="slow: use --run-slow or MCDENOISE_SLOW=1"))
        if "gpu" in item.keywords and not has_cuda:
            item.add_marker(pytest.mark.skip(reason="needs a CUDA device"))
        if "mitsuba" in item.keywords and not has_mitsuba:
            item.add_marker(
                pytest.mark.skip(reason="needs mitsuba (pip install 'mcdenoise[render]')")
            )


def _heavy_entries() -> list[str]:
    lines = (line.split("#", 1)[0].strip() for line in HEAVY_LIST.read_text().splitlines())
    return [line for line in lines if line]


def _mark_heavy(items: list[pytest.Item]) -> None:
    """Mark ``heavy`` every test named in ``tests/heavy_tests.txt`` (the one list of what the
    fast tier, ``make test-fast`` = ``pytest -m "not heavy"``, leaves out). An entry is a
    node-id prefix: a file, a test with all its parameters, or one parametrised case. An
    entry whose file was collected but matches none of its tests is stale: warn."""
    entries = _heavy_entries()
    used: set[str] = set()
    for item in items:
        node = item.nodeid
        for entry in entries:
            if node == entry or node.startswith((entry + "::", entry + "[")):
                item.add_marker(pytest.mark.heavy)
                used.add(entry)
                break
    files = {item.nodeid.split("::", 1)[0] for item in items}
    for entry in entries:
        if entry not in used and entry.split("::", 1)[0] in files:
            warnings.warn(
                pytest.PytestWarning(f"{HEAVY_LIST.name}: {entry} matches no test"),
                stacklevel=1,
            )


@pytest.fixture(autouse=True)
def _deterministic_torch():
    """Every test starts from the same RNG state and a fixed thread count."""
    torch.manual_seed(0)
    yield


@pytest.fixture(autouse=True)
def _drjit_pool_restored():
    """Dr.Jit's thread pool as it was before the test: a test that renders with
    ``--threads 1`` in this process leaves a 1-thread pool behind, and Mitsuba 3.9.1 hangs
    in ``Bitmap.write`` (and loading an envmap) with one thread (see
    ``mcdenoise/render/scenes.py``), which froze a later test of the full run."""
    import sys

    before = sys.modules["drjit"].thread_count() if "drjit" in sys.modules else None
    yield
    dr = sys.modules.get("drjit")
    if dr is None:
        return
    if before is None:  # imported during the test: Dr.Jit's default pool is one per core
        before = max(2, os.cpu_count() or 2)
    if dr.thread_count() != before:
        dr.set_thread_count(before)


@pytest.fixture(scope="module", autouse=True)
def _one_thread_modules(request: pytest.FixtureRequest):
    """Modules that set ``ONE_THREAD = True`` run with one intra-op thread (before their own
    module fixtures): two cores are shared with other jobs, and these tests time nothing."""
    if not getattr(request.module, "ONE_THREAD", False):
        yield
        return
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


@pytest.fixture
def interrupted_training(monkeypatch: pytest.MonkeyPatch):
    """``run(train_fn, cfg, out, at)``: ``train_fn(cfg, out)`` with a Ctrl-C raised when the
    patch sampler draws its ``at``-th batch (a kill in the middle of step ``at``)."""
    from mcdenoise.train.patches import PatchSampler

    def run(train_fn, cfg, out, at: int) -> None:
        real_batch = PatchSampler.batch
        calls = {"n": 0}

        def killed(self, size, g):
            calls["n"] += 1
            if calls["n"] == at:
                raise KeyboardInterrupt
            return real_batch(self, size, g)

        monkeypatch.setattr(PatchSampler, "batch", killed)
        try:
            with pytest.raises(KeyboardInterrupt):
                train_fn(cfg, out, progress=False)
        finally:
            monkeypatch.setattr(PatchSampler, "batch", real_batch)

    return run


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


@pytest.fixture
def plugins(monkeypatch: pytest.MonkeyPatch):
    """``plugins(*entry_points)``: a fresh method table whose built-ins load with these
    plugins (``shared_inputs.EntryPoint``), as if those packages were installed."""
    from mcdenoise import registry

    def install(*eps: object) -> None:
        monkeypatch.setattr(registry, "_REGISTRY", {})
        monkeypatch.setattr(registry, "_ALIASES", {})
        monkeypatch.setattr(registry, "_PLUGINS", set())
        monkeypatch.setattr(registry, "_builtins", {"state": "no"})
        monkeypatch.setattr(registry, "_entry_points", lambda: list(eps))

    return install
