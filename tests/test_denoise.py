"""The one entry point: ``denoise_sequence`` (per-frame and temporal methods), ``denoise`` as
its one-frame case, and the job planning behind ``mcdenoise denoise`` (``plan_jobs``)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest
import torch

from mcdenoise import registry
from mcdenoise.batch import OptionError, denoise_paths, plan_jobs
from mcdenoise.denoise import denoise, denoise_sequence
from mcdenoise.errors import InputError
from mcdenoise.io import FeatureBuffers, save_buffers
from mcdenoise.io.buffers import MissingFeatureError
from mcdenoise.method import Method

ONE_THREAD = True


def frame(seed: int, h: int = 8, w: int = 10, *, features: bool = True) -> FeatureBuffers:
    g = torch.Generator().manual_seed(seed)
    b = {"color": torch.rand(3, h, w, generator=g) * 2}
    if features:
        b["albedo"] = torch.rand(3, h, w, generator=g)
        b["normal"] = torch.rand(3, h, w, generator=g) * 2 - 1
        b["motion"] = torch.zeros(2, h, w)
    return FeatureBuffers(b, spp=4)


class Ema:
    """A temporal toy: exponential moving average of the colour over the frames (state: the
    history), recording what it received."""

    def __init__(self, alpha: float = 0.5) -> None:
        self.alpha = alpha
        self.seen: list[FeatureBuffers] = []

    def __call__(
        self, frames: Iterable[FeatureBuffers], params: Mapping[str, Any], device: torch.device
    ) -> Iterator[torch.Tensor]:
        history = None
        for f in frames:
            self.seen.append(f)
            c = f["color"]
            history = (
                c if history is None else params["alpha"] * c + (1 - params["alpha"]) * history
            )
            yield history


def ema_method(run_sequence: Ema, **kw: Any) -> Method:
    return Method(
        name="ema",
        summary="moving average over frames (test)",
        requires=("color",),
        uses=("motion",),
        defaults={"alpha": 0.5},
        run=None,
        temporal=True,
        run_sequence=run_sequence,
        **kw,
    )


def test_a_registered_temporal_method_gets_the_frames_in_order_and_keeps_state(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    registry.methods()  # the built-ins are in the table before it is copied
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    ema = Ema()
    registry.register(ema_method(ema))
    frames = [frame(i) for i in range(4)]
    results = list(denoise_sequence(frames, "ema", params={"alpha": "0.25"}, device="cpu"))
    assert [r.method for r in results] == ["ema"] * 4
    assert len(ema.seen) == 4
    assert all(torch.equal(s["color"], f["color"]) for s, f in zip(ema.seen, frames))
    assert all(set(f.names()) == {"color", "motion"} for f in ema.seen)  # requires + uses only
    want = None
    for f, r in zip(frames, results):
        want = f["color"] if want is None else 0.25 * f["color"] + 0.75 * want
        torch.testing.assert_close(r.image, want)
    assert results[0].params == {"alpha": 0.25}
    assert all(r.seconds >= 0 and r.device == "cpu" for r in results)


def test_a_lazy_sequence_is_read_one_frame_at_a_time() -> None:
    ema = Ema()
    read: list[int] = []

    def frames() -> Iterator[FeatureBuffers]:
        for i in range(3):
            read.append(i)
            yield frame(i)

    results = denoise_sequence(frames(), ema_method(ema), device="cpu")
    assert read == [0]  # the first frame is checked before this returns
    first = next(results)
    assert read == [0] and first.image.shape == (3, 8, 10)
    assert len(list(results)) == 2 and read == [0, 1, 2]


def test_one_frame_sequence_equals_denoise() -> None:
    b = frame(3)
    b["color"][0, 0, 0] = float("nan")
    for name in ("nlm", "cross-bilateral"):
        (seq,) = denoise_sequence([b], name, device="cpu")
        one = denoise(b, name, device="cpu")
        assert torch.equal(seq.image, one.image)
        assert (seq.method, seq.params, seq.device, seq.repaired) == (
            one.method,
            one.params,
            one.device,
            one.repaired,
        )
        assert one.repaired == {"color": 1}


def test_a_per_frame_method_through_a_sequence_equals_denoise_per_frame() -> None:
    frames = [frame(i) for i in range(3)]
    results = list(denoise_sequence(frames, "nlm", device="cpu"))
    assert len(results) == 3
    for f, r in zip(frames, results):
        assert torch.equal(r.image, denoise(f, "nlm", device="cpu").image)


def test_per_frame_methods_run_each_frame_alone() -> None:
    calls: list[int] = []

    def run(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> torch.Tensor:
        calls.append(int(b["color"].sum() * 1000))
        return b["color"] * 2

    m = Method("double", "x2", ("color",), (), {}, run)
    frames = [frame(i) for i in range(3)]
    out = [r.image for r in denoise_sequence(frames, m, device="cpu")]
    assert len(calls) == 3
    for f, o in zip(frames, out):
        torch.testing.assert_close(o, f["color"] * 2)


def test_output_sanitising_applies_to_every_frame() -> None:
    def run_sequence(frames, params, device):
        for i, f in enumerate(frames):
            out = f["color"].clone() - 0.5  # negatives
            out[0, 0, i] = float("nan")
            out[1, 0, i] = float("inf")
            yield out.double()

    m = Method("bad", "test", ("color",), (), {}, None, temporal=True, run_sequence=run_sequence)
    for r in denoise_sequence([frame(i) for i in range(3)], m, device="cpu"):
        assert r.image.dtype == torch.float32 and r.image.device.type == "cpu"
        assert bool(torch.isfinite(r.image).all()) and bool((r.image >= 0).all())


def test_requires_and_devices_are_checked_before_any_frame_is_denoised() -> None:
    ema = Ema()
    needs_albedo = Method(
        "needs-albedo", "t", ("color", "albedo"), (), {}, None,
        temporal=True, run_sequence=ema,
    )  # fmt: skip
    with pytest.raises(MissingFeatureError, match="albedo"):
        denoise_sequence([frame(0, features=False), frame(1)], needs_albedo, device="cpu")
    # a later frame without the buffer: refused when it is reached, never handed over
    results = denoise_sequence([frame(0), frame(1, features=False)], needs_albedo, device="cpu")
    next(results)
    with pytest.raises(MissingFeatureError, match="albedo"):
        next(results)
    assert len(ema.seen) == 1
    cuda_only = ema_method(Ema(), devices=("cuda",))
    with pytest.raises(InputError, match="does not run on cpu"):
        denoise_sequence([frame(0)], cuda_only, device="cpu")
    unavailable = ema_method(Ema(), unavailable=lambda: "no library")
    with pytest.raises(InputError, match="no library"):
        denoise_sequence([frame(0)], unavailable, device="cpu")
    with pytest.raises(InputError, match="has no parameter 'beta'"):
        denoise_sequence([frame(0)], ema_method(Ema()), params={"beta": 1}, device="cpu")


def test_a_method_must_give_one_output_per_frame_of_the_right_shape() -> None:
    def too_few(frames, params, device):
        for f in list(frames)[:-1]:
            yield f["color"]

    def wrong_shape(frames, params, device):
        for f in frames:
            yield f["color"][:, :4]

    for fn, needle in ((too_few, "outputs for a longer sequence"), (wrong_shape, "shape")):
        m = Method("m", "t", ("color",), (), {}, None, temporal=True, run_sequence=fn)
        with pytest.raises(RuntimeError, match=needle):
            list(denoise_sequence([frame(0), frame(1)], m, device="cpu"))


def test_an_empty_sequence_gives_no_results() -> None:
    assert list(denoise_sequence([], "nlm", device="cpu")) == []


def test_method_contract_validation() -> None:
    with pytest.raises(ValueError, match="temporal"):
        Method("t", "t", ("color",), (), {}, lambda b, p, d: b["color"], temporal=True)
    with pytest.raises(ValueError, match="neither"):
        Method("t", "t", ("color",), (), {}, None)


# --- jobs of mcdenoise denoise ---------------------------------------------------------------


def _write(path: Path, *, features: bool) -> Path:
    save_buffers(path, frame(0, features=features))
    return path


def test_plan_jobs_auto_decides_per_input_and_all_plans_every_method(tmp_path: Path) -> None:
    a = _write(tmp_path / "a.exr", features=True)
    b = _write(tmp_path / "b.exr", features=False)
    plan = plan_jobs([a, b])
    assert [(j.input, j.output, j.method) for j in plan.jobs] == [(a, None, None), (b, None, None)]
    plan = plan_jobs([a], tmp_path / "out", "nlm,xbf", part="spp4")
    assert [j.output for j in plan.jobs] == [
        tmp_path / "out" / "a_spp4_nlm.exr",
        tmp_path / "out" / "a_spp4_cross-bilateral.exr",
    ]
    assert not plan.skip_missing and plan_jobs([a], method="all").skip_missing


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"method": "nlm,xbf", "params": {"radius": "3"}}, "--param needs exactly one --method"),
        ({"method": "nlm,xbf", "output": "x.exr"}, "give -o a folder"),
        ({"params": {"model": "run"}}, "--param needs an explicit --method"),
        ({"method": "nlm", "model": "run"}, "--model needs exactly one learned --method"),
    ],
)
def test_plan_jobs_refuses_options_that_do_not_go_together(
    tmp_path: Path, kwargs: dict[str, Any], needle: str
) -> None:
    a = _write(tmp_path / "a.exr", features=True)
    with pytest.raises(OptionError, match=needle):
        plan_jobs([a], **kwargs)


def test_denoise_paths_auto_picks_per_input_and_all_skips_what_an_input_cannot_feed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    registry.methods()
    monkeypatch.setattr(registry, "_REGISTRY", {})  # two cheap methods only
    monkeypatch.setattr(registry, "_ALIASES", {})
    registry.register(
        Method("plain", "t", ("color",), (), {}, lambda b, p, d: b["color"], priority=1)
    )
    registry.register(
        Method("guided", "t", ("color", "albedo"), (), {}, lambda b, p, d: b["albedo"], priority=2)
    )
    a = _write(tmp_path / "a.exr", features=True)
    b = _write(tmp_path / "b.exr", features=False)
    auto = list(denoise_paths([a, b], progress=False))
    assert [(o.job.method.name, o.job.output.name) for o in auto] == [
        ("guided", "a_guided.exr"),
        ("plain", "b_plain.exr"),
    ]
    assert all(o.result is not None and o.result.output.is_file() for o in auto)
    every = list(denoise_paths([a, b], tmp_path / "all", "all", progress=False))
    done = [(o.job.input.name, o.job.method.name) for o in every if o.result is not None]
    skipped = [o for o in every if o.skipped is not None]
    assert sorted(done) == [("a.exr", "guided"), ("a.exr", "plain"), ("b.exr", "plain")]
    assert len(skipped) == 1 and "albedo" in skipped[0].summary()
    assert skipped[0].summary().startswith("skipped guided on b.exr: ")
    with pytest.raises(MissingFeatureError):  # named explicitly: an error, not a skip
        list(denoise_paths([b], tmp_path / "x", "guided", progress=False))
