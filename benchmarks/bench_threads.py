"""Does ``mcdenoise denoise`` survive another multi-threaded process busy on the cores?

For every shipped method (nlm, cross-bilateral, kalantari-xbf, kalantari-nlm, kpcn; oidn when
pyoidn is installed) this times the whole process

    mcdenoise denoise data/samples/cornell_spp4.exr -o TMP.exr --method M --json

once idle and once while a background process runs a 2-thread torch matmul loop
(``torch.set_num_threads(2); a = torch.randn(1500, 1500)``, then ``a @ a`` forever: issue 20's
load), and prints both, their ratio, and the same for the method's own seconds (the ``seconds``
of the ``--json`` record, i.e. without Python start-up, imports and file I/O). Idle and loaded
runs alternate per method and repetition, and each cell is the median of ``--repeats``, because
the machines this runs on are shared and noisy. The first row, ``(start-up only)``, times a
process that only imports (Python, torch, mcdenoise) the same way: the slow-down the load
causes to work that has no threads at all, the floor under every method's ratio. Target (issue 20): whole-process ratio <= 3×
for every method with the default settings.

    python benchmarks/bench_threads.py [--repeats 3] [--methods nlm,kpcn]
        [--env OMP_NUM_THREADS=2 ...] [--args "--threads 2"] [--load-threads 2]

``--env`` and ``--args`` measure alternatives to the default (an environment variable set for
the denoise process, extra ``mcdenoise denoise`` arguments); the table's header says which.

``--calibrate`` instead measures each method's recorded speed for
:attr:`mcdenoise.method.Method.recorded_speed` (one thread, ``OMP_WAIT_POLICY=PASSIVE``): in a fresh
process per method and repetition, the first frame (128×128 sample, model loading included, as
a command-line user waits for it) and then the sample tiled 4×4 (512×512); ``per_mp`` is the
slope between the two, ``fixed`` the first frame's time minus its pixels' share. Prints the
minimum over ``--repeats`` (the least disturbed run on a shared machine), one line per method:
the ``recorded_speed=...`` argument to paste into its declaration in ``mcdenoise/methods/``.
``--waits`` times that 512×512 frame idle with 1 thread and with 2 threads under three OpenMP
wait policies (libgomp's default spin, ``GOMP_SPINCOUNT=10000``, ``PASSIVE``).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SAMPLE = ROOT / "data" / "samples" / "cornell_spp4.exr"
METHODS = ("nlm", "cross-bilateral", "kalantari-xbf", "kalantari-nlm", "kpcn", "oidn")

LOAD = """
import sys, torch
torch.set_num_threads({threads})
a = torch.randn(1500, 1500)
a @ a
print("ready", flush=True)
while True:
    a @ a
"""


CALIBRATE = """
import json, sys, time
import torch
from mcdenoise.denoise import denoise
from mcdenoise.io import FeatureBuffers, load_buffers

small = load_buffers(sys.argv[2])
big = FeatureBuffers({k: small[k].repeat(1, 4, 4) for k in small}, spp=small.spp)
first = denoise(small, sys.argv[1], device="cpu").seconds
tiled = denoise(big, sys.argv[1], device="cpu").seconds
print(json.dumps({"first": first, "tiled": tiled, "pixels": [small.height * small.width,
      big.height * big.width], "threads": torch.get_num_threads()}))
"""


def calibrate(methods: list[str], repeats: int) -> None:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OMP_WAIT_POLICY": "PASSIVE"}
    env.pop("GOMP_SPINCOUNT", None)
    print(f"# one thread; min of {repeats} fresh processes; {SAMPLE.name} and tiled 4x4")
    print(f"# load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print("# paste each line into the method's declaration (Method.recorded_speed)")
    for m in methods:
        runs = []
        for _ in range(repeats):
            proc = subprocess.run(
                [sys.executable, "-c", CALIBRATE, m, str(SAMPLE)],
                capture_output=True,
                text=True,
                env=env,
                check=True,
            )
            runs.append(json.loads(proc.stdout.strip().splitlines()[-1]))
        small, big = runs[0]["pixels"]
        first = min(r["first"] for r in runs)
        tiled = min(r["tiled"] for r in runs)
        per_mp = max(0.0, (tiled - first) / ((big - small) / 1e6))
        fixed = max(0.0, first - per_mp * small / 1e6)
        print(
            f'{m}: recorded_speed={{"{m}": ({fixed:.3g}, {per_mp:.3g})}},  # first '
            f"{first:.3f} s, 512x512 {tiled:.3f} s",
            flush=True,
        )
    print(f"# load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


WAITS = {
    "1 thread": {"OMP_NUM_THREADS": "1"},
    "2 threads, libgomp default spin": {"OMP_NUM_THREADS": "2"},
    "2 threads, GOMP_SPINCOUNT=10000 (the command's)": {
        "OMP_NUM_THREADS": "2",
        "GOMP_SPINCOUNT": "10000",
    },
    "2 threads, OMP_WAIT_POLICY=PASSIVE": {"OMP_NUM_THREADS": "2", "OMP_WAIT_POLICY": "PASSIVE"},
}


def compare_waits(methods: list[str], repeats: int) -> None:
    """Idle seconds of the 512×512 (tiled sample) frame per thread count and wait policy."""
    base = {k: v for k, v in os.environ.items() if not k.startswith(("OMP_", "GOMP_"))}
    print(f"# idle, {SAMPLE.name} tiled to 512x512, min of {repeats} fresh processes")
    print(f"# load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    for m in methods:
        for name, env in WAITS.items():
            best = min(
                json.loads(
                    subprocess.run(
                        [sys.executable, "-c", CALIBRATE, m, str(SAMPLE)],
                        capture_output=True,
                        text=True,
                        env={**base, **env},
                        check=True,
                    )
                    .stdout.strip()
                    .splitlines()[-1]
                )["tiled"]
                for _ in range(repeats)
            )
            print(f"{m:<16} {name:<48} {best:>7.3f} s", flush=True)
    print(f"# load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


def mcdenoise_cmd() -> list[str]:
    """The installed ``mcdenoise`` next to this Python, else ``python -m mcdenoise_cli.main``."""
    exe = Path(sys.executable).with_name("mcdenoise")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "mcdenoise_cli.main"]


def available(name: str) -> bool:
    if name != "oidn":
        return True
    try:
        import pyoidn  # noqa: F401  # lazy: pyoidn is optional
    except ImportError:
        return False
    return True


class Load:
    """The background 2-thread torch matmul loop (started; ready once its first product ran)."""

    def __init__(self, threads: int) -> None:
        env = {k: v for k, v in os.environ.items() if not k.startswith(("OMP_", "GOMP_"))}
        self.proc = subprocess.Popen(
            [sys.executable, "-c", LOAD.format(threads=threads)],
            stdout=subprocess.PIPE,
            text=True,
            env=env,
        )

    def __enter__(self) -> Load:
        assert self.proc.stdout is not None
        if self.proc.stdout.readline().strip() != "ready":
            raise RuntimeError("the background load did not start")
        time.sleep(0.5)  # let it reach its steady state
        return self

    def __exit__(self, *exc: object) -> None:
        self.proc.terminate()
        self.proc.wait()


def run_once(
    method: str, extra: list[str], env: dict[str, str], out: Path, timeout: float
) -> tuple[float, float]:
    """(whole-process seconds, the method's own seconds) of one ``mcdenoise denoise``."""
    cmd = [*mcdenoise_cmd(), "denoise", str(SAMPLE), "-o", str(out), "--method", method]
    cmd += ["--json", *extra]
    start = time.perf_counter()
    proc = subprocess.run(
        cmd, capture_output=True, text=True, env={**os.environ, **env}, timeout=timeout
    )
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise RuntimeError(f"{shlex.join(cmd)} failed:\n{proc.stderr}")
    record = json.loads(proc.stdout.strip().splitlines()[-1])
    return wall, float(record["seconds"])


def startup_once(env: dict[str, str], timeout: float) -> float:
    """Seconds of a process that only starts: Python, torch and the denoise module imported
    (the floor of every row: no method runs)."""
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, "-c", "import mcdenoise_cli.main, mcdenoise.denoise"],
        check=True,
        env={**os.environ, **env},
        timeout=timeout,
    )
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3, help="runs per cell (median)")
    ap.add_argument("--methods", default=",".join(METHODS), help="comma-separated methods")
    ap.add_argument("--env", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--args", default="", help="extra `mcdenoise denoise` arguments")
    ap.add_argument("--load-threads", type=int, default=2, help="threads of the background load")
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds per run")
    ap.add_argument(
        "--calibrate", action="store_true", help="measure each method's recorded_speed instead"
    )
    ap.add_argument(
        "--waits", action="store_true", help="idle 512x512 times per thread count and wait policy"
    )
    ns = ap.parse_args(argv)
    if ns.waits:
        compare_waits([m for m in ns.methods.split(",") if m and available(m)], ns.repeats)
        return 0
    if ns.calibrate:
        calibrate([m for m in ns.methods.split(",") if m and available(m)], ns.repeats)
        return 0

    env = dict(kv.split("=", 1) for kv in ns.env)
    extra = shlex.split(ns.args)
    methods = [m for m in ns.methods.split(",") if m and available(m)]
    print(f"# {shlex.join(mcdenoise_cmd())} denoise {SAMPLE.relative_to(ROOT)} --method M")
    print(f"# extra args: {shlex.join(extra) or '-'}; env: {ns.env or '-'}; cpus: {os.cpu_count()}")
    print(f"# load: {ns.load_threads}-thread torch matmul loop; median of {ns.repeats}")
    print(f"# load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    head = (
        f"{'method':<16} {'idle s':>8} {'loaded s':>9} {'ratio':>6}   "
        f"{'method idle':>11} {'method loaded':>13} {'ratio':>6}"
    )
    print(head)
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.exr"
        run_once(methods[0], extra, env, out, ns.timeout)  # warm the file cache
        idle_s, loaded_s = [], []
        for _ in range(ns.repeats):
            idle_s.append(startup_once(env, ns.timeout))
            with Load(ns.load_threads):
                loaded_s.append(startup_once(env, ns.timeout))
        wi, wl = statistics.median(idle_s), statistics.median(loaded_s)
        print(f"{'(start-up only)':<16} {wi:>8.2f} {wl:>9.2f} {wl / wi:>5.1f}×", flush=True)
        for m in methods:
            idle, loaded = [], []
            for _ in range(ns.repeats):
                idle.append(run_once(m, extra, env, out, ns.timeout))
                with Load(ns.load_threads):
                    loaded.append(run_once(m, extra, env, out, ns.timeout))
            wi, mi = (statistics.median(x[k] for x in idle) for k in (0, 1))
            wl, ml = (statistics.median(x[k] for x in loaded) for k in (0, 1))
            worst = max(worst, wl / wi)
            print(
                f"{m:<16} {wi:>8.2f} {wl:>9.2f} {wl / wi:>5.1f}×   "
                f"{mi:>11.3f} {ml:>13.3f} {ml / mi:>5.1f}×",
                flush=True,
            )
    print(f"# worst whole-process ratio: {worst:.1f}× (target <= 3×)")
    print(f"# load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
