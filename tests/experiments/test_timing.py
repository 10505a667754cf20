"""Tests of ``mcdenoise/experiments/timing.py``: warm-up, medians, threads, machine."""

from __future__ import annotations

import pytest
import torch

from mcdenoise.experiments.timing import machine_info, time_runs, torch_threads


def scripted(seconds):
    it = iter(seconds)
    count = {"n": 0}

    def run():
        count["n"] += 1
        return count["n"], next(it), "cpu"

    return run, count


def test_warmup_is_excluded_and_the_median_reported():
    run, count = scripted([50.0, 3.0, 1.0, 2.0])
    result, t = time_runs(run, repetitions=3, warmup=1)
    assert count["n"] == 4 and result == 4  # the last run's result
    assert t.warmup == (50.0,) and t.runs == (3.0, 1.0, 2.0) and t.median == 2.0
    assert t.device == "cpu" and t.threads == torch.get_num_threads()
    run, _ = scripted([5.0, 1.0])
    _, t = time_runs(run, repetitions=2, warmup=0)
    assert t.median == 3.0 and t.warmup == ()
    with pytest.raises(ValueError):
        time_runs(run, repetitions=0)


def test_torch_threads_are_restored():
    before = torch.get_num_threads()
    with torch_threads(1) as n:
        assert n == 1 == torch.get_num_threads()
    assert torch.get_num_threads() == before
    with torch_threads(None) as n:
        assert n == before


def test_machine_info_names_cpu_and_threads():
    info = machine_info()
    assert info["cpu_count"] >= 1 and info["torch_threads"] == torch.get_num_threads()
    assert isinstance(info["cpu"], str) and info["cpu"]
