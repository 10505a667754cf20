"""A stand-in for a researcher's denoiser program, for ``tests/methods/test_external.py``.

It reads and writes images with OpenImageIO only (never mcdenoise), so the tests check the
files mcdenoise hands to a command against an independent reader. Modes::

    external_denoiser.py --version            prints a version line
    external_denoiser.py blur IN OUT          3x3 box blur (edges repeated) of IN's R,G,B
    external_denoiser.py copy SRC OUT         SRC's first three channels written to OUT
    external_denoiser.py channels IN          IN's channel names on stderr, exit status 4
                                              (so a test sees them in mcdenoise's error)
    external_denoiser.py fail                 a message on stderr, exit status 3
    external_denoiser.py sleep SECONDS        sleeps
    external_denoiser.py nothing              exits 0 without writing anything
    external_denoiser.py oidn C A N OUT       OIDN (pyoidn, RT filter, HDR, quality high) on
                                              colour C, albedo A, normal N: the wrapper of
                                              the issue's check against the built-in ``oidn``
    external_denoiser.py garbage OUT          writes a file that is no image
    external_denoiser.py half IN OUT          writes an output of half IN's width

PFM files (``.pfm``, what OIDN's own tools read and write) are read and written here with
numpy, rows bottom to top as the Netpbm PFM specification and OIDN's ``image_io.cpp`` have
it (OpenImageIO 3.2 reads PFM rows in file order, top to bottom).
"""

from __future__ import annotations

import sys
import time

import numpy as np


def _read_pfm(path: str) -> tuple[list[str], np.ndarray]:
    with open(path, "rb") as f:
        kind = f.readline().strip()
        w, h = (int(v) for v in f.readline().split())
        scale = float(f.readline())
        c = 3 if kind == b"PF" else 1
        px = np.frombuffer(f.read(w * h * c * 4), dtype="<f4" if scale < 0 else ">f4")
    return (["R", "G", "B"] if c == 3 else ["Y"]), px.reshape(h, w, c)[::-1].astype(np.float32)


def _read(path: str) -> tuple[list[str], np.ndarray]:
    import OpenImageIO as oiio

    if path.endswith(".pfm"):
        return _read_pfm(path)
    inp = oiio.ImageInput.open(path)
    if inp is None:
        sys.exit(f"cannot open {path}: {oiio.geterror()}")
    names = list(inp.spec().channelnames)
    pixels = inp.read_image(oiio.FLOAT)  # (H, W, C)
    inp.close()
    return names, np.asarray(pixels, dtype=np.float32)


def _rgb(path: str) -> np.ndarray:
    names, px = _read(path)
    if {"R", "G", "B"} <= set(names):
        return px[..., [names.index(c) for c in "RGB"]]
    return px[..., :3]


def _write(path: str, rgb: np.ndarray) -> None:
    import OpenImageIO as oiio

    h, w, _ = rgb.shape
    if path.endswith(".pfm"):
        with open(path, "wb") as f:
            f.write(f"PF\n{w} {h}\n-1.0\n".encode())
            f.write(np.ascontiguousarray(rgb[::-1], dtype="<f4").tobytes())
        return
    spec = oiio.ImageSpec(w, h, 3, oiio.FLOAT)
    spec.channelnames = ("R", "G", "B")
    out = oiio.ImageOutput.create(path)
    if out is None or not out.open(path, spec):
        sys.exit(f"cannot write {path}: {oiio.geterror()}")
    out.write_image(np.ascontiguousarray(rgb, dtype=np.float32))
    out.close()


def box_blur(rgb: np.ndarray) -> np.ndarray:
    """3x3 mean of ``(H, W, 3)`` with the edge pixels repeated."""
    h, w, _ = rgb.shape
    p = np.pad(rgb, ((1, 1), (1, 1), (0, 0)), mode="edge")
    return sum(p[dy : dy + h, dx : dx + w] for dy in range(3) for dx in range(3)) / 9.0


def main(argv: list[str]) -> int:
    if argv[:1] == ["--version"]:
        print("external_denoiser 1.0")
        return 0
    mode, args = argv[0], argv[1:]
    if mode == "blur":
        _write(args[1], box_blur(_rgb(args[0])))
    elif mode == "copy":
        _write(args[1], _rgb(args[0]))
    elif mode == "channels":
        print("channels: " + ",".join(_read(args[0])[0]), file=sys.stderr)
        return 4
    elif mode == "fail":
        print("loading model weights.pt", file=sys.stderr)
        print("error: the tensor has the wrong shape", file=sys.stderr)
        return 3
    elif mode == "sleep":
        time.sleep(float(args[0]))
    elif mode == "half":
        rgb = _rgb(args[0])
        _write(args[1], rgb[:, : rgb.shape[1] // 2])
    elif mode == "oidn":
        import pyoidn

        c, a, n = (_rgb(f) for f in args[:3])  # clamped as the built-in oidn method does
        out = pyoidn.denoise(
            np.ascontiguousarray(np.maximum(c, 0)),
            np.ascontiguousarray(np.clip(a, 0, 1)),
            np.ascontiguousarray(np.clip(n, -1, 1)),
            hdr=True,
            clean_aux=False,
            quality="high",
        )
        _write(args[3], np.asarray(out, dtype=np.float32))
    elif mode == "garbage":
        with open(args[0], "wb") as f:
            f.write(b"not an image")
    elif mode != "nothing":
        print(f"unknown mode {mode}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
