"""mcdenoise.threads: the thread count chosen on purpose, the OpenMP wait policy set before
torch starts, and one warning when a method runs far slower than its recorded speed."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from mcdenoise import threads
from mcdenoise.denoise import denoise
from mcdenoise.io import load_buffers
from mcdenoise.registry import get_method, methods, recorded_speed

SAMPLES = Path(__file__).resolve().parents[1] / "data" / "samples"


@pytest.fixture(autouse=True)
def _restore_threads():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


# --- wait policy --------------------------------------------------------------------------


def test_the_spin_is_bounded_unless_the_user_chose_a_policy() -> None:
    env: dict[str, str] = {}
    assert threads.set_wait_policy(env) == "GOMP_SPINCOUNT=10000"
    assert env == {"GOMP_SPINCOUNT": "10000"}
    active = {"OMP_WAIT_POLICY": "active"}
    assert threads.set_wait_policy(active) == "ACTIVE"
    assert active == {"OMP_WAIT_POLICY": "active"}
    spin = {"GOMP_SPINCOUNT": "0"}
    assert threads.set_wait_policy(spin) == "GOMP_SPINCOUNT=0"
    assert spin == {"GOMP_SPINCOUNT": "0"}
    assert threads.wait_policy({}) == "default"


def _fresh(code: str, **env: str) -> dict:
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("OMP_", "GOMP_"))}
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env={**clean, **env},
        check=True,
        timeout=120,
    )
    return json.loads(proc.stdout.strip().splitlines()[-1])


CHECK = (
    "import json, os, sys\n"
    "import mcdenoise_cli.main\n"
    "before = 'torch' in sys.modules\n"
    "import torch\n"
    "print(json.dumps({'torch_before': before, 'policy': os.environ.get('OMP_WAIT_POLICY'),"
    " 'spin': os.environ.get('GOMP_SPINCOUNT'), 'threads': torch.get_num_threads()}))"
)


def test_the_cli_sets_the_policy_before_torch_starts_in_a_fresh_process() -> None:
    seen = _fresh(CHECK)
    assert seen["torch_before"] is False  # importing the CLI does not start torch (libgomp)
    assert seen["spin"] == "10000" and seen["policy"] is None
    assert seen["threads"] >= 1


def test_the_cli_keeps_a_policy_and_thread_count_the_user_set() -> None:
    seen = _fresh(CHECK, OMP_WAIT_POLICY="ACTIVE", OMP_NUM_THREADS="1")
    assert seen["policy"] == "ACTIVE" and seen["spin"] is None and seen["threads"] == 1
    seen = _fresh(CHECK, GOMP_SPINCOUNT="1000")
    assert seen["policy"] is None and seen["spin"] == "1000"


# --- the thread count ---------------------------------------------------------------------


def test_an_explicit_request_wins_then_omp_num_threads_then_auto(monkeypatch) -> None:
    monkeypatch.setattr(threads, "auto_threads", lambda: (7, "auto: test"))
    assert threads.choose_threads(3, env={"OMP_NUM_THREADS": "2"}).threads == 3
    chosen = threads.choose_threads(None, env={"OMP_NUM_THREADS": "2"})
    assert (chosen.threads, chosen.source) == (2, "OMP_NUM_THREADS")
    chosen = threads.choose_threads(None, env={"OMP_NUM_THREADS": "junk"})
    assert (chosen.threads, chosen.source) == (7, "auto: test")
    with pytest.raises(ValueError):
        threads.choose_threads(0, env={})


@pytest.mark.parametrize(
    ("cores", "others", "expected"),
    [(2, 0, 2), (2, 1, 1), (2, 2, 1), (2, 9, 1), (8, 3, 5), (4, None, 4)],
)
def test_auto_takes_the_cores_not_busy_and_at_least_one(
    monkeypatch, cores, others, expected
) -> None:
    monkeypatch.setattr(threads, "physical_cores", lambda: cores)
    monkeypatch.setattr(threads, "other_running_tasks", lambda: others)
    assert threads.auto_threads()[0] == expected


def test_other_running_tasks_is_the_least_of_the_readings(tmp_path: Path, monkeypatch) -> None:
    readings = iter(["5/200", "3/200", "4/200"])
    path = tmp_path / "loadavg"

    def fake_read(self: Path) -> str:
        return f"0.50 0.40 0.30 {next(readings)} 1234\n"

    monkeypatch.setattr(Path, "read_text", fake_read)
    assert threads.other_running_tasks(samples=3, interval=0.0, loadavg=path) == 2
    monkeypatch.undo()
    assert threads.other_running_tasks(loadavg=tmp_path / "missing") is None


def test_physical_cores_counts_hyperthreads_once(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3})
    info = "\n\n".join(
        f"processor\t: {p}\nphysical id\t: 0\ncore id\t\t: {p // 2}" for p in range(4)
    )
    (tmp_path / "cpuinfo").write_text(info + "\n")
    assert threads.physical_cores(tmp_path / "cpuinfo") == 2
    assert threads.physical_cores(tmp_path / "missing") == 4


def test_apply_threads_sets_torch() -> None:
    assert threads.apply_threads(threads.ThreadChoice(1, "--threads", "default")) == 1
    assert torch.get_num_threads() == 1


# --- a method far slower than recorded ------------------------------------------------------


@pytest.fixture
def fresh_warnings(monkeypatch):
    monkeypatch.setattr(threads, "_warned", set())
    monkeypatch.setattr(threads, "MIN_WARN_SECONDS", 0.0)


def test_check_speed_warns_once_per_method_naming_the_cause(fresh_warnings, caplog) -> None:
    caplog.set_level(logging.WARNING, logger="mcdenoise.threads")
    pixels = 128 * 128
    expected = threads.expected_seconds("nlm", pixels)
    assert expected is not None and expected > 0
    assert threads.check_speed("nlm", 9 * expected, pixels, threads=2) is None  # within 10x
    message = threads.check_speed("nlm", 20 * expected, pixels, threads=2)
    assert message is not None and "20x" in message
    assert "another process is probably busy on the cores" in message
    assert "--threads 1" in message
    assert threads.check_speed("nlm", 50 * expected, pixels, threads=2) is None  # once only
    assert threads.check_speed("kpcn", 1e6, pixels, device="cuda") is None  # CPU only
    assert threads.check_speed("unknown-method", 1e6, pixels) is None
    assert [r.getMessage() for r in caplog.records] == [message]


def test_check_speed_on_one_thread_does_not_suggest_one_thread(fresh_warnings) -> None:
    message = threads.check_speed("kpcn", 1e6, 128 * 128, threads=1)
    assert message is not None and "--threads 1" not in message and "overloaded" in message


def test_denoise_warns_once_when_the_method_is_far_slower(
    fresh_warnings, monkeypatch, caplog
) -> None:
    buffers = load_buffers(SAMPLES / "cornell_spp4.exr").crop(0, 0, 24, 24)
    monkeypatch.setitem(
        get_method("cross-bilateral").recorded_speed, "cross-bilateral", (1e-9, 1e-9)
    )
    caplog.set_level(logging.WARNING, logger="mcdenoise.threads")
    denoise(buffers, "cross-bilateral", device="cpu")
    denoise(buffers, "cross-bilateral", device="cpu")
    slow = [r for r in caplog.records if "cross-bilateral took" in r.getMessage()]
    assert len(slow) == 1


def test_denoise_at_its_recorded_speed_does_not_warn(fresh_warnings, monkeypatch, caplog) -> None:
    buffers = load_buffers(SAMPLES / "cornell_spp4.exr").crop(0, 0, 24, 24)
    monkeypatch.setitem(get_method("cross-bilateral").recorded_speed, "cross-bilateral", (1e6, 0.0))
    caplog.set_level(logging.WARNING, logger="mcdenoise.threads")
    denoise(buffers, "cross-bilateral", device="cpu")
    assert not caplog.records


def test_every_shipped_method_has_a_recorded_speed() -> None:
    for m in methods():
        assert m.name in m.recorded_speed, m.name
        assert recorded_speed(m.name) == m.recorded_speed[m.name]


def test_a_parameter_that_multiplies_the_cost_has_its_own_recorded_speed() -> None:
    # kalantari-xbf with per-region selection runs 42 filters: judged against the model
    # alone's record it would warn "overloaded" on an idle machine.
    for name in ("kalantari-xbf", "kalantari-nlm"):
        m = get_method(name)
        assert m.speed_name(m.resolve_params(None)) == name
        key = m.speed_name(m.resolve_params({"select": "auto"}))
        assert key == f"{name}+select" and key in m.recorded_speed
        assert threads.expected_seconds(key, 10**6) > 50 * threads.expected_seconds(name, 10**6)
    assert get_method("nlm").speed_name({}) == "nlm"
