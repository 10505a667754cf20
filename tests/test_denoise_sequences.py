"""Sequences as input (issue 23, item 1): a folder of frames is one sequence for a temporal
method (its frames in order, outputs written frame by frame, a re-run resumes), checked from
the headers before anything is written; per-frame methods keep taking a folder as stills.

The temporal method here is a test toy, a running mean of the colour over the frames: its
output at frame t depends on every earlier frame, so a wrong order, a lost or a wrong history
shows in the pixels.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest
import torch

from mcdenoise import registry
from mcdenoise.batch import denoise_paths, plan_jobs
from mcdenoise.denoise_files import (
    ReadOptions,
    SequenceJob,
    frame_info,
    output_complete,
    scan_sequence,
)
from mcdenoise.errors import InputError
from mcdenoise.io import FeatureBuffers, load_buffers, probe_exr, save_buffers
from mcdenoise.io.buffers import MissingFeatureError
from mcdenoise.io.exr_write import write_exr
from mcdenoise.method import Method

ONE_THREAD = True


class RunningMean:
    """Temporal toy: output t = mean of the colours of frames 0..t. Records every frame it
    was given (``seen``: the ``mcdenoise:frame`` of each, in order) and can stop the run
    with Ctrl-C when it reaches frame ``interrupt_at``."""

    def __init__(self, *, motion: bool = True) -> None:
        self.motion = motion
        self.seen: list[int] = []
        self.interrupt_at: int | None = None

    def __call__(
        self, frames: Iterable[FeatureBuffers], params: Mapping[str, Any], device: torch.device
    ) -> Iterator[torch.Tensor]:
        total, n = None, 0
        for f in frames:
            assert ("motion" in f) == self.motion  # listed in uses: it reaches the method
            self.seen.append(len(self.seen))
            if self.interrupt_at is not None and len(self.seen) - 1 == self.interrupt_at:
                raise KeyboardInterrupt
            c = f["color"] * params["gain"]
            total = c if total is None else total + c
            n += 1
            yield total / n


def mean_method(fn: RunningMean) -> Method:
    return Method(
        "runmean",
        "running mean over frames (test)",
        ("color",),
        ("motion", "motion_valid"),
        {"gain": 1.0},
        None,
        temporal=True,
        run_sequence=fn,
    )


def box3(b: FeatureBuffers, p: Mapping[str, Any], d: torch.device) -> torch.Tensor:
    c = b["color"][None]
    return torch.nn.functional.avg_pool2d(c, 3, 1, 1, count_include_pad=False)[0]


@pytest.fixture
def toy(monkeypatch: pytest.MonkeyPatch) -> RunningMean:
    """The running mean registered as ``runmean`` and a 3×3 box as ``box3``, for one test."""
    registry.methods()
    monkeypatch.setattr(registry, "_REGISTRY", {})
    monkeypatch.setattr(registry, "_ALIASES", {})
    fn = RunningMean()
    registry.register(mean_method(fn))
    registry.register(Method("box3", "3x3 box (test)", ("color",), (), {}, box3))
    return fn


def colour(t: int, h: int = 6, w: int = 8) -> torch.Tensor:
    g = torch.Generator().manual_seed(100 + t)
    return torch.rand(3, h, w, generator=g) + 0.1


def write_frames(
    folder: Path,
    count: int = 4,
    *,
    numbers: Iterable[int] | None = None,
    size: tuple[int, int] = (6, 8),
    motion: bool = True,
    sizes: Mapping[int, tuple[int, int]] | None = None,
    no_motion: Iterable[int] = (),
) -> list[Path]:
    """Frames in the canonical layout of ``mcdenoise render --frames`` (``frame_0000.exr``,
    ``mcdenoise:frame`` in the header, motion + motion_valid), and a ``ref/`` beside them."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "ref").mkdir(exist_ok=True)
    paths = []
    for t in numbers if numbers is not None else range(count):
        h, w = (sizes or {}).get(t, size)
        b: dict[str, torch.Tensor] = {"color": colour(t, h, w)}
        if motion and t not in set(no_motion):
            b["motion"] = torch.full((2, h, w), 0.5)
            b["motion_valid"] = torch.full((1, h, w), float(t > 0))
        attrs = {"mcdenoise:frame": t, "mcdenoise:sequence": "seq"}
        p = folder / f"frame_{t:04d}.exr"
        save_buffers(p, FeatureBuffers(b, spp=4), attributes=attrs)
        save_buffers(folder / "ref" / p.name, FeatureBuffers({"color": colour(t, h, w)}, spp=64))
        paths.append(p)
    return paths


def expected(count: int) -> list[torch.Tensor]:
    out, total = [], None
    for t in range(count):
        total = colour(t) if total is None else total + colour(t)
        out.append(total / (t + 1))
    return out


def run(inputs: list[Path], out: Path | None, method: str, **kw: Any) -> list[Any]:
    return list(denoise_paths(inputs, out, method, device="cpu", progress=False, **kw))


# --- a folder is one sequence for a temporal method -------------------------------------------
def test_a_folder_is_one_sequence_denoised_in_frame_order(toy: RunningMean, tmp_path: Path):
    seq = tmp_path / "seq"
    write_frames(seq, 4)
    outcomes = run([seq], tmp_path / "out", "runmean")
    assert [o.job.input.name for o in outcomes] == [f"frame_{t:04d}.exr" for t in range(4)]
    assert toy.seen == [0, 1, 2, 3]  # one pass over the frames, ref/ never read
    for t, (o, want) in enumerate(zip(outcomes, expected(4))):
        assert (
            o.result is not None and o.job.output == tmp_path / "out" / f"frame_{t:04d}_runmean.exr"
        )
        got = load_buffers(o.job.output)
        torch.testing.assert_close(got["color"], want)
        assert (
            got.attributes["mcdenoise:frame"] == t
            and got.attributes["mcdenoise:method"] == "runmean"
        )
        assert got.attributes["mcdenoise:sequence"] == "seq"
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        f"frame_{t:04d}_runmean.exr" for t in range(4)
    ]


def test_frames_are_ordered_by_number_not_by_name(toy: RunningMean, tmp_path: Path):
    """frame_9 sorts after frame_10 by name; the sequence order is the number."""
    seq = tmp_path / "seq"
    seq.mkdir()
    for t in (8, 9, 10, 11):
        save_buffers(
            seq / f"shot.{t}.exr",
            FeatureBuffers({"color": colour(t - 8), "motion": torch.zeros(2, 6, 8)}),
        )
    outcomes = run([seq], tmp_path / "out", "runmean")
    assert [o.job.input.name for o in outcomes] == [f"shot.{t}.exr" for t in (8, 9, 10, 11)]
    for o, want in zip(outcomes, expected(4)):
        torch.testing.assert_close(load_buffers(o.job.output)["color"], want)


def test_a_sequence_of_one_frame_works_even_without_motion(toy: RunningMean, tmp_path: Path):
    seq = tmp_path / "one"
    write_frames(seq, 1, motion=False)
    toy_fn = RunningMean(motion=False)
    registry.register(  # the same toy, without motion among the buffers it uses
        Method(
            "still", "t", ("color",), (), {"gain": 1.0}, None, temporal=True, run_sequence=toy_fn
        )
    )
    (o,) = run([seq], None, "still")
    assert o.job.output == seq / "frame_0000_still.exr"
    torch.testing.assert_close(load_buffers(o.job.output)["color"], colour(0))
    (o,) = run([seq / "frame_0000.exr"], tmp_path / "x.exr", "still")  # one file, -o a file
    assert (tmp_path / "x.exr").is_file()


def test_a_per_frame_method_still_takes_a_folder_as_stills(toy: RunningMean, tmp_path: Path):
    """Gaps, sizes and missing motion do not matter to a per-frame method: one job per file,
    as before."""
    seq = tmp_path / "seq"
    write_frames(seq, numbers=[0, 1, 3], sizes={3: (5, 5)}, motion=False)
    plan = plan_jobs([seq], tmp_path / "out", "box3")
    assert not any(isinstance(j, SequenceJob) for j in plan.jobs)
    assert [j.input.name for j in plan.jobs] == [
        "frame_0000.exr",
        "frame_0001.exr",
        "frame_0003.exr",
    ]
    outcomes = run([seq], tmp_path / "out", "box3")
    assert all(o.result is not None for o in outcomes) and len(outcomes) == 3
    assert toy.seen == []


def test_several_methods_per_frame_and_temporal_together(toy: RunningMean, tmp_path: Path):
    seq = tmp_path / "seq"
    write_frames(seq, 3)
    outcomes = run([seq], tmp_path / "out", "box3,runmean")
    names = sorted(o.job.output.name for o in outcomes)
    assert names == sorted(
        [f"frame_{t:04d}_box3.exr" for t in range(3)]
        + [f"frame_{t:04d}_runmean.exr" for t in range(3)]
    )


# --- bad sequences: one line, nothing written ------------------------------------------------
@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        (
            {"numbers": [0, 1, 3, 4]},
            "frame 2 is missing (between frame_0001.exr and frame_0003.exr)",
        ),
        ({"numbers": [0, 4]}, "frames 1-3 are missing"),
        (
            {"count": 3, "sizes": {2: (6, 7)}},
            "frames of different sizes: frame_0000.exr is 8x6, frame_0002.exr is 7x6",
        ),
        (
            {"count": 3, "no_motion": [1]},
            "method 'runmean' needs motion vectors in every frame; frame_0001.exr has none",
        ),
        ({"count": 3, "motion": False}, "--mapping"),
    ],
)
def test_bad_sequences_are_refused_before_anything_is_written(
    toy: RunningMean, tmp_path: Path, kwargs: dict[str, Any], needle: str
) -> None:
    seq = tmp_path / "seq"
    write_frames(seq, **kwargs)
    with pytest.raises(InputError) as err:
        run([seq], tmp_path / "out", "runmean")
    msg = str(err.value)
    assert needle in msg and "\n" not in msg and msg.startswith(str(seq))
    assert not (tmp_path / "out").exists() and toy.seen == []
    assert sorted(p.name for p in seq.glob("*.exr")) == sorted(
        p.name for p in seq.glob("frame_????.exr")
    )


def test_two_files_of_one_frame_and_unnumbered_frames_are_refused(toy: RunningMean, tmp_path: Path):
    seq = tmp_path / "seq"
    write_frames(seq, 2)
    save_buffers(
        seq / "take2.exr",
        FeatureBuffers({"color": colour(0), "motion": torch.zeros(2, 6, 8)}),
        attributes={"mcdenoise:frame": 1},
    )
    with pytest.raises(InputError, match=r"frame_0001\.exr and take2\.exr are both frame 1"):
        run([seq], tmp_path / "out", "runmean")
    (seq / "take2.exr").unlink()
    save_buffers(
        seq / "extra.exr", FeatureBuffers({"color": colour(0), "motion": torch.zeros(2, 6, 8)})
    )
    with pytest.raises(InputError, match=r"extra\.exr has no frame number"):
        run([seq], tmp_path / "out", "runmean")


def test_frames_of_two_rendered_sequences_are_refused(toy: RunningMean, tmp_path: Path):
    a, b = write_frames(tmp_path / "a", 1), write_frames(tmp_path / "b", 2)
    with pytest.raises(InputError, match=r"frames of different sequences \(a, b"):
        # the loose files are one sequence; rewrite b's frame 1 as sequence "b"
        save_buffers(b[1], load_buffers(b[1]), attributes={"mcdenoise:sequence": "b"})
        save_buffers(a[0], load_buffers(a[0]), attributes={"mcdenoise:sequence": "a"})
        run([a[0], b[1]], tmp_path / "out", "runmean")


def test_a_missing_required_buffer_names_it(toy: RunningMean, tmp_path: Path):
    registry.register(
        Method(
            "needs-albedo",
            "t",
            ("color", "albedo"),
            ("motion",),
            {},
            None,
            temporal=True,
            run_sequence=RunningMean(),
        )
    )
    seq = tmp_path / "seq"
    write_frames(seq, 2)
    with pytest.raises(MissingFeatureError, match="method 'needs-albedo' needs albedo"):
        run([seq], tmp_path / "out", "needs-albedo")
    assert not (tmp_path / "out").exists()


def test_method_all_skips_a_temporal_method_on_a_sequence_it_refuses(
    toy: RunningMean, tmp_path: Path
):
    seq = tmp_path / "seq"
    write_frames(seq, 3, motion=False)
    outcomes = run([seq], tmp_path / "out", "all")
    skipped = [o for o in outcomes if o.skipped is not None]
    assert len(skipped) == 1 and skipped[0].summary().startswith("skipped runmean on seq: ")
    assert "needs motion vectors" in skipped[0].summary()
    assert sorted(o.job.output.name for o in outcomes if o.result) == [
        f"frame_{t:04d}_box3.exr" for t in range(3)
    ]


# --- motion read by name: Cycles' Vector, a mapping file --------------------------------------
def test_motion_is_found_through_the_profiles_and_a_mapping_file(toy: RunningMean, tmp_path: Path):
    seq = tmp_path / "seq"
    seq.mkdir()
    h, w = 6, 8
    for t in range(3):
        c = colour(t).numpy()
        chans = {"R": c[0], "G": c[1], "B": c[2], "vel.u": c[0] * 0 + 1, "vel.v": c[0] * 0}
        write_exr(seq / f"plate_{t:03d}.exr", chans)
    info = frame_info(seq / "plate_000.exr")
    assert info.number == 0 and info.size == (w, h) and "motion" not in info.buffers
    with pytest.raises(InputError, match="needs motion vectors"):
        run([seq], tmp_path / "out", "runmean")
    mapping = tmp_path / "map.toml"
    mapping.write_text('color = ["R", "G", "B"]\nmotion = ["vel.u", "vel.v"]\n')
    read = ReadOptions(mapping=str(mapping))
    assert "motion" in frame_info(seq / "plate_000.exr", read).buffers
    outcomes = run([seq], tmp_path / "out", "runmean", read=read)
    for o, want in zip(outcomes, expected(3)):
        torch.testing.assert_close(load_buffers(o.job.output)["color"], want)


def test_cycles_vector_pass_is_motion(tmp_path: Path):
    """A Blender multilayer frame: ``Vector`` (mapped by the cycles profile) is motion."""
    h, w = 4, 5
    z = torch.zeros(h, w).numpy()
    chans = {f"ViewLayer.Combined.{c}": z + 0.5 for c in "RGBA"}
    chans.update({f"ViewLayer.Vector.{c}": z + 1 for c in "XYZW"})
    path = tmp_path / "0007.exr"
    write_exr(path, chans, attributes={"BlenderMultiChannel": "Blender"})
    info = frame_info(path)
    assert {"color", "motion", "motion_next"} <= info.buffers and info.number == 7
    assert info.size == (w, h)
    by_layer = frame_info(path, ReadOptions(part="ViewLayer"))  # a view layer by name
    assert by_layer.buffers == info.buffers and by_layer.size == (w, h)
    forced = frame_info(path, ReadOptions(profile="cycles:ViewLayer"))
    assert forced.buffers == info.buffers


# --- frame by frame, and resume ---------------------------------------------------------------
def test_an_interrupted_run_keeps_its_frames_and_a_rerun_writes_the_rest(
    toy: RunningMean, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    seq, out = tmp_path / "seq", tmp_path / "out"
    write_frames(seq, 5)
    toy.interrupt_at = 3
    with pytest.raises(KeyboardInterrupt):
        run([seq], out, "runmean")
    done = sorted(p.name for p in out.iterdir())
    assert done == [f"frame_{t:04d}_runmean.exr" for t in range(3)]  # written as finished
    stamps = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}

    import mcdenoise.batch as batch

    written: list[str] = []
    real = batch.write_result

    def spy(src, dst, *a, **k):
        written.append(dst.name)
        return real(src, dst, *a, **k)

    monkeypatch.setattr(batch, "write_result", spy)
    toy.interrupt_at, toy.seen = None, []
    outcomes = run([seq], out, "runmean")
    assert written == ["frame_0003_runmean.exr", "frame_0004_runmean.exr"]
    assert toy.seen == [0, 1, 2, 3, 4]  # the history is replayed from frame 0
    assert [o.skipped is not None for o in outcomes] == [True, True, True, False, False]
    assert "is done" in outcomes[0].summary()
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.name in stamps} == stamps
    for t, want in enumerate(expected(5)):  # as an uninterrupted run: the history is exact
        torch.testing.assert_close(load_buffers(out / f"frame_{t:04d}_runmean.exr")["color"], want)
    written.clear()
    toy.seen = []
    run([seq], out, "runmean")  # everything done: nothing runs, nothing is written
    assert written == [] and toy.seen == []


def test_a_missing_middle_output_is_rewritten_and_the_run_stops_there(
    toy: RunningMean, tmp_path: Path
) -> None:
    seq, out = tmp_path / "seq", tmp_path / "out"
    write_frames(seq, 5)
    run([seq], out, "runmean")
    (out / "frame_0002_runmean.exr").unlink()
    toy.seen = []
    run([seq], out, "runmean")
    assert toy.seen == [0, 1, 2]  # frames 3, 4 are done: not run
    torch.testing.assert_close(
        load_buffers(out / "frame_0002_runmean.exr")["color"], expected(3)[2]
    )


def test_outputs_of_other_parameters_or_sources_are_not_taken_as_done(
    toy: RunningMean, tmp_path: Path
) -> None:
    seq, out = tmp_path / "seq", tmp_path / "out"
    write_frames(seq, 2)
    run([seq], out, "runmean")
    m = registry.get_method("runmean")
    dst, src = out / "frame_0000_runmean.exr", seq / "frame_0000.exr"
    assert output_complete(dst, src, m, {"gain": 1.0}, None)
    assert not output_complete(dst, src, m, {"gain": 2.0}, None)
    assert not output_complete(dst, seq / "frame_0001.exr", m, {"gain": 1.0}, None)
    assert not output_complete(dst, src, m, {"gain": 1.0}, "spp4")
    toy.seen = []
    run([seq], out, "runmean", params={"gain": "2"})
    assert toy.seen == [0, 1]
    torch.testing.assert_close(load_buffers(dst)["color"], 2 * colour(0))
    assert json.loads(probe_exr(dst)[0].attributes["mcdenoise:params"]) == {"gain": 2.0}


def test_outputs_beside_the_frames_are_not_frames(toy: RunningMean, tmp_path: Path):
    """Without -o the outputs land in the sequence folder; a re-run does not take them for
    frames (their header records a method) and finds everything done."""
    seq = tmp_path / "seq"
    write_frames(seq, 3)
    run([seq], None, "runmean")
    assert len(list(seq.glob("*_runmean.exr"))) == 3
    frames = scan_sequence(seq, sorted(seq.glob("*.exr")), registry.get_method("runmean"))
    assert [f.path.name for f in frames] == [f"frame_{t:04d}.exr" for t in range(3)]
    toy.seen = []
    outcomes = run([seq], None, "runmean")
    assert toy.seen == [] and all(o.skipped for o in outcomes)


def test_a_part_is_read_from_every_frame_and_named_in_the_outputs(toy: RunningMean, tmp_path: Path):
    from mcdenoise.io import save_buffers_parts

    seq = tmp_path / "seq"
    seq.mkdir()
    for t in range(2):
        levels = {
            f"spp{n}": FeatureBuffers(
                {"color": colour(t) * n, "motion": torch.zeros(2, 6, 8)}, spp=n
            )
            for n in (1, 4)
        }
        save_buffers_parts(seq / f"frame_{t:04d}.exr", levels)
    outcomes = run([seq], tmp_path / "out", "runmean", read=ReadOptions(part="spp4"))
    assert [o.job.output.name for o in outcomes] == [
        f"frame_{t:04d}_spp4_runmean.exr" for t in range(2)
    ]
    torch.testing.assert_close(
        load_buffers(outcomes[1].job.output)["color"], (colour(0) + colour(1)) * 4 / 2
    )


CYCLES_FILE = Path(__file__).parent / "io" / "data" / "cycles_32" / "cycles_spp4.exr"


@pytest.mark.parametrize(
    "read",
    [
        ReadOptions(),
        ReadOptions(part="ViewLayer"),
        ReadOptions(part="Layer2"),
        ReadOptions(profile="cycles:Layer2"),
    ],
    ids=["auto", "part-ViewLayer", "part-Layer2", "profile-Layer2"],
)
def test_frame_info_finds_what_the_loader_reads_in_a_real_blender_file(read: ReadOptions):
    """Blender 5 output (one part per pass, two view layers): the headers give the buffers
    and size the loader produces (the Vector pass: motion and motion_next)."""
    import logging

    logging.disable(logging.WARNING)  # the profile's convention notes, not tested here
    try:
        fb = load_buffers(
            CYCLES_FILE, profile=read.profile, mapping=read.mapping, part=read.part, spp=read.spp
        )
        info = frame_info(CYCLES_FILE, read)
    finally:
        logging.disable(logging.NOTSET)
    assert info.buffers == set(fb.names()) and info.size == (fb.shape[1], fb.shape[0])
    assert {"motion", "motion_next"} <= info.buffers


def test_the_top_of_a_render_folder_points_to_its_sequences(toy: RunningMean, tmp_path: Path):
    write_frames(tmp_path / "renders" / "ballA", 2)
    write_frames(tmp_path / "renders" / "ballB", 2)
    with pytest.raises(InputError) as err:
        run([tmp_path / "renders"], tmp_path / "out", "runmean")
    msg = str(err.value)
    assert "holds no .exr files (its subfolders ballA, ballB hold some" in msg
    assert str(tmp_path / "renders" / "ballA") in msg
