"""A packed training set (``mcdenoise train --pack``): the folder's items in one ``.npz``,
training from it gives the folder's weights, and reading it imports no EXR library."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from mcdenoise_cli.main import main
from test_train_kpcn import TINY as KPCN_TINY

from mcdenoise.errors import InputError
from mcdenoise.models.encoders import SOURCES
from mcdenoise.models.kpcn import KpcnModel
from mcdenoise.train.config import load_config
from mcdenoise.train.kpcn import PACK_KEYS, make_prepare, pack_kpcn, train_kpcn
from mcdenoise.train.pack import FLOAT16_MAX, is_pack, pack_meta, read_pack
from mcdenoise.train.patches import load_split

REPO = Path(__file__).resolve().parents[2]
#: The tiny kpcn of tests/train/test_train_kpcn.py; prefilter=auto: the basic crops' tensors too.
TINY = {**KPCN_TINY, "prefilter": "auto"}

#: one intra-op thread for this module (tests/conftest.py)
ONE_THREAD = True


def cfg(data: Path | str, **kw):
    values = {**TINY, "data": str(data), **kw}
    return load_config(None, {k: str(v) for k, v in values.items()})


@pytest.fixture(scope="module")
def packs(tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("packs")
    out = {}
    for dtype in ("float32", "float16"):
        out[dtype] = folder / f"tiny-{dtype}.npz"
        pack_kpcn(cfg(tiny_dataset), out[dtype], dtype=dtype)
    return out


def _folder_items(tiny_dataset: Path):
    c = cfg(tiny_dataset)
    sources = [s for s in SOURCES if s in c.sources]
    return load_split(c, make_prepare(c, sources), crop=c.patch + 2 * c.margin)


def test_a_float32_pack_holds_the_folders_items_bit_for_bit(
    tiny_dataset: Path, packs: dict[str, Path]
) -> None:
    train, val, _ = _folder_items(tiny_dataset)
    c = cfg(packs["float32"])
    ptrain, pval, report = read_pack(c, crop=c.patch + 2 * c.margin, keys=PACK_KEYS)
    assert report.used == len(train)
    for mine, theirs in ((ptrain, train), (pval, val)):
        assert [it.entry for it in mine] == [it.entry for it in theirs]  # same split and order
        for a, b in zip(mine, theirs, strict=True):
            assert sorted(a.tensors) == sorted(b.tensors)
            assert "albedo_basic" in a.tensors  # the basic crops' prefiltered features
            for k in a.tensors:
                assert a.tensors[k].dtype == torch.float32
                assert torch.equal(a.tensors[k], b.tensors[k]), (a.entry.name, k)
    meta = pack_meta(packs["float32"])
    assert meta["source"] == str(tiny_dataset) and meta["config"]["prefilter"] == "auto"
    # one reference per image, shared by its levels
    refs = {it["arrays"]["reference"] for it in meta["items"]}
    assert len(refs) == len({it["image"] for it in meta["items"]}) < len(meta["items"])


def test_a_float16_pack_rounds_within_half_precision(
    tiny_dataset: Path, packs: dict[str, Path]
) -> None:
    train, _, _ = _folder_items(tiny_dataset)
    c = cfg(packs["float16"])
    ptrain, _, _ = read_pack(c, crop=c.patch + 2 * c.margin)
    with np.load(packs["float16"]) as z:
        assert {z[n].dtype for n in z.files if n != "meta"} == {np.dtype(np.float16)}
    assert packs["float16"].stat().st_size < 0.6 * packs["float32"].stat().st_size
    for a, b in zip(ptrain, train, strict=True):
        for k in a.tensors:
            x, y = a.tensors[k], b.tensors[k]
            # relative 2^-11 for normal numbers; below float16's normal range, absolute 2^-25
            assert bool((x - y).abs().le(y.abs() * 2**-11 + 2**-25).all()), k


def test_a_float16_pack_keeps_an_array_beyond_its_range_in_float32(
    tiny_dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import mcdenoise.train.kpcn as kpcn_module

    c = cfg(tiny_dataset)
    plain = make_prepare(c, list(c.sources))

    def firefly(buffers, ref):
        t = plain(buffers, ref)
        t["color_var"] = t["color_var"].clone()
        t["color_var"][0, 0, 0] = 4 * FLOAT16_MAX
        return t

    monkeypatch.setattr(kpcn_module, "make_prepare", lambda cfg, sources: firefly)
    summary = pack_kpcn(c, tmp_path / "f.npz")
    assert summary.float32_arrays == summary.train_levels + summary.val_levels
    items, _, _ = read_pack(cfg(tmp_path / "f.npz"), crop=32)
    assert float(items[0].tensors["color_var"][0, 0, 0]) == 4 * FLOAT16_MAX


def test_training_from_a_float32_pack_gives_the_folders_weights(
    tiny_dataset: Path, packs: dict[str, Path], tmp_path: Path
) -> None:
    folder_run, pack_run = tmp_path / "folder", tmp_path / "pack"
    r1, _ = train_kpcn(cfg(tiny_dataset), folder_run, progress=False)
    r2, _ = train_kpcn(cfg(packs["float32"]), pack_run, progress=False)
    strip = ("seconds",)
    m1 = [{k: v for k, v in m.items() if k not in strip} for m in r1.metrics]
    m2 = [{k: v for k, v in m.items() if k not in strip} for m in r2.metrics]
    assert m1 == m2  # train and validation losses, step for step
    a, b = KpcnModel.load(folder_run), KpcnModel.load(pack_run)
    sa, sb = a.state_dict(), b.state_dict()
    assert sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)
    assert b.card.stats == a.card.stats
    assert b.card.training["pack"] == {"source": str(tiny_dataset), "dtype": "float32"}
    assert b.card.training["train_images"] == a.card.training["train_images"]


def test_training_from_a_float16_pack_stays_close(
    tiny_dataset: Path, packs: dict[str, Path], tmp_path: Path
) -> None:
    r1, _ = train_kpcn(cfg(tiny_dataset), tmp_path / "a", progress=False)
    r2, _ = train_kpcn(cfg(packs["float16"]), tmp_path / "b", progress=False)
    for m1, m2 in zip(r1.metrics, r2.metrics, strict=True):
        assert m2["train_loss"] == pytest.approx(m1["train_loss"], rel=2e-3)
        assert m2["val_loss"] == pytest.approx(m1["val_loss"], rel=2e-3)


def test_a_pack_refuses_a_config_it_was_not_prepared_for(packs: dict[str, Path]) -> None:
    with pytest.raises(InputError, match=r"seed: pack 0, config 3.*pack the data again"):
        read_pack(cfg(packs["float16"], seed=3), crop=32, keys=PACK_KEYS)
    with pytest.raises(InputError, match="prefilter"):
        train_kpcn(cfg(packs["float16"], prefilter="off"), "unused", progress=False)
    # the crop is not a pack key: images smaller than it are skipped, as from the folder
    with pytest.raises(InputError, match=r"smaller than a training crop \(64 px\)"):
        read_pack(cfg(packs["float16"], patch=48), crop=64)
    assert is_pack("a/B.NPZ") and not is_pack("a/b") and not is_pack("")


def test_the_cli_packs_and_trains_from_the_pack(tiny_dataset: Path, tmp_path: Path) -> None:
    pack = tmp_path / "set.npz"
    args = ["train", "--model", "kpcn", "--data", str(tiny_dataset), "--quiet"]
    flags = [x for k, v in TINY.items() if k != "model" for x in ("-s", f"{k}={v}")]
    r = CliRunner().invoke(main, [*args, "--pack", str(pack), *flags])
    assert r.exit_code == 0, r.output
    assert "packed 6 training and 2 validation level(s)" in r.output and pack.is_file()
    run = tmp_path / "run"
    r = CliRunner().invoke(
        main,
        ["train", "--model", "kpcn", "--data", str(pack), "--out", str(run), "--quiet", *flags],
    )
    assert r.exit_code == 0, r.output
    assert json.loads((run / "config.json").read_text())["data"] == str(pack)
    r = CliRunner().invoke(main, ["train", "--data", str(pack), "--out", str(tmp_path / "x")])
    assert r.exit_code == 1 and "pass --model kpcn" in r.output  # the default model is not kpcn
    # without --pack, --out is still required; a file that is not a pack is still refused
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2 and "Missing option '--out'" in r.output
    r = CliRunner().invoke(main, ["train", "--data", str(run / "config.json"), "--out", "x"])
    assert r.exit_code == 2 and "is a file" in r.output


_NO_EXR = """
import sys, importlib.abc
BLOCKED = ("OpenImageIO", "OpenEXR", "mitsuba", "drjit", "Imath")
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ImportError(f"blocked: {name}")
sys.meta_path.insert(0, Block())
from mcdenoise_cli.main import main
main(sys.argv[1:], standalone_mode=False)
assert not [m for m in sys.modules if m.split(".")[0] in BLOCKED]
import mcdenoise, mcdenoise_cli
print("no EXR library imported", mcdenoise.__file__, mcdenoise_cli.__file__)
"""


def test_training_from_a_pack_imports_no_exr_library(
    packs: dict[str, Path], tmp_path: Path
) -> None:
    flags = [
        x for k, v in {**TINY, "steps": 1, "epoch_steps": 1}.items() for x in ("-s", f"{k}={v}")
    ]
    # as data/recipes/kpcn_gpu.sh runs it: from the source tree, mcdenoise_cli a link to cli/
    shim = tmp_path / "shim"
    shim.mkdir()
    (shim / "mcdenoise_cli").symlink_to(REPO / "cli")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), str(shim)])}
    args = ["train", "--data", str(packs["float16"]), "--out", str(tmp_path / "run"), "--quiet"]
    r = subprocess.run(
        [sys.executable, "-c", _NO_EXR, *args, *flags],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert "no EXR library imported" in r.stdout
    assert f"{REPO / 'mcdenoise'}" in r.stdout and f"{shim / 'mcdenoise_cli'}" in r.stdout
    assert (tmp_path / "run" / "model.pt").is_file()


def test_the_gpu_recipe_script_trains_from_a_pack_on_cpu(
    packs: dict[str, Path], tmp_path: Path
) -> None:
    """data/recipes/kpcn_gpu.sh end to end with DEVICE=cpu: the run folder in $OUT/run, a
    summary with steps/s (what a GPU session runs, with DEVICE=cuda)."""
    flags = [
        x for k, v in {**TINY, "steps": 2, "epoch_steps": 2}.items() for x in ("-s", f"{k}={v}")
    ]
    env = {**os.environ, "OUT": str(tmp_path / "out"), "DEVICE": "cpu", "PYTHON": sys.executable}
    r = subprocess.run(
        ["bash", str(REPO / "data" / "recipes" / "kpcn_gpu.sh"), str(packs["float16"]), *flags],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=120,
    )
    assert r.returncode == 0, (r.stdout + r.stderr)[-2000:]
    out = tmp_path / "out"
    summary = (out / "summary.txt").read_text()
    assert "no CUDA device" in summary and "2 steps in" in summary and "steps/s" in summary
    run = out / "run"
    assert {p.name for p in run.iterdir()} >= {"config.json", "latest", "metrics.jsonl", "model.pt"}
    assert json.loads((run / "config.json").read_text())["device"] == "cpu"
    assert KpcnModel.load(run).card.training["pack"]["dtype"] == "float16"
    assert len(list(run.rglob("*"))) + 2 <= 9  # files + checkpoints/: what $OUT brings back


def test_a_pack_split_into_parts_reads_as_one(
    tiny_dataset: Path, packs: dict[str, Path], tmp_path: Path
) -> None:
    r = CliRunner().invoke(
        main,
        ["train", "--model", "kpcn", "--data", str(tiny_dataset), "--quiet"]
        + ["--pack", str(tmp_path / "set.npz"), "--pack-shard-mib", "0.02"]
        + [x for k, v in TINY.items() if k != "model" for x in ("-s", f"{k}={v}")],
    )
    assert r.exit_code == 0, r.output
    parts = sorted(p.name for p in tmp_path.iterdir())
    assert "set.npz" in parts and "set.part1.npz" in parts and "in 1 files" not in r.output
    assert all(p.stat().st_size < 0.02 * 2**20 + 40_000 for p in tmp_path.iterdir())
    shards = pack_meta(tmp_path / "set.npz")["shards"]
    assert sorted(shards) == [p for p in parts if p != "set.npz"]
    c = cfg(tmp_path / "set.npz")
    whole, whole_val, _ = read_pack(cfg(packs["float16"]), crop=32)
    split, split_val, _ = read_pack(c, crop=32)
    for a, b in zip([*split, *split_val], [*whole, *whole_val], strict=True):
        assert a.entry == b.entry
        assert all(torch.equal(a.tensors[k], b.tensors[k]) for k in b.tensors)
    (tmp_path / "set.part1.npz").unlink()
    with pytest.raises(InputError, match=r"set\.part1\.npz: no such pack"):
        read_pack(c, crop=32)


def test_a_pack_write_that_fails_leaves_no_file_and_no_temporary(tmp_path, monkeypatch) -> None:
    """A full disk while packing (the second array's write fails): no pack, no shard and no
    temporary file is left, and the error names the pack (written as every file is)."""
    import errno

    import numpy as np

    from mcdenoise.errors import WriteError
    from mcdenoise.train import pack

    real, calls = np.lib.format.write_array, []

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(*args, **kwargs)

    monkeypatch.setattr(np.lib.format, "write_array", failing)
    arrays = {f"a{i}": np.full((64, 64), i, np.float32) for i in range(4)}
    out = tmp_path / "set.npz"
    with pytest.raises(WriteError, match=r"set\.npz"):
        pack._write_shards(out, arrays, {"version": 1}, compress=False, shard_bytes=20_000)
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(np.lib.format, "write_array", real)
    files = pack._write_shards(out, arrays, {"version": 1}, compress=False, shard_bytes=20_000)
    assert files[0] == out and len(files) > 1  # the main file and its shards, nothing else
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in files)


def test_a_pack_from_elsewhere_is_data(tmp_path) -> None:
    """A pack whose metadata names a shard elsewhere (``../secret.npz``) or does not hold
    together is refused in one line naming the pack; no path it gives is opened."""
    import json

    import numpy as np

    from mcdenoise.train import pack
    from mcdenoise.train.config import TrainConfig

    def make(meta: object) -> None:
        np.savez(tmp_path / "set.npz", **{pack._META: np.array(json.dumps(meta))})

    good = {"version": pack.PACK_VERSION, "config": {}, "items": [], "skipped": []}
    cfg = TrainConfig(model="kpcn", data=str(tmp_path / "set.npz"))
    for meta, why in [
        ({**good, "shards": ["../secret.npz"]}, "not 'set.part1.npz'"),
        ({**good, "items": [{"image": 1}]}, "not a valid training pack"),
        ([1, 2], "not a training pack"),
    ]:
        make(meta)
        with pytest.raises(InputError, match=r"set\.npz") as info:
            pack.read_pack(cfg, crop=8, keys=())
        assert why in str(info.value) and len(str(info.value).splitlines()) == 1
